"""goflow/GearInsertion-v0 (variant "fast") batched: N tools, each holding its gear, over one plate.

`gymnasium.make_vec("goflow/GearInsertion-v0", num_envs=N, vectorization_mode="vector_entry_point")`
builds it. Copy i is the fast variant's tool on x, y, z, yaw joints with its held gear
(`insertion_model.add_fast_tool`) in model instance "tool_i"; the copies share the plate and its
shafts, and contact between copies is filtered out. Task, reward, xi (the grasp error) and the
observation law are GearInsertionEnv's (assembly/envs/gear_insertion.py); the contract is
BatchedEnv's (assembly/envs/batched.py). The "panda" variant (the full station) has no batched env.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from assembly.envs.batched import BatchedEnv, check_num_envs, episode_steps, refuse_render
from assembly.envs.drake_sim import HeldInput, advance, filter_between_copies
from assembly.envs.gear_insertion import (
    GearInsertionConfig,
    tool_down_pose,
    grasp_error_space,
    insertion_reward,
    observation_space,
    seated_and_start,
)
from assembly.insertion_law import InsertionLaw, PoseHistory
from assembly.insertion_model import (
    FastInsertionConfig,
    FastInsertionModel,
    add_fast_fixtures,
    add_fast_tool,
    fast_plant_config,
    gravity_feedforward,
)
from assembly.samplers import Sampler
from assembly.world import grasp_with_error, insertion_error, is_seated
from assembly.panda_ik import panda_jacobian_at
from assembly.wrench_sensor import WRENCH_MODELS, WrenchSensor, joint_torque_of
from goflow_common.config import config_with_overrides
from goflow_common.errors import InputError

__all__ = ["GearInsertionVectorEnv"]


class GearInsertionVectorEnv(BatchedEnv):
    """N gears inserted at once; xi per copy = the grasp error (x, y, yaw)."""

    _owner = "GearInsertionVectorEnv"

    def __init__(
        self,
        num_envs: int = 1,
        config: GearInsertionConfig | None = None,
        *,
        sampler: Sampler | None = None,
        max_episode_steps: int | None = None,
        render_mode: str | None = None,
        **overrides: Any,
    ) -> None:
        refuse_render(render_mode, self._owner)
        n = check_num_envs(num_envs, self._owner)
        self.config = c = config_with_overrides(GearInsertionConfig, config, overrides, self._owner)
        if c.variant != "fast":
            raise InputError(
                f"{self._owner}: variant {c.variant!r} has no batched env; expected 'fast' "
                "(use vectorization_mode='sync' for the full station)"
            )
        steps = episode_steps(c.t_max, c.control_dt, max_episode_steps)
        super().__init__(
            n,
            grasp_error_space(c),
            sampler,
            observation_space(c),
            spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32),
            c.control_dt,
            steps,
            c.success_threshold,
        )
        self._build()

    def _build(self) -> None:
        from pydrake.multibody.plant import AddMultibodyPlant
        from pydrake.systems.analysis import Simulator
        from pydrake.systems.framework import DiagramBuilder

        c, n = self.config, self.num_envs
        fast = FastInsertionConfig(gear=c.gear, time_step=c.fast_time_step)
        builder = DiagramBuilder()
        plant, scene_graph = AddMultibodyPlant(fast_plant_config(fast), builder)
        X_WP = add_fast_fixtures(plant, fast)
        copies = [add_fast_tool(plant, fast, plant.AddModelInstance(f"tool_{i}")) for i in range(n)]
        plant.Finalize()
        geometries = [
            [
                g
                for body in (plant.GetBodyIndices(tool.model_instance()) + plant.GetBodyIndices(held.instance))
                for g in plant.GetCollisionGeometriesForBody(plant.get_body(body))
            ]
            for tool, held in copies
        ]
        filter_between_copies(scene_graph, geometries)
        self._diagram = builder.Build()
        self._plant = plant
        self._model = FastInsertionModel(self._diagram, plant, scene_graph, copies[0][1], X_WP, fast)
        self._held = [held for _, held in copies]
        self._gears = [plant.get_body(plant.GetBodyIndices(h.instance)[0]) for h in self._held]
        self._simulator = Simulator(self._diagram)
        self._context = self._simulator.get_mutable_context()
        self._pc = plant.GetMyMutableContextFromRoot(self._context)
        feedforward = gravity_feedforward(self._model)
        self._desired = []
        for tool, _ in copies:
            plant.get_actuation_input_port(tool.model_instance()).FixValue(self._pc, feedforward)
            self._desired.append(
                HeldInput(plant.get_desired_state_input_port(tool.model_instance()), self._pc, np.zeros(8))
            )
        nq, nv = plant.num_positions(), plant.num_velocities()
        q = np.array(
            [plant.GetPositionsFromArray(tool.model_instance(), np.arange(nq, dtype=float)) for tool, _ in copies]
        ).astype(int)
        v = np.array(
            [plant.GetVelocitiesFromArray(tool.model_instance(), np.arange(nv, dtype=float)) for tool, _ in copies]
        ).astype(int)
        self._columns = np.concatenate((q, nq + v), axis=1)  # (n, 8): x y z yaw and their rates
        X_WS = self._model.X_WS(c.gear)
        self._X_SW = X_WS.inverse()
        self._seated, self._start_pose = seated_and_start(c, X_WS)
        self._q_start = self._model.joint_positions_for(tool_down_pose(self._start_pose[:3], self._start_pose[3]))
        self.law = InsertionLaw(tuple(self._seated), c.action_scale, c.workspace, c.history, c.control_dt, c.sensing)
        self._histories = [PoseHistory(self.law) for _ in range(n)]
        self._sensors = None  # with wrench sensing: each copy's WrenchSensor, the contact ports, J
        if c.sensing == "wrench":
            self._sensors = [WrenchSensor(WRENCH_MODELS[c.wrench_sensor], c.control_dt) for _ in range(n)]
            self._contact = [plant.get_generalized_contact_forces_output_port(t.model_instance()) for t, _ in copies]
            self._J = panda_jacobian_at(self._model.tool_pose_of(self._q_start))
        self._d = np.zeros(n)
        self._simulator.Initialize()

    # -- BatchedEnv hooks --------------------------------------------------------------------------

    def _apply_xi(self, idx: NDArray[np.int64], xi: NDArray[np.float64]) -> None:
        for i, (x, y, yaw) in zip(idx, xi):
            self._held[i].grasp_frame.SetPoseInParentFrame(self._pc, grasp_with_error(self.config.gear, x, y, yaw))

    def _wrench(self, i: int) -> NDArray[np.float64] | None:
        """Copy i's estimated external wrench now (a fresh noise draw from its generator), or None
        without wrench sensing: the single env's `wrench`."""
        if self._sensors is None:
            return None
        tau = joint_torque_of(self._J, self._contact[i].Eval(self._pc))
        return self._sensors[i].measure(tau, self._J, self._rngs[i])

    def _gear_error(self, i: int) -> tuple[float, float]:
        return insertion_error(self._X_SW, self._gears[i].EvalPoseInWorld(self._pc))

    def _rest_state(self, idx: NDArray[np.int64]) -> NDArray[np.float64]:
        rows = self._get_state(idx)
        rows[:, :8] = np.concatenate((self._q_start, np.zeros(4)))
        return rows

    def _reset_copies(
        self, idx: NDArray[np.int64], xi: NDArray[np.float64], rngs: list[np.random.Generator]
    ) -> NDArray[np.float32]:
        if len(idx) == self.num_envs:  # a full reset restarts the clock, as the single env does
            self._context.SetTime(0.0)
        full = self._plant.GetPositionsAndVelocities(self._pc).copy()
        full[self._columns[idx]] = np.concatenate((self._q_start, np.zeros(4)))
        self._plant.SetPositionsAndVelocities(self._pc, full)
        for i in idx:
            self._desired[i].set(np.concatenate([self._q_start, np.zeros(4)]))
        if len(idx) == self.num_envs:
            self._simulator.Initialize()
        obs = []
        for k, i in enumerate(idx):
            if self._sensors is not None:
                self._sensors[i].reset(rngs[k])
            self._histories[i].reset(full[self._columns[i, :4]], self._wrench(i))
            self._d[i] = math.hypot(*self._gear_error(i))
            obs.append(self._histories[i].observation())
        return np.array(obs)

    def _get_state(self, idx: NDArray[np.int64]) -> NDArray[np.float64]:
        full = self._plant.GetPositionsAndVelocities(self._pc)
        history = np.array([self._history_state(i) for i in idx]).reshape(len(idx), -1)
        return np.concatenate((full[self._columns[idx]], history, self._d[idx, None]), axis=1)

    def _history_state(self, i: int) -> NDArray[np.float64]:
        """Copy i's history (poses, and with wrench sensing its wrenches, its tare and the sensor's
        bias), flat."""
        h = self._histories[i]
        if self._sensors is None:
            return h.poses.ravel()
        return np.concatenate((h.poses.ravel(), h.wrenches.ravel(), h.tare, self._sensors[i].bias))

    def _set_state(self, idx: NDArray[np.int64], state: NDArray[np.float64]) -> None:
        full = self._plant.GetPositionsAndVelocities(self._pc).copy()
        full[self._columns[idx]] = state[:, :8]
        self._plant.SetPositionsAndVelocities(self._pc, full)
        rows = self.law.history * 4
        for k, i in enumerate(idx):
            self._histories[i].poses[:] = state[k, 8 : 8 + rows].reshape(-1, 4)
            if self._sensors is not None:
                self._histories[i].wrenches[:] = state[k, 8 + rows : 8 + 2 * rows].reshape(-1, 4)
                self._histories[i].tare[:] = state[k, 8 + 2 * rows : 12 + 2 * rows]
                self._sensors[i].bias = state[k, 12 + 2 * rows : -1].copy()
            self._d[i] = state[k, -1]

    def _make_twin(self) -> GearInsertionVectorEnv:
        twin = GearInsertionVectorEnv(1, self.config)
        twin._rngs[0] = np.random.default_rng(0)  # its sensor noise while it replays a copy's step
        return twin

    def _step_copies(self, actions: NDArray[np.float64]):
        n, c = self.num_envs, self.config
        full = self._plant.GetPositionsAndVelocities(self._pc)
        for i in range(n):  # the impedance target from the measured pose (InsertionLaw, per copy)
            target = self.law.target(actions[i], full[self._columns[i, :4]])
            self._desired[i].set(np.concatenate([target, np.zeros(4)]))
        t = self._context.get_time()
        try:
            advance(self._simulator, t + c.control_dt, self._owner)
        except Exception:
            self._context.SetTime(t)  # the step can be repeated
            raise
        full = self._plant.GetPositionsAndVelocities(self._pc)
        obs = np.zeros((n, *self.single_observation_space.shape), dtype=np.float32)
        reward = np.zeros(n)
        seated_all = np.zeros(n, dtype=bool)
        lateral_all, height_all = np.zeros(n), np.zeros(n)
        high = self.single_observation_space.high
        for i in range(n):
            pose = full[self._columns[i, :4]]
            if not np.all(np.isfinite(pose)):
                self._step_failures[i] = f"non-finite tool pose {pose} after the step"
                reward[i] = np.nan
                continue
            self._histories[i].push(pose, self._wrench(i))
            lateral, height = self._gear_error(i)
            seated = is_seated(lateral, height)
            d = math.hypot(lateral, height)
            reward[i] = insertion_reward(c, seated, d, self._d[i])
            self._d[i] = d
            obs[i] = self._histories[i].observation()
            if not np.all(np.abs(obs[i]) <= high):
                self._step_failures[i] = f"observation left its bounds: tool pose {self._histories[i].poses[0]}"
                reward[i] = np.nan
            seated_all[i], lateral_all[i], height_all[i] = seated, lateral, height
        extra = {"seated": seated_all, "lateral_error": lateral_all, "height_error": height_all}
        return obs, reward, np.zeros(n, dtype=bool), extra
