"""goflow/Quadrotor-v0 batched: N airframes in one MultibodyPlant, one AdvanceTo per vector step.

`gymnasium.make_vec("goflow/Quadrotor-v0", num_envs=N, vectorization_mode="vector_entry_point")`
builds it. Copy i is QuadrotorEnv's airframe (`quadrotor.add_quadrotor`) in model instance
"quadrotor_i"; all copies start at the same place over one shared ground, and contact between
copies is filtered out; one Propeller system drives the 4 N rotors. Task, reward, xi and
observations are QuadrotorEnv's (assembly/envs/quadrotor.py); the contract is BatchedEnv's
(assembly/envs/batched.py).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from assembly.envs.batched import BatchedEnv, check_num_envs, episode_steps, refuse_render
from assembly.envs.drake_sim import HeldInput, filter_between_copies
from assembly.envs.quadrotor import QUADROTOR_SPACE, QuadrotorConfig, add_ground, add_propellers, add_quadrotor
from assembly.samplers import Sampler
from goflow_common.config import config_with_overrides

__all__ = ["QuadrotorVectorEnv"]


class QuadrotorVectorEnv(BatchedEnv):
    """N quadrotors flying to their own random goals; xi per copy = (mass,)."""

    _owner = "QuadrotorVectorEnv"

    def __init__(
        self,
        num_envs: int = 1,
        config: QuadrotorConfig | None = None,
        *,
        sampler: Sampler | None = None,
        max_episode_steps: int | None = None,
        render_mode: str | None = None,
        **overrides: Any,
    ) -> None:
        refuse_render(render_mode, self._owner)
        n = check_num_envs(num_envs, self._owner)
        self.config = cfg = config_with_overrides(QuadrotorConfig, config, overrides, self._owner)
        self._obs_high = np.array((200.0,) * 3 + (500.0,) * 3 + (1.0,) * 3 + (500.0,) * 3)
        high = self._obs_high.astype(np.float32)
        steps = episode_steps(cfg.t_max, cfg.control_dt, max_episode_steps)
        super().__init__(
            n,
            QUADROTOR_SPACE,
            sampler,
            spaces.Box(-high, high, dtype=np.float32),
            spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32),
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
        self._bodies = [add_quadrotor(plant, cfg, plant.AddModelInstance(f"quadrotor_{i}")) for i in range(n)]
        add_ground(plant)
        plant.Finalize()
        filter_between_copies(scene_graph, [plant.GetCollisionGeometriesForBody(b) for b in self._bodies])
        propellers = add_propellers(builder, plant, cfg, self._bodies)
        self._diagram = builder.Build()
        self._plant = plant
        self._simulator = Simulator(self._diagram)
        self._context = self._simulator.get_mutable_context()
        self._plant_context = plant.GetMyMutableContextFromRoot(self._context)
        prop_context = propellers.GetMyMutableContextFromRoot(self._context)
        self._thrusts = np.zeros(4 * n)
        self._input = HeldInput(propellers.get_command_input_port(), prop_context, self._thrusts)
        # Copy i's free-body state (qw qx qy qz x y z, w_WB, v_WB) as columns of the plant's [q; v].
        nq = plant.num_positions()
        joints = [plant.GetJointByName("body_free", b.model_instance()) for b in self._bodies]
        q0 = np.array([j.position_start() for j in joints])
        v0 = nq + np.array([j.velocity_start() for j in joints])
        self._columns = np.concatenate((q0[:, None] + np.arange(7), v0[:, None] + np.arange(6)), axis=1)
        self._goal = np.zeros((n, 3))
        self._k = 0
        self._simulator.Initialize()

    # -- BatchedEnv hooks --------------------------------------------------------------------------

    def _apply_xi(self, idx: NDArray[np.int64], xi: NDArray[np.float64]) -> None:
        for i, (mass,) in zip(idx, xi):
            self._bodies[i].SetMass(self._plant_context, float(mass))

    def _start_rows(self, k: int) -> NDArray[np.float64]:
        rows = np.zeros((k, 13))
        rows[:, 0] = 1.0
        rows[:, 4:7] = self.config.start_position
        return rows

    def _rest_state(self, idx: NDArray[np.int64]) -> NDArray[np.float64]:
        return np.concatenate((self._start_rows(len(idx)), self._goal[idx]), axis=1)

    def _reset_copies(
        self, idx: NDArray[np.int64], xi: NDArray[np.float64], rngs: list[np.random.Generator]
    ) -> NDArray[np.float32]:
        cfg = self.config
        r = cfg.goal_xy_range
        for i, rng in zip(idx, rngs):  # QuadrotorEnv's draws, in its order
            gx, gy = rng.uniform(-r, r, size=2)
            gz = rng.uniform(*cfg.goal_z_range)
            self._goal[i] = (gx, gy, gz)
        if len(idx) == self.num_envs:  # a full reset restarts the clock, as the single env does
            self._context.SetTime(0.0)
            self._k = 0
        rows = self._start_rows(len(idx))
        self._set_state(idx, np.concatenate((rows, self._goal[idx]), axis=1))
        self._thrusts.reshape(-1, 4)[idx] = 0.0
        self._input.set(self._thrusts)
        if len(idx) == self.num_envs:
            self._simulator.Initialize()
        return self._observe_and_reward(rows, self._goal[idx])[0]

    def _get_state(self, idx: NDArray[np.int64]) -> NDArray[np.float64]:
        full = self._plant.GetPositionsAndVelocities(self._plant_context)
        return np.concatenate((full[self._columns[idx]], self._goal[idx]), axis=1)

    def _set_state(self, idx: NDArray[np.int64], state: NDArray[np.float64]) -> None:
        full = self._plant.GetPositionsAndVelocities(self._plant_context).copy()
        full[self._columns[idx]] = state[:, :13]
        self._plant.SetPositionsAndVelocities(self._plant_context, full)
        self._goal[idx] = state[:, 13:16]

    def _make_twin(self) -> QuadrotorVectorEnv:
        return QuadrotorVectorEnv(1, self.config)

    def _observe_and_reward(
        self, rows: NDArray[np.float64], goal: NDArray[np.float64]
    ) -> tuple[NDArray[np.float32], NDArray[np.float64]]:
        """QuadrotorEnv._observe_and_reward for every row, in the same operation order."""
        cfg = self.config
        qw, qx, qy, qz, px, py, pz, wx, wy, wz, vx, vy, vz = rows.T
        n = 1.0 / np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        w, x, y, z = qw * n, qx * n, qy * n, qz * n
        a0, a1, a2 = 1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)
        b0, b1, b2 = 2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)
        c0, c1, c2 = 2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)
        v_b = (a0 * vx + a1 * vy + a2 * vz, b0 * vx + b1 * vy + b2 * vz, c0 * vx + c1 * vy + c2 * vz)
        w_b = (a0 * wx + a1 * wy + a2 * wz, b0 * wx + b1 * wy + b2 * wz, c0 * wx + c1 * wy + c2 * wz)
        ex, ey, ez = goal[:, 0] - px, goal[:, 1] - py, goal[:, 2] - pz
        goal_b = (a0 * ex + a1 * ey + a2 * ez, b0 * ex + b1 * ey + b2 * ez, c0 * ex + c1 * ey + c2 * ez)
        obs = np.stack(v_b + w_b + (-a2, -b2, -c2) + goal_b, axis=1)
        obs = np.clip(obs, -self._obs_high, self._obs_high).astype(np.float32)
        d = np.sqrt(goal_b[0] ** 2 + goal_b[1] ** 2 + goal_b[2] ** 2)
        reward = self.control_dt * (
            cfg.rew_lin_vel * (v_b[0] ** 2 + v_b[1] ** 2 + v_b[2] ** 2)
            + cfg.rew_ang_vel * (w_b[0] ** 2 + w_b[1] ** 2 + w_b[2] ** 2)
            + cfg.rew_distance * (1.0 - np.tanh(d / cfg.distance_scale))
        )
        return obs, reward

    def _step_copies(self, actions: NDArray[np.float64]):
        cfg = self.config
        self._thrusts[:] = (0.5 * cfg.max_rotor_thrust * (np.clip(actions, -1.0, 1.0) + 1.0)).ravel()
        self._input.set(self._thrusts)
        self._advance_period()
        rows = self._plant.GetPositionsAndVelocities(self._plant_context)[self._columns]
        obs, reward = self._observe_and_reward(rows, self._goal)
        limit = cfg.max_angular_rate
        rates = rows[:, 7:10]
        over = ~(np.abs(rates) <= limit).all(axis=1)  # also catches NaN
        for i in np.flatnonzero(over):
            self._step_failures[int(i)] = (
                f"mass {float(self._xi[i, 0]):g} kg: body rate ({rates[i, 0]:.3g}, {rates[i, 1]:.3g}, "
                f"{rates[i, 2]:.3g}) rad/s beyond max_angular_rate = {limit:g} rad/s: the discrete step diverged"
            )
        reward[over | ~np.isfinite(rows).all(axis=1)] = np.nan
        return obs, reward, np.zeros(self.num_envs, dtype=bool), {}
