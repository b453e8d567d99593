"""The robot log: what a robot (or the simulated reality) recorded, in one validated container.

A log holds T samples of an n-joint arm: timestamps, measured joint positions, velocities and
link-side joint torques, and optionally the commanded torques, commanded joint targets, the
estimated external torques, the tool pose, an external wrench, the gripper width and phase labels.
Units and frames live in `meta`. The on-disk format (.npz of plain arrays plus a JSON metadata
string, loaded with allow_pickle=False) is documented in docs/sim2real.md; `sim2real.importers.load_log`
reads a log in that format or a foreign one.
"""

from __future__ import annotations

import copy
import dataclasses
import io
import json
import math
import os
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from goflow_common.checks import check_int
from goflow_common.errors import FileFormatError, InputError
from goflow_common.files import check_output_file, reject_json_constant, to_strict_json, write_atomic

__all__ = [
    "RobotLog",
    "PHASES",
    "UNITS",
    "FIELDS",
    "TORQUE_SIDES",
    "POSITION_SIDES",
    "MIN_SAMPLES",
    "LOG_FORMAT",
    "validate_log",
    "save_log",
    "read_npz_log",
    "slice_log",
    "with_meta",
]

#: Phase names, in the order of their integer labels in `RobotLog.phase`.
PHASES: tuple[str, ...] = ("free", "approach", "contact", "insertion")

#: The unit each signal must be given in (metadata "units" entries are checked against these).
UNITS: dict[str, str] = {
    "time": "s",
    "q": "rad",
    "dq": "rad/s",
    "tau": "N m",
    "tau_cmd": "N m",
    "q_cmd": "rad",
    "dq_cmd": "rad/s",
    "tau_ext": "N m",
    "tool_pose": "m",
    "tool_target": "m",
    "wrench": "N, N m",
    "gripper_width": "m",
}


@dataclasses.dataclass(frozen=True)
class RobotLog:
    """T samples of an n-joint robot; every array's first axis is time.

    time: (T,) [s], strictly increasing.
    q, dq: (T, n) measured joint positions [rad] and velocities [rad/s].
    tau: (T, n) measured joint torques [N m] (link side, Franka's tau_J) or None for a state log.
    tau_cmd: (T, n) commanded joint torques [N m] (Franka's tau_d, without gravity compensation
        removed: the total torque asked of the actuators) or None.
    q_cmd, dq_cmd: (T, n) commanded joint targets or None.
    tau_ext: (T, n) the robot's own external-torque estimate or None.
    tool_pose: (T, 4, 4) measured homogeneous base-to-tool transforms or None.
    tool_target: (T, 4, 4) commanded tool pose (a Cartesian impedance target) or None.
    wrench: (T, 6) external wrench on the tool (force, torque) in the base frame or None.
    gripper_width: (T,) [m] or None.
    phase: (T,) int labels indexing PHASES, or None when the log is not labelled.
    meta: plain JSON-compatible metadata: "robot", "joint_names", "units", "frames",
        "end_effector" ("none", "hand", "hand+gear_<size>"), "torque_side" ("link"/"motor"),
        "position_side" ("link" (default) / "motor": q, dq from a motor-side encoder through the gear),
        "controller" (law and gains, when known), "source", "license", "truth" (the injected
        effects of a simulated log, never read by the diagnosis).
    """

    time: NDArray[np.float64]
    q: NDArray[np.float64]
    dq: NDArray[np.float64]
    tau: NDArray[np.float64] | None = None
    tau_cmd: NDArray[np.float64] | None = None
    q_cmd: NDArray[np.float64] | None = None
    dq_cmd: NDArray[np.float64] | None = None
    tau_ext: NDArray[np.float64] | None = None
    tool_pose: NDArray[np.float64] | None = None
    tool_target: NDArray[np.float64] | None = None
    wrench: NDArray[np.float64] | None = None
    gripper_width: NDArray[np.float64] | None = None
    phase: NDArray[np.int64] | None = None
    meta: dict[str, Any] = dataclasses.field(default_factory=dict)

    @property
    def n_samples(self) -> int:
        return int(self.time.shape[0])

    @property
    def n_joints(self) -> int:
        return int(self.q.shape[1])


#: Every array field of RobotLog, in the order they are stored and documented.
FIELDS: tuple[str, ...] = (
    "time",
    "q",
    "dq",
    "tau",
    "tau_cmd",
    "q_cmd",
    "dq_cmd",
    "tau_ext",
    "tool_pose",
    "tool_target",
    "wrench",
    "gripper_width",
    "phase",
)
#: Values of meta["torque_side"]: torques measured after the gearbox (Franka's tau_J) or before it.
TORQUE_SIDES: tuple[str, ...] = ("link", "motor")
#: Values of meta["position_side"]: positions measured on the link (default) or the motor (reflected).
POSITION_SIDES: tuple[str, ...] = ("link", "motor")
#: The fewest samples a log may hold.
MIN_SAMPLES = 10
#: The value of the "format" entry of a saved log (.npz).
LOG_FORMAT = "goflow-robot-log-1"

_JOINT_FIELDS = ("q", "dq", "tau", "tau_cmd", "q_cmd", "dq_cmd", "tau_ext")
_REQUIRED = {"time": "timestamps [s]", "q": "measured joint positions [rad]", "dq": "measured joint velocities [rad/s]"}
_DRIVES = ("tau", "tau_cmd", "q_cmd")  # a log needs at least one of them: the input the model replays
# Plausibility bounds that catch wrong units even when meta claims the right ones: field -> (bound, unit, look-alike).
Q_LIMIT = 2 * math.pi + 0.5  # [rad]
DQ_LIMIT = 20.0  # [rad/s]
TAU_LIMIT = 1000.0  # [N m]
_LIMITS: dict[str, tuple[float, str, str]] = {
    "q": (Q_LIMIT, "rad", "degrees"),
    "q_cmd": (Q_LIMIT, "rad", "degrees"),
    "dq": (DQ_LIMIT, "rad/s", "deg/s"),
    "dq_cmd": (DQ_LIMIT, "rad/s", "deg/s"),
    "tau": (TAU_LIMIT, "N m", "mN m"),
    "tau_cmd": (TAU_LIMIT, "N m", "mN m"),
    "tau_ext": (TAU_LIMIT, "N m", "mN m"),
}
MAX_SPAN = 86400.0  # [s] one day
MAX_STEP = 1.0  # [s]
MAX_TRANSLATION = 10.0  # [m] tool positions beyond it look like millimetres
MAX_GRIPPER_WIDTH = 0.5  # [m]
ROTATION_TOL = 1e-3  # max |R^T R - I| of a tool pose's rotation part


# ---------------------------------------------------------------------------------------------- validation


def validate_log(log: RobotLog, n_joints: int | None = 7) -> RobotLog:
    """Check every contract of `log` and return it normalised: arrays float64 (phase int64),
    copied, and meta as plain strict-JSON data (numpy arrays and tuples become lists) with its
    defaults filled in ("units" for each present signal, "joint_names" panda_joint1..7 for a
    7-joint log, joint1..n otherwise).

    `n_joints`: the joint count the log must have (None: any, taken from q).

    Raises InputError (one line naming the field, the first bad sample and what was expected) for:
    a missing channel (time, q, dq, and one of tau / tau_cmd / q_cmd), a wrong shape or joint
    count, fewer than MIN_SAMPLES samples, a NaN or inf, timestamps not strictly increasing,
    meta units that differ from UNITS, values that look like other units (|q| > 2 pi + 0.5:
    degrees; |dq| > 20 rad/s; |tau| > 1000 N m: mN m; a time span over a day or a step over 1 s:
    ms or ns), phase labels outside range(len(PHASES)), tool poses that are not rigid transforms,
    and meta["end_effector"] / meta["torque_side"] / meta["position_side"] outside
    sim2real.arm.END_EFFECTORS / TORQUE_SIDES / POSITION_SIDES.
    """
    if not isinstance(log, RobotLog):
        raise InputError(f"log = {type(log).__name__}; expected a RobotLog")
    if n_joints is not None:
        check_int(n_joints, "n_joints", 1)
    arrays = _checked_arrays(log, n_joints)
    meta = _checked_meta(log.meta, arrays)  # before the ranges: declared wrong units are named as such
    time = arrays["time"]
    _check_time(time)
    _check_ranges(arrays, time)
    _check_poses(arrays, time)
    return RobotLog(**arrays, meta=meta)


def _as_array(value: Any, name: str) -> NDArray[Any]:
    if name == "phase":
        arr = np.array(value)
        if arr.dtype.kind in "iu":
            return arr.astype(np.int64)
        if arr.dtype.kind != "f":
            raise InputError(
                f"phase holds {arr.dtype} values; expected integer labels 0..{len(PHASES) - 1} "
                f"indexing PHASES {list(PHASES)}"
            )
        return arr
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} is not an array of numbers ({str(exc).splitlines()[0][:80]})") from None
    return arr


def _expected_shape(name: str, n_samples: int, n: int) -> tuple[int, ...]:
    if name in _JOINT_FIELDS:
        return (n_samples, n)
    return {"tool_pose": (n_samples, 4, 4), "tool_target": (n_samples, 4, 4), "wrench": (n_samples, 6)}.get(
        name, (n_samples,)
    )


def _checked_arrays(log: RobotLog, n_joints: int | None) -> dict[str, Any]:
    for name, what in _REQUIRED.items():
        if getattr(log, name) is None:
            raise InputError(f"{name} is missing; expected {what}")
    if all(getattr(log, name) is None for name in _DRIVES):
        raise InputError(
            "tau, tau_cmd and q_cmd are all missing; expected at least one of them (measured "
            "torques, commanded torques or commanded positions)"
        )
    time = _as_array(log.time, "time")
    if time.ndim != 1:
        raise InputError(f"time has shape {time.shape}; expected (T,)")
    if time.shape[0] < MIN_SAMPLES:
        raise InputError(f"time has {time.shape[0]} samples; expected at least {MIN_SAMPLES}")
    _check_finite("time", time, time)
    q = _as_array(log.q, "q")
    if q.ndim != 2:
        raise InputError(f"q has shape {q.shape}; expected (T, {n_joints or 'n'}) with T = {time.shape[0]} as time")
    n = q.shape[1] if n_joints is None else n_joints
    arrays: dict[str, Any] = {}
    for name in FIELDS:
        value = getattr(log, name)
        if value is None:
            arrays[name] = None
            continue
        arr = {"time": time, "q": q}.get(name)
        arr = _as_array(value, name) if arr is None else arr
        _check_shape(name, arr, _expected_shape(name, time.shape[0], n))
        _check_finite(name, arr, time)
        arrays[name] = arr
    return arrays


def _check_shape(name: str, arr: NDArray[Any], want: tuple[int, ...]) -> None:
    shown = "(" + ", ".join(str(s) for s in want) + ("," if len(want) == 1 else "") + ")"
    if arr.ndim != len(want):
        raise InputError(f"{name} has shape {arr.shape}; expected {shown}")
    if arr.shape[0] != want[0]:
        raise InputError(f"{name} has {arr.shape[0]} samples; expected {want[0]} (as time)")
    if name in _JOINT_FIELDS and arr.shape[1] != want[1]:
        raise InputError(f"{name} has {arr.shape[1]} joints; expected {want[1]}")
    if arr.shape != want:
        raise InputError(f"{name} has shape {arr.shape}; expected {shown}")


def _at(name: str, arr: NDArray[Any], mask: NDArray[np.bool_], time: NDArray[np.float64]) -> tuple[int, str, str]:
    """The first True entry of `mask`: (sample, 'name[i, j] = value', 'sample k, t = ... s')."""
    index = np.unravel_index(int(np.argmax(mask)), mask.shape)
    k = int(index[0])
    where = f"sample {k}" if name == "time" else f"sample {k}, t = {time[k]:.6g} s"
    return k, f"{name}[{', '.join(str(int(i)) for i in index)}] = {arr[index]:.6g}", where


def _check_finite(name: str, arr: NDArray[Any], time: NDArray[np.float64]) -> None:
    if arr.dtype.kind != "f":
        return
    bad = ~np.isfinite(arr)
    if bad.any():
        _, entry, where = _at(name, arr, bad, time)
        raise InputError(f"{name} is not finite: {entry} ({where}); expected finite numbers")


def _check_time(time: NDArray[np.float64]) -> None:
    dt = np.diff(time)
    back = np.flatnonzero(dt <= 0)
    if back.size:
        k = int(back[0]) + 1
        if dt[k - 1] == 0:
            run = int(np.argmax(dt[k - 1 :] != 0)) if np.any(dt[k - 1 :] != 0) else len(dt) - k + 1
            stall = f" and for {run} samples: a stalled logger clock" if run > 1 else ""
            raise InputError(
                f"time repeats at sample {k}: t = {float(time[k])!r} s as at sample {k - 1}{stall}; "
                "expected strictly increasing timestamps"
            )
        raise InputError(
            f"time goes back at sample {k}: t = {float(time[k])!r} s after {float(time[k - 1])!r} s; "
            "expected strictly increasing timestamps"
        )
    span = float(time[-1] - time[0])
    if span > MAX_SPAN:
        raise InputError(
            f"time spans {span:.6g} s; expected at most one day ({MAX_SPAN:g} s): the timestamps "
            "look like ms or ns, expected s"
        )
    jumps = np.flatnonzero(dt > MAX_STEP)
    if jumps.size:
        k = int(jumps[0]) + 1
        raise InputError(
            f"time jumps by {dt[k - 1]:.6g} s at sample {k}; expected steps of at most "
            f"{MAX_STEP:g} s: the timestamps look like ms or ns, expected s"
        )


def _check_ranges(arrays: dict[str, Any], time: NDArray[np.float64]) -> None:
    for name, (bound, unit, looks) in _LIMITS.items():
        arr = arrays[name]
        if arr is not None and (over := np.abs(arr) > bound).any():
            _, entry, where = _at(name, arr, over, time)
            raise InputError(
                f"{name} out of range: {entry} ({where}) is beyond +-{bound:.6g} {unit}; it looks "
                f"like {looks}, expected {unit}"
            )
    width = arrays["gripper_width"]
    if width is not None and (bad := (width > MAX_GRIPPER_WIDTH) | (width < -0.01)).any():
        _, entry, where = _at("gripper_width", width, bad, time)
        raise InputError(
            f"gripper_width out of range: {entry} ({where}); expected a width in [0, "
            f"{MAX_GRIPPER_WIDTH:g}] m (millimetres?)"
        )
    phase = arrays["phase"]
    if phase is not None:
        if phase.dtype.kind == "f":
            if (frac := phase != np.round(phase)).any():
                _, entry, where = _at("phase", phase, frac, time)
                raise InputError(
                    f"phase label {entry} ({where}) is not an integer; expected labels 0.."
                    f"{len(PHASES) - 1} indexing PHASES {list(PHASES)}"
                )
            phase = arrays["phase"] = phase.astype(np.int64)
        if (bad := (phase < 0) | (phase >= len(PHASES))).any():
            _, entry, where = _at("phase", phase, bad, time)
            raise InputError(
                f"phase label out of range: {entry} ({where}); expected 0..{len(PHASES) - 1} "
                f"indexing PHASES {list(PHASES)}"
            )


def _check_poses(arrays: dict[str, Any], time: NDArray[np.float64]) -> None:
    for name in ("tool_pose", "tool_target"):
        X = arrays[name]
        if X is None:
            continue
        last = np.abs(X[:, 3, :] - np.array([0.0, 0.0, 0.0, 1.0])).max(axis=1)
        if (bad := last > 1e-9).any():
            k = int(np.argmax(bad))
            raise InputError(
                f"{name} is not a rigid transform at sample {k} (t = {time[k]:.6g} s): last row "
                f"{X[k, 3].tolist()}; expected [0, 0, 0, 1]"
            )
        R = X[:, :3, :3]
        err = np.abs(np.einsum("kji,kjl->kil", R, R) - np.eye(3)).max(axis=(1, 2))
        if (bad := err > ROTATION_TOL).any():
            k = int(np.argmax(bad))
            raise InputError(
                f"{name} is not a rigid transform at sample {k} (t = {time[k]:.6g} s): its rotation "
                f"part is not orthonormal (max |R^T R - I| = {err[k]:.3g}; expected <= {ROTATION_TOL:g})"
            )
        if (bad := np.linalg.det(R) < 0).any():
            k = int(np.argmax(bad))
            raise InputError(
                f"{name} is not a rigid transform at sample {k} (t = {time[k]:.6g} s): its rotation "
                "part is a reflection (det = -1); expected a rotation"
            )
        if (bad := np.abs(X[:, :3, 3]) > MAX_TRANSLATION).any():
            k, i = np.unravel_index(int(np.argmax(bad)), bad.shape)
            raise InputError(
                f"{name} translation out of range: {name}[{k}, {i}, 3] = {X[k, i, 3]:.6g} (sample {k}, "
                f"t = {time[k]:.6g} s) is beyond +-{MAX_TRANSLATION:g} m; it looks like millimetres, "
                "expected m"
            )


def _lists(obj: Any) -> Any:
    """`obj` with numpy arrays (of any depth in dicts, lists, tuples) turned into nested lists."""
    if isinstance(obj, np.ndarray) and obj.ndim > 0:
        return obj.tolist()
    if isinstance(obj, dict):
        return {k: _lists(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_lists(v) for v in obj]
    return obj


def _checked_meta(meta: Any, arrays: dict[str, Any]) -> dict[str, Any]:
    if not isinstance(meta, dict):
        raise InputError(f"meta is a {type(meta).__name__}; expected a dict of JSON-compatible data")
    try:
        meta = to_strict_json(_lists(meta), nonfinite="error", where="meta")
        json.dumps(meta, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise InputError(f"meta is not strict JSON: {str(exc).splitlines()[0][:160]}") from None
    units = meta.get("units", {})
    if not isinstance(units, dict):
        raise InputError(f"meta units = {units!r}; expected a dict signal -> unit, as UNITS")
    for key, unit in units.items():
        if key not in UNITS:
            raise InputError(
                f"meta units names {key!r}, which is not a signal of a log; expected keys among {list(UNITS)}"
            )
        if unit != UNITS[key]:
            raise InputError(f"meta units for {key} = {unit!r}; expected {UNITS[key]!r}")
    meta["units"] = {**{name: UNITS[name] for name in FIELDS if name in UNITS and arrays[name] is not None}, **units}
    if "end_effector" in meta:
        from sim2real.arm import END_EFFECTORS

        if meta["end_effector"] not in END_EFFECTORS:
            raise InputError(f"meta end_effector = {meta['end_effector']!r}; expected one of {list(END_EFFECTORS)}")
    if "torque_side" in meta and meta["torque_side"] not in TORQUE_SIDES:
        raise InputError(f"meta torque_side = {meta['torque_side']!r}; expected one of {list(TORQUE_SIDES)}")
    if "position_side" in meta and meta["position_side"] not in POSITION_SIDES:
        raise InputError(f"meta position_side = {meta['position_side']!r}; expected one of {list(POSITION_SIDES)}")
    n = arrays["q"].shape[1]
    names = meta.setdefault("joint_names", [f"panda_joint{i + 1}" if n == 7 else f"joint{i + 1}" for i in range(n)])
    if not (isinstance(names, list) and len(names) == n and all(isinstance(s, str) for s in names)):
        raise InputError(f"meta joint_names = {names!r}; expected a list of {n} strings")
    notes = meta.get("notes", [])
    if not (isinstance(notes, list) and all(isinstance(s, str) for s in notes)):
        raise InputError(f"meta notes = {notes!r}; expected a list of strings")
    return meta


# ---------------------------------------------------------------------------------------------- files


def save_log(log: RobotLog, path: str | os.PathLike[str]) -> Path:
    """Validate `log` (any joint count) and write it to `path` (a .npz name) atomically: one array
    per present field, named as the field, plus "meta" (the metadata as a strict-JSON string in a
    0-d unicode array) and "format" (LOG_FORMAT). Absent (None) fields are not stored.

    Nothing is written, nor any folder created, when the log fails validation (InputError); the
    output path is then checked (OutputPathError) before the archive is built. Returns the path."""
    path = Path(path)
    if path.suffix != ".npz":
        raise InputError(f"robot log path {path}: expected a file name ending in .npz")
    log = validate_log(log, n_joints=None)
    check_output_file(path, "robot log")
    arrays = {name: getattr(log, name) for name in FIELDS if getattr(log, name) is not None}
    buf = io.BytesIO()
    np.savez_compressed(
        buf, format=np.array(LOG_FORMAT), meta=np.array(json.dumps(log.meta, allow_nan=False)), **arrays
    )
    return write_atomic(path, buf.getvalue())


def read_npz_log(path: str | os.PathLike[str]) -> RobotLog:
    """The robot log in a .npz written by `save_log` (loaded with allow_pickle=False), not yet
    validated (`sim2real.importers.load_log` reads any format and validates). FileFormatError (one
    line, starting with the path) when the file is empty, truncated, foreign, holds pickled
    objects or unknown arrays, or its metadata is not a strict-JSON object."""
    path = Path(path)
    what = "robot log (.npz written by save_log)"
    if path.stat().st_size == 0:
        raise FileFormatError(f"{path}: the file is empty; expected a {what}")
    if not zipfile.is_zipfile(path):
        raise FileFormatError(f"{path}: not a readable {what} (truncated or foreign file: not a zip archive)")
    try:
        with np.load(path, allow_pickle=False) as data:
            unknown = sorted(set(data.files) - set(FIELDS) - {"meta", "format"})
            if unknown:
                raise FileFormatError(
                    f"{path}: not a robot log: unknown arrays {unknown}; expected arrays among "
                    f"{list(FIELDS)} plus 'meta' and 'format'"
                )
            contents = {name: data[name] for name in data.files}
    except FileFormatError:
        raise
    except ValueError as exc:
        if "pickle" in str(exc):
            raise FileFormatError(f"{path}: refused: it holds pickled objects; expected a {what}") from None
        raise FileFormatError(f"{path}: not a readable {what} ({str(exc).splitlines()[0][:160]})") from None
    except (OSError, EOFError, KeyError, zipfile.BadZipFile, zlib.error) as exc:
        reason = str(exc).strip().splitlines()[0][:160] if str(exc).strip() else type(exc).__name__
        raise FileFormatError(f"{path}: not a readable {what} (truncated or foreign file: {reason})") from None
    for name, value in contents.items():
        if not isinstance(value, np.ndarray):
            raise FileFormatError(f"{path}: member {name!r} is not a numpy array; expected a {what}")
    fmt = contents.pop("format", None)
    if fmt is not None and not (fmt.ndim == 0 and fmt.dtype.kind == "U" and str(fmt[()]) == LOG_FORMAT):
        raise FileFormatError(f"{path}: format = {fmt.tolist()!r}; expected {LOG_FORMAT!r}")
    meta = contents.pop("meta", None)
    if meta is None:
        raise FileFormatError(f"{path}: no 'meta' array; expected a {what}")
    if not (meta.ndim == 0 and meta.dtype.kind == "U"):
        raise FileFormatError(
            f"{path}: meta has dtype {meta.dtype} and shape {meta.shape}; expected a JSON string (0-d unicode array)"
        )
    try:
        meta_obj = json.loads(str(meta[()]), parse_constant=reject_json_constant)
    except ValueError as exc:
        raise FileFormatError(f"{path}: meta is not strict JSON ({exc})") from None
    if not isinstance(meta_obj, dict):
        raise FileFormatError(f"{path}: meta is a JSON {type(meta_obj).__name__}; expected a JSON object")
    return RobotLog(**{name: contents.get(name) for name in FIELDS}, meta=meta_obj)


# ---------------------------------------------------------------------------------------------- helpers


def slice_log(log: RobotLog, start: int, stop: int) -> RobotLog:
    """Samples start..stop-1 of `log` (0 <= start < stop <= T; InputError otherwise), arrays
    copied, timestamps kept as they are (not shifted to 0), meta copied. Used for blocked
    cross-validation; the slice is not re-validated (it may hold fewer than MIN_SAMPLES)."""
    T = log.n_samples
    start = check_int(start, "start", 0)
    stop = check_int(stop, "stop", 0)
    if not start < stop <= T:
        raise InputError(f"sample range [{start}, {stop}); expected 0 <= start < stop <= {T} (the log's samples)")
    parts = {name: getattr(log, name)[start:stop].copy() for name in FIELDS if getattr(log, name) is not None}
    return dataclasses.replace(log, **parts, meta=copy.deepcopy(log.meta))


def with_meta(log: RobotLog, **updates: Any) -> RobotLog:
    """`log` with its meta updated by `updates` (top-level keys replaced; arrays shared, meta
    copied). Not validated: pass the result to `validate_log` to check the new entries."""
    return dataclasses.replace(log, meta={**copy.deepcopy(log.meta), **updates})
