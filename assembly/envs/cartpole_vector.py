"""goflow/Cartpole-v0 batched: N cartpoles in one MultibodyPlant, one AdvanceTo per vector step.

`gymnasium.make_vec("goflow/Cartpole-v0", num_envs=N, vectorization_mode="vector_entry_point")`
builds it. Copy i is CartpoleEnv's model (`cartpole.add_cartpole`) in model instance
"cartpole_i", its rail 3 m beside the previous one, its own ground; contact between copies is
filtered out. Task, reward, xi and observations are CartpoleEnv's (assembly/envs/cartpole.py);
the contract is BatchedEnv's (assembly/envs/batched.py).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from assembly.envs.batched import BatchedEnv, check_num_envs, episode_steps, refuse_render
from assembly.envs.cartpole import CARTPOLE_SPACE, CartpoleConfig, wheel_contact, add_cartpole, cart_height
from assembly.envs.drake_sim import HeldInput, filter_between_copies
from assembly.samplers import Sampler
from goflow_common.config import config_with_overrides

__all__ = ["CartpoleVectorEnv"]

_SPACING = 3.0  # [m] between neighbouring rails (each ground is 2 m wide)


class CartpoleVectorEnv(BatchedEnv):
    """N cartpoles balanced at once; xi per copy = (pole mass, cart mass, slider Coulomb friction)."""

    _owner = "CartpoleVectorEnv"

    def __init__(
        self,
        num_envs: int = 1,
        config: CartpoleConfig | None = None,
        *,
        sampler: Sampler | None = None,
        max_episode_steps: int | None = None,
        render_mode: str | None = None,
        **overrides: Any,
    ) -> None:
        refuse_render(render_mode, self._owner)
        n = check_num_envs(num_envs, self._owner)
        self.config = cfg = config_with_overrides(CartpoleConfig, config, overrides, self._owner)
        self._obs_high = np.array((cfg.slider_limit + 1.0, 100.0, 1.0, 1.0, 200.0))
        high = self._obs_high.astype(np.float32)
        steps = episode_steps(cfg.t_max, cfg.control_dt, max_episode_steps)
        super().__init__(
            n,
            CARTPOLE_SPACE,
            sampler,
            spaces.Box(-high, high, dtype=np.float32),
            spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32),
            cfg.control_dt,
            steps,
            cfg.success_threshold,
        )
        self._build()

    def _build(self) -> None:
        from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
        from pydrake.systems.analysis import Simulator
        from pydrake.systems.framework import DiagramBuilder

        cfg, n = self.config, self.num_envs
        builder = DiagramBuilder()
        plant, scene_graph = AddMultibodyPlantSceneGraph(builder, time_step=cfg.sim_dt)
        self._copies = [
            add_cartpole(plant, cfg, plant.AddModelInstance(f"cartpole_{i}"), _SPACING * i) for i in range(n)
        ]
        plant.Finalize()
        filter_between_copies(scene_graph, [c.geometries for c in self._copies])
        self._diagram = builder.Build()
        self._plant, self._scene_graph = plant, scene_graph
        self._simulator = Simulator(self._diagram)
        self._context = self._simulator.get_mutable_context()
        self._plant_context = plant.GetMyMutableContextFromRoot(self._context)
        self._sg_context = scene_graph.GetMyMutableContextFromRoot(self._context)
        self._input = HeldInput(plant.get_actuation_input_port(), self._plant_context, np.zeros(n))
        self._forces = np.zeros(n)
        # Where copy i's (x, z, theta) and their rates sit in the plant's state vector [q; v].
        nq = plant.num_positions()
        self._q = np.array([[j.position_start() for j in c.joints] for c in self._copies])
        self._v = nq + np.array([[j.velocity_start() for j in c.joints] for c in self._copies])
        self._columns = np.concatenate((self._q, self._v), axis=1)  # (n, 6): x z theta xdot zdot thetadot
        actuators = [c.actuator.input_start() for c in self._copies]
        if actuators != list(range(n)):
            raise RuntimeError(f"{self._owner}: unexpected actuator order {actuators}")
        self._friction_set = np.full(n, np.nan)
        self._k = 0  # control steps since the last full reset
        self._simulator.Initialize()

    # -- BatchedEnv hooks --------------------------------------------------------------------------

    def _apply_xi(self, idx: NDArray[np.int64], xi: NDArray[np.float64]) -> None:
        from pydrake.geometry import RoleAssign

        source = self._plant.get_source_id()
        for i, (pole_mass, cart_mass, mu) in zip(idx, xi):
            copy = self._copies[i]
            copy.pole.SetMass(self._plant_context, float(pole_mass))
            copy.cart.SetMass(self._plant_context, float(cart_mass))
            if mu != self._friction_set[i]:
                for gid in copy.geometries:
                    self._scene_graph.AssignRole(
                        self._sg_context, source, gid, wheel_contact(float(mu), self.config), RoleAssign.kReplace
                    )
                self._friction_set[i] = mu

    def _rest(self, xi: NDArray[np.float64], theta0: NDArray[np.float64]) -> NDArray[np.float64]:
        penetration = (xi[:, 0] + xi[:, 1]) * 9.81 / self.config.contact_stiffness
        rows = np.zeros((len(xi), 6))
        rows[:, 1] = cart_height(self.config) - penetration
        rows[:, 2] = theta0
        return rows

    def _rest_state(self, idx: NDArray[np.int64]) -> NDArray[np.float64]:
        return self._rest(self._xi[idx], np.zeros(len(idx)))

    def _reset_copies(
        self, idx: NDArray[np.int64], xi: NDArray[np.float64], rngs: list[np.random.Generator]
    ) -> NDArray[np.float32]:
        a = self.config.initial_pole_angle
        theta0 = np.array([float(rng.uniform(-a, a)) if a > 0 else 0.0 for rng in rngs])
        rows = self._rest(xi, theta0)
        if len(idx) == self.num_envs:  # a full reset restarts the clock, as the single env does
            self._context.SetTime(0.0)
            self._k = 0
        self._set_state(idx, rows)
        self._forces[idx] = 0.0
        self._input.set(self._forces)
        if len(idx) == self.num_envs:
            self._simulator.Initialize()
        return self._observe(rows)

    def _get_state(self, idx: NDArray[np.int64]) -> NDArray[np.float64]:
        full = self._plant.GetPositionsAndVelocities(self._plant_context)
        return full[self._columns[idx]]

    def _set_state(self, idx: NDArray[np.int64], state: NDArray[np.float64]) -> None:
        full = self._plant.GetPositionsAndVelocities(self._plant_context).copy()
        full[self._columns[idx]] = state
        self._plant.SetPositionsAndVelocities(self._plant_context, full)

    def _make_twin(self) -> CartpoleVectorEnv:
        return CartpoleVectorEnv(1, self.config)

    def _observe(self, rows: NDArray[np.float64]) -> NDArray[np.float32]:
        theta = rows[:, 2]
        obs = np.stack((rows[:, 0], rows[:, 3], np.cos(theta), np.sin(theta), rows[:, 5]), axis=1)
        return np.clip(obs, -self._obs_high, self._obs_high).astype(np.float32)

    def _step_copies(self, actions: NDArray[np.float64]):
        cfg = self.config
        self._forces[:] = cfg.max_force * np.clip(actions[:, 0], -1.0, 1.0)
        self._input.set(self._forces)
        self._advance_period()
        rows = self._get_state(np.arange(self.num_envs))
        theta = (rows[:, 2] + np.pi) % (2.0 * np.pi) - np.pi
        reward = (
            cfg.rew_alive
            + cfg.rew_pole_angle * theta * theta
            + cfg.rew_cart_vel * np.abs(rows[:, 3])
            + cfg.rew_pole_vel * np.abs(rows[:, 5])
        )
        reward[~np.isfinite(rows).all(axis=1)] = np.nan
        return self._observe(rows), reward, np.zeros(self.num_envs, dtype=bool), {}
