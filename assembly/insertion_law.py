"""The insertion policy's observation and action law, in one place: what the policy sees (its
history of tool poses relative to the seated pose, newest first, with finite-difference
velocities) and what its action does (an impedance target = the measured tool pose plus the
scaled action, kept in a workspace around the seated pose). `GearInsertionEnv` and the planner's
insert skill both use it, so a policy gives the same action for the same history in either.

Poses are (x, y, z [m], yaw [rad]) of the tool pointing down; `seated` is the tool pose at which a
centred gear sits on its shaft.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from goflow_common.checks import check_finite_array, check_int
from goflow_common.errors import InputError


@dataclass(frozen=True)
class InsertionLaw:
    """seated: the seated tool pose (4,); action_scale, workspace: per axis (x, y, z, yaw);
    history: poses the policy sees; control_dt: its period [s]."""

    seated: tuple[float, float, float, float]
    action_scale: tuple[float, float, float, float]
    workspace: tuple[float, float, float, float]
    history: int
    control_dt: float

    def __post_init__(self) -> None:
        for name in ("seated", "action_scale", "workspace"):
            check_finite_array(getattr(self, name), f"InsertionLaw.{name}", (4,))
        check_int(self.history, "InsertionLaw.history", 2)
        if not (np.isfinite(self.control_dt) and self.control_dt > 0):
            raise InputError(f"InsertionLaw.control_dt = {self.control_dt}; expected > 0 s")

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
    """The policy's observation state under `law`: `reset(tool_pose)` at the start, `push` after
    each control period, `observation()` the flat (history x 8) vector, newest row first:
    (pose relative to seated, (pose - previous pose) / control_dt), the oldest row's velocity 0."""

    def __init__(self, law: InsertionLaw) -> None:
        self.law = law
        self.poses = np.zeros((law.history, 4))

    def reset(self, tool_pose: ArrayLike) -> None:
        self.poses[:] = 0.0
        self.poses[0] = self.law.relative(tool_pose)

    def push(self, tool_pose: ArrayLike) -> None:
        self.poses[1:] = self.poses[:-1]
        self.poses[0] = self.law.relative(tool_pose)

    def observation(self) -> NDArray[np.float32]:
        velocities = np.zeros_like(self.poses)
        velocities[:-1] = (self.poses[:-1] - self.poses[1:]) / self.law.control_dt
        return np.concatenate([self.poses, velocities], axis=1).reshape(-1).astype(np.float32)


__all__ = ["InsertionLaw", "PoseHistory"]
