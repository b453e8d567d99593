"""The estimate file that `goflow estimate` writes and training reads: strict JSON
{"format": "goflow-estimate", "version": 1, "method", "env_id", "sampler": EstimatedSampler
state_dict, "info": {...}}.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from assembly.params import ParamSpace
from goflow_common.errors import FileFormatError
from goflow_common.files import read_json, write_json
from learning.samplers.estimated import EstimatedSampler

__all__ = ["ESTIMATE_FORMAT", "save_estimate", "load_estimate"]

ESTIMATE_FORMAT = "goflow-estimate"


def save_estimate(
    path: str | Path, sampler: EstimatedSampler, method: str, env_id: str, info: Mapping[str, Any]
) -> Path:
    """Write the estimate file atomically as strict JSON; return its path.

    Raises ValueError (before writing) if any number in it is not finite."""
    doc = {
        "format": ESTIMATE_FORMAT,
        "version": 1,
        "method": method,
        "env_id": env_id,
        "sampler": sampler.state_dict(),
        "info": dict(info),
    }
    return write_json(path, doc, indent=None, nonfinite="error")


def load_estimate(path: str | Path) -> tuple[EstimatedSampler, dict[str, Any]]:
    """Read an estimate file: (the sampler, the whole file as a dict).

    Raises FileNotFoundError if missing, FileFormatError naming the file when it is not a strict
    JSON goflow estimate."""
    doc = read_json(path, "goflow estimate file (JSON written by `goflow estimate`)")
    if not isinstance(doc, dict) or doc.get("format") != ESTIMATE_FORMAT or "sampler" not in doc:
        raise FileFormatError(f"estimate {path}: not a {ESTIMATE_FORMAT!r} file (written by `goflow estimate`)")
    state = doc["sampler"]
    try:
        space = ParamSpace.from_dict(state["space"])
        sampler = EstimatedSampler(space, None, {"distribution": state["dist"]})
        sampler.load_state_dict(state)
    except (KeyError, TypeError, ValueError) as exc:
        raise FileFormatError(f"estimate {path}: malformed sampler ({exc})") from None
    return sampler, doc
