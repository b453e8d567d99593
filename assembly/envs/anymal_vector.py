"""goflow/Anymal-v0 batched: N quadrupeds in one MultibodyPlant, one AdvanceTo per vector step.

`gymnasium.make_vec("goflow/Anymal-v0", num_envs=N, vectorization_mode="vector_entry_point")`
builds it. Copy i is AnymalEnv's robot (`anymal.add_anymal`) in model instance "anymal_i", on one
shared ground, started 3 m beside the previous one (y = 3 i m; its state rows hold y relative to
that, so they are the single env's): copies at one place cost the broadphase O(N^2) candidate
pairs. Each copy keeps the single env's contact
rules (only the ground touches it, no self-contact), and contact between copies is filtered out.
The per-step work beside the physics (hip friction, joint loads, contact flags, feet timers,
reward terms) is AnymalEnv's, for all copies at once (assembly/envs/anymal.py); the contract is
BatchedEnv's (assembly/envs/batched.py).
"""

from __future__ import annotations

from dataclasses import fields, replace
from typing import Any

import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from assembly.envs import anymal
from assembly.envs.batched import BatchedEnv, check_num_envs, episode_steps, instance_state_columns, refuse_render
from assembly.envs.drake_sim import HeldInput, filter_between_copies, quiet_drake
from assembly.samplers import Sampler
from goflow_common.config import config_with_overrides

__all__ = ["AnymalVectorEnv"]

SPACING = 3.0  # [m] between neighbouring copies' start lines (the robot spans ~1 m)
_TASK = 12 + 4 + 3 * 4  # per-copy task data after the plant row: last action, HAA loads, feet timers


class AnymalVectorEnv(BatchedEnv):
    """N quadrupeds tracking the forward command at once; xi per copy = (base mass, 4 HAA frictions)."""

    _owner = "AnymalVectorEnv"

    def __init__(
        self,
        num_envs: int = 1,
        config: anymal.AnymalConfig | None = None,
        *,
        sampler: Sampler | None = None,
        max_episode_steps: int | None = None,
        render_mode: str | None = None,
        **overrides: Any,
    ) -> None:
        refuse_render(render_mode, self._owner)
        n = check_num_envs(num_envs, self._owner)
        self.config = cfg = config_with_overrides(anymal.AnymalConfig, config, overrides, self._owner)
        steps = episode_steps(cfg.t_max, cfg.control_dt, max_episode_steps)
        super().__init__(
            n,
            anymal.anymal_space(),
            sampler,
            spaces.Box(-np.inf, np.inf, shape=(48,), dtype=np.float32),
            spaces.Box(-1.0, 1.0, shape=(12,), dtype=np.float32),
            cfg.control_dt,
            steps,
            cfg.j_t(),
        )
        self._build()
        #: The last step's ten reward terms, (N,) each (AnymalEnv.last_reward_terms per copy).
        self.last_reward_terms: dict[str, NDArray[np.float64]] = {}

    def _build(self) -> None:
        from pydrake.multibody.plant import AddMultibodyPlant
        from pydrake.systems.analysis import Simulator
        from pydrake.systems.framework import DiagramBuilder

        cfg, n = self.config, self.num_envs
        builder = DiagramBuilder()
        with quiet_drake():  # half spaces and deformable contact (we have none)
            plant, scene_graph = AddMultibodyPlant(anymal.plant_config(cfg), builder)
            self._copies = [anymal.add_anymal(plant, cfg, plant.AddModelInstance(f"anymal_{i}")) for i in range(n)]
            anymal.add_ground(plant, cfg)
            plant.Finalize()
            for copy in self._copies:
                anymal.exclude_self_contact(scene_graph, copy)
            filter_between_copies(scene_graph, [c.geometries for c in self._copies])
            self._diagram = builder.Build()
            self._simulator = Simulator(self._diagram)
        self._plant = plant
        self._context = self._simulator.get_mutable_context()
        self._plant_context = ctx = plant.GetMyMutableContextFromRoot(self._context)
        # Copy i's [q; v] (the single env's order) as row i of full[self._columns].
        self._columns = np.array([instance_state_columns(plant, c.base.model_instance()) for c in self._copies])
        self._layout = anymal.anymal_layout(plant, self._copies[0], self._columns[0])
        for copy, columns in zip(self._copies[1:], self._columns[1:]):
            layout = anymal.anymal_layout(plant, copy, columns)
            if not all(np.array_equal(getattr(layout, f.name), getattr(self._layout, f.name)) for f in fields(layout)):
                raise RuntimeError(f"{self._owner}: copies have different state layouts")
        inertia = self._copies[0].base.default_spatial_inertia()
        self._base_com, self._base_unit_inertia = np.asarray(inertia.get_com()), inertia.get_unit_inertia()
        self._slots, self._per_robot = anymal.contact_slots(self._copies)
        # Copy i's entries in the net actuation (actuator order), accelerations and reaction forces.
        self._tau_index = np.array([np.sort([a.input_start() for a in c.actuators]) for c in self._copies])
        self._accel_index = np.array([[j.velocity_start() for j in c.joints] for c in self._copies])
        self._haa_index = np.array([[int(j.index()) for j in c.haa] for c in self._copies])
        # One desired-state port per model instance: [q_d; v_d] ordered by actuator index.
        self._act_order = anymal.desired_order(self._copies[0])
        self._desired = np.zeros((n, 24))
        self._desired_inputs = [
            HeldInput(plant.get_desired_state_input_port(c.base.model_instance()), ctx, self._desired[i])
            for i, c in enumerate(self._copies)
        ]
        self._actuation_input = HeldInput(plant.get_actuation_input_port(), ctx, np.zeros(plant.num_actuators()))
        self._net_actuation_port = plant.get_net_actuation_output_port()
        self._accel_port = plant.get_generalized_acceleration_output_port()
        self._contact_port = plant.get_contact_results_output_port()
        self._reaction_port = plant.get_reaction_forces_output_port()
        self._offset = SPACING * np.arange(n)  # copy i's start at y = offset[i]
        self._friction = np.zeros((n, 4))
        self._action = np.zeros((n, 12))
        self._load = np.zeros((n, 4))
        self._feet = anymal.FootTimers(n)
        self._k = 0
        self._simulator.Initialize()

    # -- BatchedEnv hooks --------------------------------------------------------------------------

    def _apply_xi(self, idx: NDArray[np.int64], xi: NDArray[np.float64]) -> None:
        from pydrake.multibody.tree import SpatialInertia

        for i, row in zip(idx, xi):  # mass and rotational inertia scale together; 0 kg is allowed
            copy = self._copies[i]
            copy.base.SetSpatialInertiaInBodyFrame(
                self._plant_context, SpatialInertia(float(row[0]), self._base_com, self._base_unit_inertia)
            )
            for joint in copy.haa:
                joint.SetDamping(self._plant_context, 0.0)
        self._friction[idx] = xi[:, 1:5]

    def _set_targets(self, idx: NDArray[np.int64], actions: NDArray[np.float64]) -> None:
        targets = np.asarray(anymal.DEFAULT_POSE) + self.config.action_scale * actions
        self._desired[np.ix_(idx, self._act_order)] = targets
        for i in idx:
            self._desired_inputs[i].set(self._desired[i])

    def _rest_state(self, idx: NDArray[np.int64]) -> NDArray[np.float64]:
        rest = anymal.initial_row(
            replace(self.config, reset_noise_scale=0.0), self._layout, self._columns.shape[1], np.random.default_rng(0)
        )  # no noise: nothing is drawn
        return np.tile(np.concatenate((rest, np.zeros(_TASK))), (len(idx), 1))

    def _reset_copies(
        self, idx: NDArray[np.int64], xi: NDArray[np.float64], rngs: list[np.random.Generator]
    ) -> NDArray[np.float32]:
        width = self._columns.shape[1]
        rows = np.array([anymal.initial_row(self.config, self._layout, width, rng) for rng in rngs])
        if len(idx) == self.num_envs:  # a full reset restarts the clock, as the single env does
            self._context.SetTime(0.0)
            self._k = 0
        self._set_state(idx, np.concatenate((rows, np.zeros((len(idx), _TASK))), axis=1))
        self._set_targets(idx, self._action[idx])
        if len(idx) == self.num_envs:
            self._simulator.Initialize()
        motion = anymal.base_motion(self._layout, rows)
        return anymal.observe(self.config, self._layout, rows, *motion, self._action[idx])

    def _rows(self, idx: NDArray[np.int64]) -> NDArray[np.float64]:
        """Copies idx's plant state rows, y relative to each copy's start line."""
        rows = self._plant.GetPositionsAndVelocities(self._plant_context)[self._columns[idx]]
        rows[:, self._layout.pos[1]] -= self._offset[idx]
        return rows

    def _get_state(self, idx: NDArray[np.int64]) -> NDArray[np.float64]:
        rows = self._rows(idx)
        f = self._feet
        return np.concatenate(
            (rows, self._action[idx], self._load[idx], f.air[idx], f.contact[idx], f.last_air[idx]), axis=1
        )

    def _set_state(self, idx: NDArray[np.int64], state: NDArray[np.float64]) -> None:
        width = self._columns.shape[1]
        full = self._plant.GetPositionsAndVelocities(self._plant_context).copy()
        rows = state[:, :width].copy()
        rows[:, self._layout.pos[1]] += self._offset[idx]
        full[self._columns[idx]] = rows
        self._plant.SetPositionsAndVelocities(self._plant_context, full)
        task = state[:, width:]
        self._action[idx], self._load[idx] = task[:, :12], task[:, 12:16]
        f = self._feet
        f.air[idx], f.contact[idx], f.last_air[idx] = task[:, 16:20], task[:, 20:24], task[:, 24:28]

    def _make_twin(self) -> AnymalVectorEnv:
        return AnymalVectorEnv(1, self.config)

    def _step_copies(self, actions: NDArray[np.float64]):
        cfg, n, ctx = self.config, self.num_envs, self._plant_context
        a = np.clip(actions, -1.0, 1.0)
        self._set_targets(np.arange(n), a)
        friction = self._friction.any()
        if friction:
            before = self._plant.GetPositionsAndVelocities(ctx)[self._columns]  # (y unused)
            damping = anymal.hip_damping(cfg, self._layout, self._friction, self._load, before)
            for i, j in zip(*np.nonzero(self._friction > 0.0)):
                self._copies[i].haa[j].SetDamping(ctx, float(damping[i, j]))
        self._advance_period()
        rows = self._rows(np.arange(n))
        if friction:
            self._load = anymal.joint_loads(self._reaction_port.Eval(ctx), self._haa_index)
        v_b, w_b, g_b = anymal.base_motion(self._layout, rows)
        tau = np.asarray(self._net_actuation_port.Eval(ctx))[self._tau_index]
        qdd = np.asarray(self._accel_port.Eval(ctx))[self._accel_index]
        base_contact, thighs, feet = anymal.contacts(
            self._contact_port.Eval(ctx), self._slots, self._per_robot, n, cfg.contact_force_threshold
        )
        air_reward = self._feet.update(feet, cfg.control_dt)
        self.last_reward_terms = anymal.reward_terms(
            cfg, cfg.control_dt, v_b, w_b, g_b, tau, qdd, a, self._action, air_reward, thighs
        )
        reward = sum(self.last_reward_terms.values())
        obs = anymal.observe(cfg, self._layout, rows, v_b, w_b, g_b, a)
        self._action = a
        terminated = base_contact & cfg.terminate_on_base_contact
        reward[~np.isfinite(rows).all(axis=1)] = np.nan
        info = {
            "base_height": rows[:, self._layout.pos[2]],
            "forward_velocity": v_b[:, 0],
            "base_contact": base_contact,
        }
        return obs, reward, terminated, info
