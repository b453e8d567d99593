"""The estimate file that `goflow estimate` writes and `goflow train`, `evaluate` and `collect`
read (`--sampler-file`): strict JSON {"format": "goflow-estimate", "version": 1, "method",
"env_id", "sampler": EstimatedSampler state_dict, "info": {...}}.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from assembly.params import ParamSpace
from goflow_common.errors import FileFormatError, InputError
from goflow_common.files import read_json, write_json
from learning.samplers.estimated import EstimatedSampler

__all__ = [
    "ESTIMATE_FORMAT",
    "save_estimate",
    "load_estimate",
    "check_estimate_space",
    "load_estimate_for",
    "estimate_source",
]

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


def check_estimate_space(sampler: EstimatedSampler, path: str | Path, space: ParamSpace, env: str) -> None:
    """An estimate drives an env (or simulator) of the same ParamSpace only: InputError naming the
    file, `env` and every difference (env vs file) otherwise."""
    if sampler.space != space:
        raise InputError(
            f"--sampler-file {path}: estimated over another ParamSpace than {env}'s (env vs file): "
            + "; ".join(space.diff(sampler.space))
        )


def load_estimate_for(path: str | Path, space: ParamSpace, env: str) -> tuple[EstimatedSampler, dict[str, Any]]:
    """`load_estimate`, then `check_estimate_space` against `space` (the ParamSpace of `env`):
    (the sampler, the whole file as a dict). The errors of both."""
    sampler, doc = load_estimate(path)
    check_estimate_space(sampler, path, space, env)
    return sampler, doc


def estimate_source(path: str | Path, sampler: EstimatedSampler, doc: Mapping[str, Any]) -> dict[str, Any]:
    """What a result drawn from an estimate file records of it (plain JSON): the path, the SHA-256
    of its bytes, its method and env id, and the distribution itself (its `to_dict()`), so that the
    source can be rebuilt without the file."""
    return {
        "kind": "estimate",
        "file": str(path),
        "sha256": hashlib.sha256(Path(path).read_bytes()).hexdigest(),
        "method": doc.get("method"),
        "env_id": doc.get("env_id"),
        "distribution": sampler.dist.to_dict(),
    }
