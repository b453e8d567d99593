"""GoFlow's settings: one frozen dataclass for the flow, the update and the three modes' options
(docs/learning.md#goflow-modes), and the config of a saved GoFlow state of an older layout.

The fields stay flat (not one dataclass per mode): they are the JSON layout of every saved
sampler state and skill file, and the names `--method-kwarg KEY=VALUE` sets.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from goflow_common.checks import check_choice, check_int, check_layer_sizes, check_number
from goflow_common.config import config_to_dict, config_with_overrides
from goflow_common.errors import InputError
from learning.samplers.gradient_update import config_from_state

__all__ = ["FEASIBLE_MODELS", "MODES", "GoFlowConfig", "classifier_width", "goflow_config_of"]


#: What an update optimizes (GoFlowConfig.mode).
MODES: tuple[str, ...] = ("entropy", "constrained", "paper")
#: How the constrained mode estimates the feasible set (GoFlowConfig.feasible_model).
FEASIBLE_MODELS: tuple[str, ...] = ("classifier", "knn")


@dataclass(frozen=True)
class GoFlowConfig:
    """GoFlow flow architecture and update settings (defaults: the GoFlow paper and its code)."""

    alpha: float = 1.0  # entropy weight (the seed swept {0.1, 0.5, 1.0, 1.5, 2.0})
    # weight of KL(q_old || q), a trust region to the flow before the update (the authors' released
    # configs use 0.0 for Cartpole/Anymal and 1.0 for Ant; the entropy and constrained modes fit a
    # target that changes only as evidence accumulates, and need none)
    beta: float = 0.0
    transforms: int = 3
    hidden_features: tuple[int, ...] = (64, 64)
    bins: int = 8
    base_scale: float = 2.5  # std of the Gaussian base in box coordinates (docs/learning.md#goflow)
    lr: float = 1e-3
    steps: int = 100  # K gradient steps per update
    # The GoFlow authors' code uses ~10k samples for H_hat and KL_hat. On a 2-core CPU that makes
    # one update 16-34 s (d = 2..5), far above the 5 % share of training time the sampler may take.
    # The uniform samples are fresh at every step, so over K = 100 steps H_hat averages 51k points;
    # the KL draws are a fresh subset of a pool of `kl_pool` pre-update draws at every step. 512
    # per step makes an update 3.4x faster than 2048 (1.7 s vs 5.7 s, d = 3, B = 64, one thread:
    # docs/learning.md) and the sampler tests pass unchanged.
    entropy_samples: int = 512  # uniform samples per step for H_hat
    kl_samples: int = 512  # pre-update flow samples per step for KL_hat (a subset of the pool)
    kl_pool: int = 4096  # pre-update flow draws per update, for KL_hat and the reported KL
    report_samples: int = 4096  # fixed-seed flow draws behind entropy()
    grad_clip: float = 1.0
    max_redraws: int = 20  # redraw rounds for draws that left the box before giving up
    seed: int = 0  # flow initialization and the update's internal Monte Carlo draws
    # What an update optimizes (docs/learning.md#goflow-modes):
    #   "entropy": E_p[r] + alpha H(p) over the box, r the signal scaled to [0, 1]; optimum p* ~ exp(r / alpha);
    #   "constrained": max H(p) subject to E_p[success] >= 1 - delta (0/1 signals); optimum (1 - delta) x
    #       uniform on the feasible set + delta x uniform on the rest of the box;
    #   "paper": the GoFlow paper's update (batch-standardized returns as weights of log p on the batch).
    mode: str = "entropy"
    delta: float = 0.002  # constrained mode: the mass allowed outside the feasible set, in (0, 1)
    signal_range: tuple[float, float] | None = None  # (lo, hi) scaled onto [0, 1]; None: the range seen so far
    memory: int = 16384  # evaluated rows kept as evidence (entropy and constrained modes)
    # rows kept beyond `memory` because they lay on the edge between the classes (scaled signal >= 0.5
    # or not) when they left the window: a row of the other class among their `neighbours` nearest
    # (SignalMemory; docs/learning.md, "Boundary rows"); 0: none
    boundary_memory: int = 0
    neighbours: int = 5  # k of the nearest-neighbour signal estimate
    outside_weight: float = 1.0  # constrained mode: weight of the flow's excess density outside the feasible set
    # constrained mode: estimated success probability from which a point counts as feasible (the
    # classifier's even-odds contour; the k-NN vote of 5 rows erodes less at 0.8, its old default)
    feasible_level: float = 0.5
    # constrained mode: the level follows the constraint by dual ascent (docs/learning.md#goflow-modes).
    # Each update first scores the current F-hat on the new batch, rows it has not been fitted to: every
    # held-out row in F-hat moves the level's logit by level_step x (failed - leak_target), so the level
    # settles where the share of F-hat's rows that fail is leak_target; level_step 0 keeps feasible_level.
    leak_target: float = 0.004
    level_step: float = 0.2
    # constrained mode: how the feasible set F-hat is estimated from the evidence, "knn" (the
    # k-nearest-neighbour vote) or "classifier" (an MLP fitted to the rows, learning.samplers.feasibility)
    feasible_model: str = "classifier"
    classifier_steps: int = 100  # Adam steps of the classifier per update (it continues from the last fit)
    # the classifier's layer sizes; None: `classifier_width(d)`, (64, 64) up to 4 parameters and
    # (128, 128) from 5 (measured on the 6-D ellipsoid, docs/learning.md#goflow-modes)
    classifier_hidden: tuple[int, ...] | None = None
    # constrained mode: the sampler is the flow truncated to F-hat with mass 1 - delta, plus delta
    # uniform on the rest of the box (docs/learning.md#goflow-modes); False: the flow alone
    truncate: bool = True
    # constrained mode, truncated: the share of the mass in F-hat drawn uniformly on F-hat, a floor
    # under the flow's density there (0: the flow alone shapes it; docs/learning.md#goflow-modes)
    floor: float = 0.2
    proposal_samples: int = 2048  # per proposal component (uniform, the flow, around successes) per update
    fit_batch: int = 512  # points resampled from the weighted proposal at each of the K steps

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "hidden_features", check_layer_sizes(self.hidden_features, "GoFlowConfig.hidden_features")
        )
        for name in ("alpha", "beta"):
            object.__setattr__(self, name, check_number(getattr(self, name), f"GoFlowConfig.{name}", 0.0))
        for name in (
            "transforms",
            "bins",
            "steps",
            "entropy_samples",
            "kl_samples",
            "kl_pool",
            "report_samples",
            "max_redraws",
        ):
            check_int(getattr(self, name), f"GoFlowConfig.{name}", 1)
        check_int(self.bins, "GoFlowConfig.bins", 2)
        for name in ("base_scale", "lr", "grad_clip"):
            check_number(getattr(self, name), f"GoFlowConfig.{name}", 0.0, low_open=True)
        check_int(self.seed, "GoFlowConfig.seed", 0)
        check_choice(self.mode, MODES, "GoFlowConfig.mode")
        check_number(self.delta, "GoFlowConfig.delta", 0.0, 1.0, low_open=True, high_open=True)
        check_number(self.outside_weight, "GoFlowConfig.outside_weight", 0.0)
        check_number(self.feasible_level, "GoFlowConfig.feasible_level", 0.0, 1.0, low_open=True)
        check_number(self.leak_target, "GoFlowConfig.leak_target", 0.0, 1.0, low_open=True, high_open=True)
        check_number(self.level_step, "GoFlowConfig.level_step", 0.0)
        check_choice(self.feasible_model, FEASIBLE_MODELS, "GoFlowConfig.feasible_model")
        check_int(self.classifier_steps, "GoFlowConfig.classifier_steps", 1)
        if self.classifier_hidden is not None:
            object.__setattr__(
                self, "classifier_hidden", check_layer_sizes(self.classifier_hidden, "GoFlowConfig.classifier_hidden")
            )
        if not isinstance(self.truncate, bool):
            raise InputError(f"GoFlowConfig.truncate = {self.truncate!r}; expected true or false")
        check_number(self.floor, "GoFlowConfig.floor", 0.0, 1.0, high_open=True)
        for name in ("memory", "neighbours", "proposal_samples", "fit_batch"):
            check_int(getattr(self, name), f"GoFlowConfig.{name}", 1)
        check_int(self.boundary_memory, "GoFlowConfig.boundary_memory", 0)
        if self.signal_range is not None:
            pair = tuple(self.signal_range)
            if len(pair) != 2:
                raise InputError(f"GoFlowConfig.signal_range = {self.signal_range!r}; expected (lo, hi) or None")
            lo = check_number(pair[0], "GoFlowConfig.signal_range[0]")
            hi = check_number(pair[1], "GoFlowConfig.signal_range[1]")
            if not hi > lo:
                raise InputError(f"GoFlowConfig.signal_range = {self.signal_range!r}; expected lo < hi")
            object.__setattr__(self, "signal_range", (lo, hi))

    def to_dict(self) -> dict[str, Any]:
        """JSON-serializable fields."""
        return config_to_dict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> GoFlowConfig:
        """Inverse of `to_dict` (unknown keys raise UnknownOptionError, a ValueError)."""
        return config_with_overrides(cls, d)

    def classifier_layers(self, dim: int) -> tuple[int, ...]:
        """The success classifier's layer sizes on `dim` parameters: `classifier_hidden`, or
        `classifier_width(dim)` where it is None."""
        return self.classifier_hidden or classifier_width(dim)

    # fields that define the flow's parameter shapes and density (must match to load a state)
    ARCHITECTURE = ("transforms", "hidden_features", "bins", "base_scale")


def classifier_width(dim: int) -> tuple[int, int]:
    """The constrained mode's default success-classifier layers for `dim` parameters: (64, 64) up
    to 4, (128, 128) from 5 (the 6-D ellipsoid's recall needs the wider one; docs/learning.md)."""
    return (64, 64) if dim <= 4 else (128, 128)


def goflow_config_of(state: Mapping[str, Any]) -> dict[str, Any]:
    """The config dict of a GoFlowSampler state (`config_from_state`), with the settings that
    states saved before a mode or option existed were made with filled in."""
    config = config_from_state(state)
    if state.get("type") != "GoFlowSampler":
        return config
    if "mode" not in config:
        config["mode"] = "paper"  # saved before the modes existed: the paper's update made it
    if "feasible_model" not in config:
        # saved before the classifier and the truncation existed: the k-NN vote and the flow alone made it
        config["feasible_model"], config["truncate"] = "knn", False
        config.setdefault("feasible_level", 0.8)  # the k-NN vote's level of that time
    if "level_step" not in config:
        config["level_step"] = 0.0  # saved before the level followed the constraint: a fixed level made it
    if "floor" not in config:
        config["floor"] = 0.0  # saved before the floor existed: the flow alone shaped the mass in F-hat
    if "classifier_hidden" not in config:
        config["classifier_hidden"] = (64, 64)  # saved before the width followed the dimension
    return config
