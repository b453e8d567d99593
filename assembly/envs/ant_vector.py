"""goflow/Ant-v0 batched: N ants in one MultibodyPlant, one AdvanceTo per vector step.

`gymnasium.make_vec("goflow/Ant-v0", num_envs=N, vectorization_mode="vector_entry_point")` builds
it. Copy i is AntEnv's robot (`ant.add_ant`) in model instance "ant_i", on one shared ground,
started 3 m beside the previous one (y = 3 i m; its state rows hold y relative to that, so they are
the single env's): copies at one place cost the broadphase O(N^2) candidate pairs (measured: N = 16
0.7x, N = 64 0.3x the steps/s of 16 single envs). Each copy keeps the single env's contact rules (only the ground
touches it, no self-contact), and contact between copies is filtered out. Task, reward, xi and
observations are AntEnv's (assembly/envs/ant.py); the contract is BatchedEnv's
(assembly/envs/batched.py).
"""

from __future__ import annotations

from dataclasses import fields, replace
from typing import Any

import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from assembly.envs import ant
from assembly.envs.batched import BatchedEnv, check_num_envs, episode_steps, instance_state_columns, refuse_render
from assembly.envs.drake_sim import HeldInput, filter_between_copies, quiet_drake
from assembly.params import Param, ParamSpace
from assembly.samplers import Sampler
from goflow_common.config import config_with_overrides

__all__ = ["AntVectorEnv"]

SPACING = 3.0  # [m] between neighbouring copies' start lines (an ant spans ~2.3 m)


class AntVectorEnv(BatchedEnv):
    """N ants running forward at once; xi per copy = (torso mass,)."""

    _owner = "AntVectorEnv"

    def __init__(
        self,
        num_envs: int = 1,
        config: ant.AntConfig | None = None,
        *,
        sampler: Sampler | None = None,
        max_episode_steps: int | None = None,
        render_mode: str | None = None,
        **overrides: Any,
    ) -> None:
        refuse_render(render_mode, self._owner)
        n = check_num_envs(num_envs, self._owner)
        self.config = cfg = config_with_overrides(ant.AntConfig, config, overrides, self._owner)
        space = ParamSpace((Param("torso_mass", 0.01, 20.0, "kg"),))
        steps = episode_steps(cfg.t_max, cfg.control_dt, max_episode_steps)
        super().__init__(
            n,
            space,
            sampler,
            spaces.Box(-np.inf, np.inf, shape=(27,), dtype=np.float32),
            spaces.Box(-1.0, 1.0, shape=(8,), dtype=np.float32),
            cfg.control_dt,
            steps,
            cfg.j_t(),
        )
        self._build()

    def _build(self) -> None:
        from pydrake.multibody.plant import AddMultibodyPlant
        from pydrake.systems.analysis import Simulator
        from pydrake.systems.framework import DiagramBuilder

        cfg, n = self.config, self.num_envs
        builder = DiagramBuilder()
        with quiet_drake():  # half spaces and deformable contact (we have none)
            plant, scene_graph = AddMultibodyPlant(ant.plant_config(cfg), builder)
            self._copies = [ant.add_ant(plant, cfg, plant.AddModelInstance(f"ant_{i}")) for i in range(n)]
            ant.add_ground(plant, cfg)
            plant.Finalize()
            for copy in self._copies:
                ant.exclude_self_contact(scene_graph, copy)
            filter_between_copies(scene_graph, [c.geometries for c in self._copies])
            self._diagram = builder.Build()
            self._simulator = Simulator(self._diagram)
        self._plant = plant
        self._context = self._simulator.get_mutable_context()
        self._plant_context = plant.GetMyMutableContextFromRoot(self._context)
        # Copy i's [q; v] (the single env's order) as row i of full[self._columns].
        self._columns = np.array([instance_state_columns(plant, c.torso.model_instance()) for c in self._copies])
        self._layout = ant.ant_layout(plant, self._copies[0], self._columns[0])
        for copy, columns in zip(self._copies[1:], self._columns[1:]):
            layout = ant.ant_layout(plant, copy, columns)
            if not all(np.array_equal(getattr(layout, f.name), getattr(self._layout, f.name)) for f in fields(layout)):
                raise RuntimeError(f"{self._owner}: copies have different state layouts")
        inertia = self._copies[0].torso_inertia
        self._com0, self._unit_inertia0 = np.asarray(inertia.get_com()), inertia.get_unit_inertia()
        # Actuation vector entries of copy i's joints, in joint order.
        self._offset = SPACING * np.arange(n)  # copy i's start at y = offset[i]
        self._u_index = np.array([[a.input_start() for a in c.actuators] for c in self._copies])
        self._u = np.zeros(plant.num_actuated_dofs())
        self._input = HeldInput(plant.get_actuation_input_port(), self._plant_context, self._u)
        self._k = 0
        self._simulator.Initialize()

    # -- BatchedEnv hooks --------------------------------------------------------------------------

    def _apply_xi(self, idx: NDArray[np.int64], xi: NDArray[np.float64]) -> None:
        from pydrake.multibody.tree import SpatialInertia

        for i, (mass,) in zip(idx, xi):  # mass and rotational inertia scale together
            self._copies[i].torso.SetSpatialInertiaInBodyFrame(
                self._plant_context, SpatialInertia(float(mass), self._com0, self._unit_inertia0)
            )

    def _rest_state(self, idx: NDArray[np.int64]) -> NDArray[np.float64]:
        rest = ant.initial_row(
            replace(self.config, reset_noise_scale=0.0), self._layout, self._columns.shape[1], np.random.default_rng(0)
        )  # no noise: nothing is drawn
        return np.tile(rest, (len(idx), 1))

    def _reset_copies(
        self, idx: NDArray[np.int64], xi: NDArray[np.float64], rngs: list[np.random.Generator]
    ) -> NDArray[np.float32]:
        width = self._columns.shape[1]
        rows = np.array([ant.initial_row(self.config, self._layout, width, rng) for rng in rngs])
        if len(idx) == self.num_envs:  # a full reset restarts the clock, as the single env does
            self._context.SetTime(0.0)
            self._k = 0
        self._set_state(idx, rows)
        self._u[self._u_index[idx]] = 0.0
        self._input.set(self._u)
        if len(idx) == self.num_envs:
            self._simulator.Initialize()
        return ant.observe(self._layout, rows)

    def _get_state(self, idx: NDArray[np.int64]) -> NDArray[np.float64]:
        rows = self._plant.GetPositionsAndVelocities(self._plant_context)[self._columns[idx]]
        rows[:, self._layout.pos[1]] -= self._offset[idx]
        return rows

    def _set_state(self, idx: NDArray[np.int64], state: NDArray[np.float64]) -> None:
        full = self._plant.GetPositionsAndVelocities(self._plant_context).copy()
        rows = state.copy()
        rows[:, self._layout.pos[1]] += self._offset[idx]
        full[self._columns[idx]] = rows
        self._plant.SetPositionsAndVelocities(self._plant_context, full)

    def _make_twin(self) -> AntVectorEnv:
        return AntVectorEnv(1, self.config)

    def _step_copies(self, actions: NDArray[np.float64]):
        cfg = self.config
        a = np.clip(actions, -1.0, 1.0)
        full = self._plant.GetPositionsAndVelocities(self._plant_context)
        x_before = full[self._columns[:, self._layout.pos[0]]]
        self._u[self._u_index] = a * cfg.effort_limit
        self._input.set(self._u)
        self._advance_period()
        rows = self._get_state(np.arange(self.num_envs))
        reward, terminated, info = ant.step_reward(cfg, self._layout, x_before, rows, a)
        reward[~np.isfinite(rows).all(axis=1)] = np.nan
        return ant.observe(self._layout, rows), reward, terminated, info
