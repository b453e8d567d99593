"""The insertion policy's observation and action law, in one place: what the policy sees (its
history of tool poses relative to the seated pose, newest first, with finite-difference
velocities, and with `sensing="wrench"` the estimated external wrench at each of those times,
assembly.wrench_sensor) and what its action does (an impedance target = the measured tool pose plus the
scaled action, kept in a workspace around the seated pose). `GearInsertionEnv` and the planner's
insert skill both use it, so a policy gives the same action for the same history in either.

Poses are (x, y, z [m], yaw [rad]) of the tool pointing down; `seated` is the tool pose at which a
centred gear sits on its shaft.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from goflow_common.checks import check_choice, check_finite_array, check_int
from goflow_common.errors import InputError

#: What the policy observes: tool poses only (the blind skills), or poses and the external wrench.
SENSING = ("pose", "wrench")


@dataclass(frozen=True)
class InsertionLaw:
    """seated: the seated tool pose (4,); action_scale, workspace: per axis (x, y, z, yaw);
    history: poses the policy sees; control_dt: its period [s]; sensing: "pose" or "wrench" (each
    row also holds the wrench (Fx, Fy, Fz, Mz) divided by `wrench_scale` [N, N, N, N m])."""

    seated: tuple[float, float, float, float]
    action_scale: tuple[float, float, float, float]
    workspace: tuple[float, float, float, float]
    history: int
    control_dt: float
    sensing: str = "pose"
    wrench_scale: tuple[float, float, float, float] = (10.0, 10.0, 10.0, 1.0)

    def __post_init__(self) -> None:
        for name in ("seated", "action_scale", "workspace"):
            check_finite_array(getattr(self, name), f"InsertionLaw.{name}", (4,))
        check_int(self.history, "InsertionLaw.history", 2)
        if not (np.isfinite(self.control_dt) and self.control_dt > 0):
            raise InputError(f"InsertionLaw.control_dt = {self.control_dt}; expected > 0 s")
        check_choice(self.sensing, SENSING, "InsertionLaw.sensing")
        check_finite_array(self.wrench_scale, "InsertionLaw.wrench_scale", (4,), low=1e-9)

    @property
    def row_size(self) -> int:
        """Numbers per history row: pose and velocity (8), and the wrench (4) when sensed."""
        return 12 if self.sensing == "wrench" else 8

    def relative(self, tool_pose: ArrayLike) -> NDArray[np.float64]:
        """A tool pose relative to the seated one (yaw wrapped to [-pi, pi))."""
        rel = np.asarray(tool_pose, dtype=float) - np.asarray(self.seated)
        rel[3] = (rel[3] + np.pi) % (2 * np.pi) - np.pi
        return rel

    def target(self, action: ArrayLike, tool_pose: ArrayLike) -> NDArray[np.float64]:
        """The impedance target for `action` (4,) in [-1, 1] (clipped) at measured `tool_pose`."""
        offset = self.relative(tool_pose) + np.clip(action, -1.0, 1.0) * np.asarray(self.action_scale)
        workspace = np.asarray(self.workspace)
        return np.clip(offset, -workspace, workspace) + np.asarray(self.seated)


class PoseHistory:
    """The policy's observation state under `law`: `reset(tool_pose, wrench)` at the start, `push`
    after each control period, `observation()` the flat (history x law.row_size) vector, newest
    row first: (pose relative to seated, (pose - previous pose) / control_dt, and with wrench
    sensing (wrench - tare) / wrench_scale), the oldest row's velocity 0, rows before the first
    zero. `wrench` (Fx, Fy, Fz [N], Mz [N m]) is required with wrench sensing and refused without.
    The tare is the wrench at `reset`, in the air before any contact: what a robot zeroes its
    force reading with before a contact task, so that the estimate's bias and the held gear's
    weight drop out and the policy sees the contact alone."""

    def __init__(self, law: InsertionLaw) -> None:
        self.law = law
        self.poses = np.zeros((law.history, 4))
        self.wrenches = np.zeros((law.history, 4))
        self.tare = np.zeros(4)

    def _checked(self, wrench: ArrayLike | None) -> NDArray[np.float64]:
        """`wrench` (4,) as given, zeros for a pose-only history; InputError if it is missing or
        not wanted."""
        if self.law.sensing == "pose":
            if wrench is not None:
                raise InputError("a wrench was given to a pose-only history; expected wrench=None")
            return np.zeros(4)
        if wrench is None:
            raise InputError("a wrench-sensing history needs the wrench (Fx, Fy, Fz [N], Mz [N m]) at every push")
        return check_finite_array(wrench, "wrench", (4,))

    def reset(self, tool_pose: ArrayLike, wrench: ArrayLike | None = None) -> None:
        self.poses[:] = 0.0
        self.wrenches[:] = 0.0
        self.poses[0] = self.law.relative(tool_pose)
        self.tare[:] = self._checked(wrench)

    def push(self, tool_pose: ArrayLike, wrench: ArrayLike | None = None) -> None:
        self.poses[1:] = self.poses[:-1]
        self.wrenches[1:] = self.wrenches[:-1]
        self.poses[0] = self.law.relative(tool_pose)
        self.wrenches[0] = (self._checked(wrench) - self.tare) / np.asarray(self.law.wrench_scale)

    def observation(self) -> NDArray[np.float32]:
        velocities = np.zeros_like(self.poses)
        velocities[:-1] = (self.poses[:-1] - self.poses[1:]) / self.law.control_dt
        rows = [self.poses, velocities] + ([self.wrenches] if self.law.sensing == "wrench" else [])
        return np.concatenate(rows, axis=1).reshape(-1).astype(np.float32)


__all__ = ["SENSING", "InsertionLaw", "PoseHistory"]
