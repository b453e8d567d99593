"""Transition simulators for offline parameter estimation: reset to a logged state, apply the
logged action under parameters xi, return the next state.

Every simulator keeps one contract (`base.TransitionSim`); `base.BatchTransitionSim` owns the batch
loop and each model implements its hooks (one module per model: `point_mass`, `cartpole`, `ant`,
`panda_arm`, `locomotion`, `quadrotor`, `anymal`, `gear_insertion`); `parallel.ParallelTransitionSim`
splits batches over processes; `registry` holds the ids.

Simulators are registered by name, lazily like gymnasium's `register`: an entry point is a
"module:Class" string imported on first use, so listing the ids imports no Drake.

    sim = make_transition_sim("goflow/Cartpole-v0")
    next_states = sim.step(states, actions, xi)
"""

from __future__ import annotations

from assembly.transition.base import BatchTransitionSim, TransitionSim, check_step_args, xi_groups
from assembly.transition.parallel import ParallelTransitionSim
from assembly.transition.registry import TRANSITION_SIMS, make_transition_sim, register_transition_sim

__all__ = [
    "TransitionSim",
    "BatchTransitionSim",
    "ParallelTransitionSim",
    "TRANSITION_SIMS",
    "check_step_args",
    "xi_groups",
    "register_transition_sim",
    "make_transition_sim",
]
