"""Learned domain-randomization samplers on the Sampler protocol (assembly.samplers)."""

from learning.samplers.adr import ADRSampler
from learning.samplers.doraemon import DORAEMONSampler
from learning.samplers.goflow import GoFlowSampler
from learning.samplers.lsdr import LSDRSampler

__all__ = ["ADRSampler", "DORAEMONSampler", "GoFlowSampler", "LSDRSampler"]
