"""The offline dataset format: logged trajectories of (s, a, s') for parameter estimation.

One file, a NumPy `.npz` archive (`np.savez_compressed`), holding:

  meta          0-d string array: JSON with
                  "format": "goflow-transitions", "version": 1,
                  "env_id": the simulator that can replay it (assembly/transition/),
                  "params": [{"name", "low", "high", "unit", "nominal"}, ...]  (ParamSpace.to_dict),
                  "state_dim", "action_dim", "control_dt" [s],
                  "collection": how it was collected (xi distribution and its settings, policy,
                                episodes, steps per episode, seed, date, command)
  states        (N, ds) float64  logged state s_t (the simulator's full state)
  actions       (N, da) float64  normalized action a_t in [-1, 1]
  next_states   (N, ds) float64  logged state s_{t+1}
  episode       (N,)    int64    trajectory index in [0, E), non-decreasing
  true_xi       (E, d)  float64  the parameters each trajectory ran with, for EVALUATION ONLY

Estimators read a file through `load_dataset`, which returns the transitions without `true_xi`;
only `load_truth` (used by metrics and benchmarks) returns it. Both, and `save_dataset`, validate
everything (keys, shapes, dtypes, finite values, actions in [-1, 1], parameter names) and raise
`DatasetError` naming the file, the bad field, what it was and what was expected.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from assembly.params import ParamSpace
from goflow_common.checks import check_int
from goflow_common.errors import FileFormatError, InputError

__all__ = [
    "DatasetError",
    "TransitionDataset",
    "save_dataset",
    "load_dataset",
    "load_truth",
    "FORMAT",
    "VERSION",
    "segment_rows",
]

FORMAT = "goflow-transitions"
VERSION = 1
_ARRAYS = ("states", "actions", "next_states", "episode")


class DatasetError(FileFormatError):
    """A dataset file is missing, unreadable or malformed (a FileFormatError, hence a ValueError)."""


@dataclass
class TransitionDataset:
    """Logged transitions of one environment (no ground truth: see `load_truth`)."""

    env_id: str
    space: ParamSpace
    states: NDArray[np.float64]
    actions: NDArray[np.float64]
    next_states: NDArray[np.float64]
    episode: NDArray[np.int64]
    control_dt: float
    collection: dict[str, Any] = field(default_factory=dict)

    @property
    def num_transitions(self) -> int:
        """N, the number of (s, a, s') rows."""
        return int(len(self.states))

    @property
    def num_episodes(self) -> int:
        """E, the number of trajectories."""
        return int(self.episode.max()) + 1 if len(self.episode) else 0

    def episode_rows(self, e: int) -> NDArray[np.int64]:
        """Row indices of trajectory e, in time order."""
        return np.flatnonzero(self.episode == e)

    def delta_scale(self) -> NDArray[np.float64]:
        """Per-dimension std of s' - s (floored at 1e-6 x its largest entry + 1e-9): the unit in
        which estimators compare predicted and logged next states."""
        std = (self.next_states - self.states).std(axis=0)
        return np.maximum(std, 1e-6 * float(std.max()) + 1e-9)


def _meta(ds: TransitionDataset) -> dict[str, Any]:
    return {
        "format": FORMAT,
        "version": VERSION,
        "env_id": ds.env_id,
        **ds.space.to_dict(),
        "state_dim": int(ds.states.shape[1]),
        "action_dim": int(ds.actions.shape[1]),
        "control_dt": float(ds.control_dt),
        "collection": ds.collection,
    }


def save_dataset(path: str | Path, data: TransitionDataset, true_xi: NDArray[np.float64]) -> Path:
    """Validate and write `data` plus the per-trajectory truth (E, d) to `path` (.npz); return the path."""
    path = Path(path)
    _check_arrays(str(path), data, np.asarray(true_xi, dtype=np.float64))
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez_compressed(
        tmp,
        meta=np.array(json.dumps(_meta(data))),
        states=data.states,
        actions=data.actions,
        next_states=data.next_states,
        episode=data.episode.astype(np.int64),
        true_xi=np.asarray(true_xi, dtype=np.float64),
    )
    tmp.replace(path)
    return path


def _fail(path: str, msg: str) -> DatasetError:
    return DatasetError(f"dataset {path}: {msg}")


def _read(path: str | Path) -> tuple[str, dict[str, Any], dict[str, NDArray]]:
    """Open the archive and parse its meta; DatasetError on anything unreadable."""
    p = str(path)
    if not Path(path).is_file():
        raise _fail(p, "no such file (expected a .npz written by `goflow collect`)")
    if not zipfile.is_zipfile(path):  # np.load would take it for a pickle and suggest loading it unsafely
        raise _fail(
            p,
            "not a readable .npz archive (truncated or foreign file: not a zip archive); expected one "
            "written by `goflow collect`",
        )
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except ValueError as exc:
        if "pickle" in str(exc):
            raise _fail(p, "refused: it holds pickled objects; expected plain arrays (`goflow collect`)") from None
        raise _fail(p, f"not a readable .npz archive ({exc})") from exc
    except (zipfile.BadZipFile, OSError, EOFError) as exc:
        raise _fail(p, f"not a readable .npz archive ({exc})") from exc
    missing = [k for k in ("meta", *_ARRAYS, "true_xi") if k not in arrays]
    if missing:
        raise _fail(p, f"missing array(s) {missing}; expected {['meta', *_ARRAYS, 'true_xi']}")
    try:
        meta = json.loads(str(arrays["meta"]))
    except json.JSONDecodeError as exc:
        raise _fail(p, f"'meta' is not valid JSON ({exc})") from exc
    if not isinstance(meta, dict):
        raise _fail(p, f"'meta' must be a JSON object, got {type(meta).__name__}")
    if meta.get("format") != FORMAT or meta.get("version") != VERSION:
        raise _fail(
            p, f"format/version is {meta.get('format')!r}/{meta.get('version')!r}, expected {FORMAT!r}/{VERSION}"
        )
    for key in ("env_id", "params", "state_dim", "action_dim", "control_dt"):
        if key not in meta:
            raise _fail(p, f"'meta' lacks {key!r}")
    return p, meta, arrays


def _space(p: str, meta: dict[str, Any]) -> ParamSpace:
    try:
        return ParamSpace.from_dict({"params": meta["params"]})
    except (ValueError, TypeError) as exc:
        raise _fail(p, f"bad parameter list in 'meta': {exc}") from exc


def _check_arrays(p: str, ds: TransitionDataset, true_xi: NDArray[np.float64] | None) -> None:
    """Shapes, dtypes, finiteness and episode indexing of the arrays; DatasetError otherwise."""
    s, a, s2, ep = ds.states, ds.actions, ds.next_states, ds.episode
    for name, arr in (("states", s), ("actions", a), ("next_states", s2)):
        if arr.ndim != 2 or not np.issubdtype(arr.dtype, np.floating):
            raise _fail(p, f"{name!r} must be a 2-D float array, got shape {arr.shape} dtype {arr.dtype}")
    n = len(s)
    if n == 0:
        raise _fail(p, "holds no transitions (expected N >= 1)")
    if s2.shape != s.shape:
        raise _fail(p, f"'next_states' has shape {s2.shape}, expected {s.shape} like 'states'")
    if a.shape[0] != n:
        raise _fail(p, f"'actions' has {a.shape[0]} rows, expected {n} (one per transition)")
    if ep.shape != (n,) or not np.issubdtype(ep.dtype, np.integer):
        raise _fail(p, f"'episode' must be an integer array of shape ({n},), got shape {ep.shape} dtype {ep.dtype}")
    for name, arr in (("states", s), ("actions", a), ("next_states", s2)):
        bad = ~np.isfinite(arr)
        if bad.any():
            r, c = map(int, np.argwhere(bad)[0])
            raise _fail(
                p,
                f"{name!r} has {int(bad.sum())} non-finite value(s) (first: row {r}, column {c} "
                f"= {arr[r, c]}); every value must be finite",
            )
    outside = np.abs(a) > 1.0
    if outside.any():
        r, c = map(int, np.argwhere(outside)[0])
        raise _fail(
            p,
            f"'actions' has {int(outside.sum())} value(s) outside [-1, 1] (first: row {r}, column {c} "
            f"= {a[r, c]:g}); expected normalized actions in [-1, 1]",
        )
    if ep.min() < 0 or np.any(np.diff(ep) < 0):
        raise _fail(p, "'episode' must be non-negative and non-decreasing (trajectories stored in order)")
    e = int(ep.max()) + 1
    if len(np.unique(ep)) != e:
        raise _fail(p, f"'episode' skips indices: expected every trajectory 0..{e - 1} to have transitions")
    if true_xi is not None:
        if true_xi.shape != (e, ds.space.dim):
            raise _fail(
                p,
                f"'true_xi' has shape {true_xi.shape}, expected ({e}, {ds.space.dim}): one row per "
                f"trajectory, columns {ds.space.names}",
            )
        try:
            ds.space.validate(true_xi, what="'true_xi'")
        except ValueError as exc:
            raise _fail(p, str(exc)) from exc


def _dataset(p: str, meta: dict[str, Any], arrays: dict[str, NDArray]) -> TransitionDataset:
    ds = TransitionDataset(
        env_id=str(meta["env_id"]),
        space=_space(p, meta),
        states=arrays["states"],
        actions=arrays["actions"],
        next_states=arrays["next_states"],
        episode=arrays["episode"],
        control_dt=float(meta["control_dt"]),
        collection=dict(meta.get("collection", {})),
    )
    _check_arrays(p, ds, arrays["true_xi"])
    if ds.states.shape[1] != meta["state_dim"] or ds.actions.shape[1] != meta["action_dim"]:
        raise _fail(
            p,
            f"arrays have state/action dims {ds.states.shape[1]}/{ds.actions.shape[1]}, but "
            f"'meta' says {meta['state_dim']}/{meta['action_dim']}",
        )
    ds.states = ds.states.astype(np.float64)
    ds.actions = ds.actions.astype(np.float64)
    ds.next_states = ds.next_states.astype(np.float64)
    ds.episode = ds.episode.astype(np.int64)
    return ds


def load_dataset(path: str | Path, expected_space: ParamSpace | None = None) -> TransitionDataset:
    """Read and validate a dataset for estimation (the truth is NOT returned); if `expected_space`
    is given (the simulator's), the file's parameter names, bounds and units must equal it."""
    p, meta, arrays = _read(path)
    ds = _dataset(p, meta, arrays)
    if expected_space is not None and ds.space != expected_space:
        raise _fail(
            p,
            "its parameters differ from the simulator's (file vs simulator): "
            + "; ".join(ds.space.diff(expected_space)),
        )
    return ds


def load_truth(path: str | Path) -> tuple[ParamSpace, NDArray[np.float64]]:
    """The ParamSpace and per-trajectory true parameters (E, d): for evaluation only."""
    p, meta, arrays = _read(path)
    ds = _dataset(p, meta, arrays)
    return ds.space, arrays["true_xi"].astype(np.float64)


def segment_rows(data: TransitionDataset, length: int) -> NDArray[np.int64]:
    """Non-overlapping windows of `length` consecutive transitions of one trajectory, (S, length)."""
    check_int(length, "segment_length", 1)
    out = []
    for e in range(data.num_episodes):
        rows = data.episode_rows(e)
        for k in range(len(rows) // length):
            out.append(rows[k * length : (k + 1) * length])
    if not out:
        raise InputError(
            f"segment_length = {length}; no trajectory has {length} transitions (the longest has "
            f"{max(len(data.episode_rows(e)) for e in range(data.num_episodes))})"
        )
    return np.array(out, dtype=np.int64)
