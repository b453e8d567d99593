"""The registry of transition simulators: env id -> "module:Class", imported on first use (like
gymnasium's `register`), so listing the ids imports no Drake. `assembly.transition` re-exports it.
"""

from __future__ import annotations

import importlib
from typing import Any

from assembly.transition.base import TransitionSim
from goflow_common.errors import UnknownOptionError

__all__ = ["TRANSITION_SIMS", "make_transition_sim", "register_transition_sim"]

#: env id -> "module:Class" of its transition simulator (imported by `make_transition_sim`).
TRANSITION_SIMS: dict[str, str] = {}


def register_transition_sim(env_id: str, entry_point: str) -> None:
    """Add a simulator to the registry.

    Arguments:
        env_id: the id, e.g. "goflow/PandaArm-v0".
        entry_point: "module:Class"; the class is called with `make_transition_sim`'s kwargs.

    Raises:
        ValueError: the id is taken, or the entry point is not "module:Class".
    """
    if env_id in TRANSITION_SIMS:
        raise ValueError(f"a transition simulator for {env_id!r} is already registered")
    module, sep, attr = entry_point.partition(":")
    if not (module and sep and attr):
        raise ValueError(f"entry point {entry_point!r}; expected 'module:Class'")
    TRANSITION_SIMS[env_id] = entry_point


for _env_id, _entry_point in (
    ("goflow/PointMass-v0", "assembly.transition.point_mass:PointMassSim"),
    ("goflow/Cartpole-v0", "assembly.transition.cartpole:CartpoleTransitionSim"),
    ("goflow/Ant-v0", "assembly.transition.ant:AntTransitionSim"),
    ("goflow/PandaArm-v0", "assembly.transition.panda_arm:PandaArmSim"),
    ("goflow/Hopper-v0", "assembly.transition.locomotion:HopperTransitionSim"),
    ("goflow/Walker2d-v0", "assembly.transition.locomotion:Walker2dTransitionSim"),
    ("goflow/HalfCheetah-v0", "assembly.transition.locomotion:HalfCheetahTransitionSim"),
    ("goflow/Humanoid-v0", "assembly.transition.locomotion:HumanoidTransitionSim"),
    ("goflow/Quadrotor-v0", "assembly.transition.quadrotor:QuadrotorTransitionSim"),
    ("goflow/Anymal-v0", "assembly.transition.anymal:AnymalTransitionSim"),
    ("goflow/GearInsertion-v0", "assembly.transition.gear_insertion:GearInsertionTransitionSim"),
):
    register_transition_sim(_env_id, _entry_point)


def make_transition_sim(env_id: str, **kwargs: Any) -> TransitionSim:
    """The transition simulator registered for `env_id`.

    Arguments:
        env_id: a registered id (`TRANSITION_SIMS`).
        kwargs: keyword arguments of the simulator's class (its config fields).

    Returns:
        A new simulator.

    Raises:
        UnknownOptionError: `env_id` is not registered (the message lists the known ids).
    """
    if env_id not in TRANSITION_SIMS:
        raise UnknownOptionError(f"no step-from-state simulator for env {env_id!r}; known: {sorted(TRANSITION_SIMS)}")
    module, _, attr = TRANSITION_SIMS[env_id].partition(":")
    return getattr(importlib.import_module(module), attr)(**kwargs)
