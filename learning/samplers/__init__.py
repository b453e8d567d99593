"""Learned domain-randomization samplers on the Sampler protocol (assembly.samplers): ADR, LSDR,
DORAEMON, GoFlow, and fixed estimates; `learning.samplers.registry` builds any sampler by name.

Importing this package imports no sampler module (each pulls torch or scipy): import the one you
need, e.g. `from learning.samplers.goflow import GoFlowSampler`, or use the registry.
"""

from learning.samplers.registry import METHODS, SAMPLERS, make_sampler

__all__ = ["METHODS", "SAMPLERS", "make_sampler"]
