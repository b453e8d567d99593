"""What the samplers updated by gradient steps on a batch (GoFlow, LSDR) share: batch-standardized
returns, their update diagnostics, and the config of a saved state with older layouts folded in.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from assembly.samplers import base_diagnostics

__all__ = ["config_from_state", "standardize_returns", "update_diagnostics"]


def standardize_returns(returns: NDArray[np.float64]) -> tuple[NDArray[np.float64], bool]:
    """Per-batch standardized returns (mean 0, std 1) and whether they carry any signal.

    All-equal returns (or a single one) give zeros, never NaN. The returns are first divided by
    their largest magnitude so that huge finite values (1e300) cannot overflow the mean or variance.
    """
    r = np.asarray(returns, dtype=np.float64)
    scale = float(np.max(np.abs(r))) if r.size else 0.0
    if r.size < 2 or scale == 0.0:
        return np.zeros_like(r), False
    r = r / scale
    centred = r - r.mean()
    std = float(np.sqrt(np.mean(centred**2)))
    if not math.isfinite(std) or std <= 1e-12:
        return np.zeros_like(r), False
    return centred / std, True


def update_diagnostics(
    returns: NDArray[np.float64],
    entropy: float,
    *,
    first: dict[str, float] | None,
    last: dict[str, float],
    steps: int,
    skipped: int,
    reverted: bool,
    has_signal: bool,
    update_index: int,
    t0: float,
    **extra: Any,
) -> dict[str, Any]:
    """What a sampler updated by gradient steps reports (GoFlow, LSDR): the protocol's diagnostics,
    the first and last step's loss, the step counts, whether it reverted, and `extra`."""
    diag = base_diagnostics(returns, entropy)
    diag.update(
        {
            "loss": last.get("loss", math.nan),
            "loss_first": math.nan if first is None else first["loss"],
            **extra,
            "steps": steps,
            "skipped_steps": skipped,
            "reverted": reverted,
            "returns_have_signal": has_signal,
            "update_index": update_index,
            "time_s": time.perf_counter() - t0,
        }
    )
    return diag


def config_from_state(state: Mapping[str, Any]) -> dict[str, Any]:
    """The config dict of a GoFlowSampler or LSDRSampler state, with the weights that older
    states kept beside it (top-level "alpha", "beta") folded in."""
    config = dict(state["config"])
    for key in ("alpha", "beta"):
        if key in state and key not in config:
            config[key] = state[key]
    return config
