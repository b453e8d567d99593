"""Samplers by name: one registry, lazy like gymnasium's `register` (entry points are strings,
imported on first use), so that listing the names costs no import of torch or scipy.

    sampler = make_sampler("goflow", space, success_threshold=50.0, config={"alpha": 0.5})

Every sampler has one constructor signature, `Cls(space, success_threshold=None, config=None,
**overrides)` (assembly.samplers); `config` is checked against the sampler's config dataclass by
`goflow_common.config.config_with_overrides` (an unknown key is an UnknownOptionError naming the known
ones). A new sampler goes here with `register_sampler`.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from goflow_common.config import config_with_overrides
from goflow_common.errors import UnknownOptionError

__all__ = [
    "SamplerSpec",
    "SAMPLERS",
    "METHODS",
    "THRESHOLD_METHODS",
    "GRADIENT_METHODS",
    "SAMPLER_SIGNALS",
    "register_sampler",
    "sampler_spec",
    "sampler_class",
    "sampler_config",
    "make_sampler",
    "protocol_sampler_kwargs",
]

#: What a sampler may learn from: the episodes' returns, or their 0/1 successes (return >= J_T).
SAMPLER_SIGNALS: tuple[str, ...] = ("return", "success")


@dataclass(frozen=True)
class SamplerSpec:
    """A registered sampler.

    Arguments:
        name: the registry name (also the CLI's `--method` value for training methods).
        entry_point: "module:Class" of the sampler.
        config_entry_point: "module:ConfigClass" of its config dataclass.
        training: whether it is a domain-randomization method `goflow train` can use.
        threshold: it compares returns with J_T itself (learns from returns, needs J_T).
        gradient: it is updated by gradient steps on a batch of (xi, signal).
    """

    name: str
    entry_point: str
    config_entry_point: str
    training: bool = True
    threshold: bool = False
    gradient: bool = False


SAMPLERS: dict[str, SamplerSpec] = {}


def register_sampler(spec: SamplerSpec) -> None:
    """Add `spec` to the registry (ValueError if the name is taken)."""
    if spec.name in SAMPLERS:
        raise ValueError(f"a sampler named {spec.name!r} is already registered")
    SAMPLERS[spec.name] = spec


for _spec in (
    SamplerSpec("nodr", "assembly.samplers:NoDR", "assembly.samplers:NoDRConfig"),
    SamplerSpec("fulldr", "assembly.samplers:FullDR", "assembly.samplers:FullDRConfig"),
    SamplerSpec("adr", "learning.samplers.adr:ADRSampler", "learning.samplers.adr:ADRConfig", threshold=True),
    SamplerSpec("lsdr", "learning.samplers.lsdr:LSDRSampler", "learning.samplers.lsdr:LSDRConfig", gradient=True),
    SamplerSpec(
        "doraemon",
        "learning.samplers.doraemon:DORAEMONSampler",
        "learning.samplers.doraemon:DORAEMONConfig",
        threshold=True,
    ),
    SamplerSpec(
        "goflow",
        "learning.samplers.goflow:GoFlowSampler",
        "learning.samplers.goflow_config:GoFlowConfig",
        gradient=True,
    ),
    SamplerSpec(
        "estimated",
        "learning.samplers.estimated:EstimatedSampler",
        "learning.samplers.estimated:EstimatedSamplerConfig",
        training=False,
    ),
):
    register_sampler(_spec)

#: The domain-randomization methods `goflow train` / `experiment` can use, in table order.
METHODS: tuple[str, ...] = tuple(name for name, spec in SAMPLERS.items() if spec.training)
#: Methods that compare returns with J_T themselves: they learn from returns, never 0/1 successes.
THRESHOLD_METHODS: tuple[str, ...] = tuple(name for name, spec in SAMPLERS.items() if spec.threshold)
#: Methods whose sampler is updated by gradient steps on a batch of (xi, signal).
GRADIENT_METHODS: tuple[str, ...] = tuple(name for name, spec in SAMPLERS.items() if spec.gradient)


def _load(entry_point: str) -> Any:
    module, _, attr = entry_point.partition(":")
    return getattr(importlib.import_module(module), attr)


def sampler_spec(name: str) -> SamplerSpec:
    """The registered spec of `name`; UnknownOptionError listing the registered names otherwise."""
    if name not in SAMPLERS:
        raise UnknownOptionError(f"unknown sampler {name!r}; expected one of {list(SAMPLERS)}")
    return SAMPLERS[name]


def sampler_class(name: str) -> type:
    """The sampler class registered as `name` (imported now)."""
    return _load(sampler_spec(name).entry_point)


def sampler_config(name: str, config: Any = None) -> Any:
    """The config dataclass of sampler `name` built from `config` (None, a mapping of its fields,
    or an instance), validated: use it to check options before any work starts."""
    spec = sampler_spec(name)
    return config_with_overrides(_load(spec.config_entry_point), config, owner=f"{name} sampler config")


def make_sampler(
    name: str, space: Any, success_threshold: float | None = None, config: Mapping[str, Any] | Any = None
) -> Any:
    """The sampler `name` over ParamSpace `space` with J_T `success_threshold` and `config` (its
    config dataclass, a mapping of its fields, or None for the defaults)."""
    return sampler_class(name)(space, success_threshold, sampler_config(name, config))


def protocol_sampler_kwargs(method: str, sampler_kwargs: dict[str, Any]) -> dict[str, Any]:
    """The sampler options the protocol runs `method` with: the user's, plus DORAEMON's
    `proposal="uniform"` (the protocol updates it with the uniform validation batch, so its
    importance weights are p'/U) unless the user set it."""
    if method == "doraemon":
        return {"proposal": "uniform", **sampler_kwargs}
    return dict(sampler_kwargs)
