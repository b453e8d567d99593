"""Robot logs in foreign layouts: the Gaz et al. 2019 Panda log folder and Franka CSV exports; and
`load_log`, which reads a log in any of them or in the npz format of `sim2real.log`, by what its
path is (a folder, a .csv, a .npz). The formats are documented in docs/robot_logs.md.
"""

from __future__ import annotations

import csv
import json
import math
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from goflow_common.errors import FileFormatError, InputError
from goflow_common.files import check_output_file, read_json, reject_json_constant, write_atomic
from sim2real.log import PHASES, RobotLog, read_npz_log, validate_log

__all__ = [
    "GAZ_FILES",
    "GAZ_JOINTS",
    "load_log",
    "read_gaz_layout",
    "write_gaz_layout",
    "read_gaz_trajectory",
    "csv_columns",
    "read_franka_csv",
    "write_franka_csv",
]

# ---------------------------------------------------------------------------------------------- Gaz et al. 2019

#: The four files of the Gaz et al. log, by the field they fill (in `rbt_log/` or the folder itself).
GAZ_FILES: dict[str, str] = {
    "time": "exciting_traj_time.txt",
    "q": "exciting_traj_positions.txt",
    "dq": "exciting_traj_velocity.txt",
    "tau": "exciting_traj_torques.txt",
}
#: Lines per sample in the position, velocity and torque files (joint 1..7).
GAZ_JOINTS = 7
_GAZ_WF = 0.15 * math.pi  # [rad/s] fundamental of the Fourier trajectory (AutomaticExcTrjGen.m)
_GAZ_TRAJECTORY = (
    "Commanded exciting trajectory (Gaz et al. 2019, matlab/generate_joint_traj/AutomaticExcTrjGen.m): the arm "
    "starts at rest at q0 [rad]; after a 0.5 s (1 - cos) velocity ramp, joint j follows dq_j(t) = sum_{l=1..5} "
    "a[j][l-1] cos(l wf s) + b[j][l-1] sin(l wf s) [rad/s], s = t - t0 with t0 the end of the ramp (about "
    "0.5 s), wf = omega_f = 0.15 pi rad/s, for 20 s, then a 0.5 s ramp back to rest. a (rows 1-7) and b (rows "
    "8-14) are gen_params.txt (4 decimals), q0 is gen_q0.txt; the sampled command itself is gen_dq.txt on "
    "gen_time.txt (not part of the log)."
)


def _read_numbers(path: Path, what: str) -> NDArray[np.float64]:
    """The whitespace-separated numbers of a text file as a float64 array (1-D for one per line)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # an empty file: checked below
            arr = np.loadtxt(path, dtype=np.float64, ndmin=1)
    except (ValueError, OSError) as exc:
        raise FileFormatError(f"{path}: not a {what} ({str(exc).strip().splitlines()[0][:160]})") from None
    if arr.size == 0:
        raise FileFormatError(f"{path}: the file is empty; expected a {what}")
    return arr


def _gaz_folder(folder: Path) -> Path:
    """The folder holding the four files: `folder/rbt_log` or `folder` itself."""
    for where in (folder / "rbt_log", folder):
        present = [name for name in GAZ_FILES.values() if (where / name).is_file()]
        if len(present) == len(GAZ_FILES):
            return where
        if present:
            missing = [name for name in GAZ_FILES.values() if name not in present]
            raise FileFormatError(
                f"{where}: missing {', '.join(missing)}; expected the four files {', '.join(GAZ_FILES.values())}"
            )
    raise FileFormatError(
        f"{folder}: no rbt_log/{GAZ_FILES['time']} (nor {GAZ_FILES['time']}); expected a robot log "
        f"folder in the Gaz et al. 2019 layout ({', '.join(GAZ_FILES.values())})"
    )


def has_gaz_layout(folder: str | os.PathLike[str]) -> bool:
    """Whether `folder` holds the Gaz et al. time file (in rbt_log/ or directly)."""
    folder = Path(folder)
    return any((d / "exciting_traj_time.txt").is_file() for d in (folder / "rbt_log", folder))


def read_gaz_trajectory(folder: str | os.PathLike[str]) -> dict[str, Any] | None:
    """The commanded trajectory of a Gaz et al. log folder as plain JSON data (description,
    q0 [rad], Fourier coefficients a and b (7 x 5 lists), omega_f [rad/s], harmonics), read from
    `gen_q0.txt` and `gen_params.txt` in `folder`; None when these files are not there.
    FileFormatError names the file when one holds the wrong count of numbers."""
    folder = Path(folder)
    q0_path, params_path = folder / "gen_q0.txt", folder / "gen_params.txt"
    if not (q0_path.is_file() and params_path.is_file()):
        return None
    q0 = _read_numbers(q0_path, "start pose (7 numbers)")
    params = _read_numbers(params_path, "Fourier coefficient table (14 rows of 5)")
    if q0.shape != (GAZ_JOINTS,):
        raise FileFormatError(f"{q0_path}: {q0.size} numbers in shape {q0.shape}; expected {GAZ_JOINTS}, one per line")
    if params.shape != (2 * GAZ_JOINTS, 5):
        raise FileFormatError(
            f"{params_path}: a table of shape {params.shape}; expected (14, 5): 7 rows of a then "
            "7 rows of b, 5 harmonics each"
        )
    return {
        "description": _GAZ_TRAJECTORY,
        "q0": q0.tolist(),
        "a": params[:GAZ_JOINTS].tolist(),
        "b": params[GAZ_JOINTS:].tolist(),
        "omega_f": _GAZ_WF,
        "harmonics": 5,
        "files": ["gen_q0.txt", "gen_params.txt"],
    }


def _gaz_meta(folder: Path, where: Path, notes: list[str]) -> dict[str, Any]:
    # the layout carries no end effector: "none" (the Gaz et al. arm) is a guess the diagnosis may
    # revise from the data (end_effector_assumed); a meta.json stating it replaces both
    meta: dict[str, Any] = {
        "robot": "franka_panda",
        "end_effector": "none",
        "end_effector_assumed": True,
        "torque_side": "link",
        "source": str(folder),
    }
    trajectory = read_gaz_trajectory(folder)
    if trajectory is not None:
        meta["commanded_trajectory"] = trajectory
    for path in dict.fromkeys((folder / "meta.json", where / "meta.json")):
        if path.is_file():
            extra = read_json(path, "log metadata file (meta.json)")
            if not isinstance(extra, dict):
                raise FileFormatError(f"{path}: a JSON {type(extra).__name__}; expected a JSON object of metadata")
            meta.update(extra)
            if "end_effector" in extra:
                meta.pop("end_effector_assumed", None)
    if notes:  # after the notes of meta.json (a non-list there fails validation)
        meta["notes"] = [*meta.get("notes", []), *notes] if isinstance(meta.get("notes", []), list) else notes
    return meta


def read_gaz_layout(folder: str | os.PathLike[str]) -> RobotLog:
    """The log of a folder in the layout of Gaz et al. 2019 (/work/shared/data/panda-gaz2019):
    `rbt_log/exciting_traj_{time,positions,velocity,torques}.txt`, or the same four files directly
    in `folder`; one timestamp [s] per line, and 7 lines per sample (joint 1..7) of measured q
    [rad], dq [rad/s] and link-side torques tau_J [N m] (-> `tau`).

    Files one sample short at the end are accepted: all are cut to the common length, said in
    meta["notes"]; any other count mismatch, or a line count that is not a whole number of 7-line
    samples, raises FileFormatError naming the file. Meta: robot "franka_panda", end_effector
    "none", torque_side "link", source (the folder), the commanded trajectory when gen_q0.txt and
    gen_params.txt are in `folder` (see read_gaz_trajectory), then the entries of a `meta.json` in
    `folder` or next to the files (strict JSON; its entries win). The log is validated (7 joints).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"no robot log folder at {folder}")
    where = _gaz_folder(folder)
    columns = {name: _read_numbers(where / file, "column of numbers, one per line") for name, file in GAZ_FILES.items()}
    counts: dict[str, int] = {}
    for name, arr in columns.items():
        path = where / GAZ_FILES[name]
        if arr.ndim != 1:
            raise FileFormatError(f"{path}: {arr.shape[1]} numbers per line; expected one")
        per_sample = 1 if name == "time" else GAZ_JOINTS
        if arr.size % per_sample:
            raise FileFormatError(
                f"{path}: {arr.size} lines, not a whole number of {GAZ_JOINTS}-line samples "
                f"(joint 1..{GAZ_JOINTS} per sample)"
            )
        counts[name] = arr.size // per_sample
    n = min(counts.values())
    shortest = GAZ_FILES[min(counts, key=counts.__getitem__)]
    longer = [GAZ_FILES[name] for name, count in counts.items() if count > n]
    for name, count in counts.items():
        if count > n + 1:
            raise FileFormatError(
                f"{where / GAZ_FILES[name]}: {count} samples, but {shortest} has {n}; expected the "
                "same count in the four files (one sample missing at the end is accepted)"
            )
    notes = (
        [f"truncated to the common length of {n} samples: {', '.join(longer)} had one sample more"] if longer else []
    )
    arrays = {name: arr[: n * (1 if name == "time" else GAZ_JOINTS)] for name, arr in columns.items()}
    log = RobotLog(
        time=arrays["time"],
        q=arrays["q"].reshape(n, GAZ_JOINTS),
        dq=arrays["dq"].reshape(n, GAZ_JOINTS),
        tau=arrays["tau"].reshape(n, GAZ_JOINTS),
        meta=_gaz_meta(folder, where, notes),
    )
    return _validated(log, folder, GAZ_JOINTS)


def write_gaz_layout(log: RobotLog, folder: str | os.PathLike[str]) -> Path:
    """Write `log` (validated first, 7 joints, tau present; nothing is written if it fails) into
    `folder` in the Gaz et al. 2019 layout that `read_gaz_layout` reads back to the same values:
    `folder/rbt_log/exciting_traj_{time,positions,velocity,torques}.txt` (one number per line in
    its shortest exact form, 7 lines per sample) and `folder/rbt_log/meta.json` (the log's meta;
    the other fields are not part of the layout). `folder` may exist; the files are written
    atomically. Returns `folder`. Raises InputError for a log that fails validation or lacks tau."""
    log = validate_log(log, n_joints=GAZ_JOINTS)
    if log.tau is None:
        raise InputError("log.tau is missing; expected measured joint torques for exciting_traj_torques.txt")
    where = Path(folder) / "rbt_log"
    where.mkdir(parents=True, exist_ok=True)
    for name, file in GAZ_FILES.items():
        values = getattr(log, name).reshape(-1).tolist()
        write_atomic(where / file, "".join(repr(x) + "\n" for x in values))
    write_atomic(where / "meta.json", json.dumps(log.meta, allow_nan=False, indent=1) + "\n")
    return Path(folder)


def _validated(log: RobotLog, path: Path, n_joints: int | None) -> RobotLog:
    try:
        return validate_log(log, n_joints)
    except InputError as exc:
        raise FileFormatError(f"{path}: {exc}") from None


# ---------------------------------------------------------------------------------------------- Franka CSV


def csv_columns(n_joints: int = 7) -> dict[str, list[str]]:
    """The CSV column names of each RobotLog field, as libfranka / franka_ros users name the
    robot-state members: time; q, dq, tau_J (-> tau), tau_d (-> tau_cmd), q_d (-> q_cmd), dq_d
    (-> dq_cmd), tau_ext (-> tau_ext, Franka's tau_ext_hat_filtered) with suffixes 0..n-1;
    O_T_EE0..15 (-> tool_pose) and O_T_EE_d0..15 (-> tool_target), column-major 4x4 as libfranka
    stores them; O_F_ext_hat_K0..5 (-> wrench); gripper_width; phase (integer labels or names)."""

    def joints(prefix: str) -> list[str]:
        return [f"{prefix}{i}" for i in range(n_joints)]

    return {
        "time": ["time"],
        "q": joints("q"),
        "dq": joints("dq"),
        "tau": joints("tau_J"),
        "tau_cmd": joints("tau_d"),
        "q_cmd": joints("q_d"),
        "dq_cmd": joints("dq_d"),
        "tau_ext": joints("tau_ext"),
        "tool_pose": [f"O_T_EE{i}" for i in range(16)],
        "tool_target": [f"O_T_EE_d{i}" for i in range(16)],
        "wrench": [f"O_F_ext_hat_K{i}" for i in range(6)],
        "gripper_width": ["gripper_width"],
        "phase": ["phase"],
    }


def _csv_preamble(path: Path, lines: list[str]) -> tuple[int, dict[str, Any]]:
    """Leading blank and '#' lines: (index of the header line, metadata of its '# meta: {json}' lines)."""
    meta: dict[str, Any] = {}
    i = 0
    while i < len(lines) and (not lines[i].strip() or lines[i].lstrip().startswith("#")):
        body = lines[i].lstrip()[1:].strip()
        if body.startswith("meta:"):
            try:
                extra = json.loads(body[len("meta:") :], parse_constant=reject_json_constant)
            except ValueError as exc:
                raise FileFormatError(f"{path}: line {i + 1}: the meta comment is not strict JSON ({exc})") from None
            if not isinstance(extra, dict):
                raise FileFormatError(
                    f"{path}: line {i + 1}: the meta comment is a JSON {type(extra).__name__}; expected a JSON object"
                )
            meta.update(extra)
            if "end_effector" in extra:
                meta.pop("end_effector_assumed", None)
        i += 1
    if i == len(lines):
        raise FileFormatError(
            f"{path}: no header row; expected a CSV with a header of columns time, q0.., dq0.., tau_J0.."
        )
    return i, meta


def _csv_fields(path: Path, header: list[str], n_joints: int | None) -> dict[str, list[str]]:
    """The fields the header holds, with their columns; FileFormatError naming missing columns."""
    if n_joints is None:
        n_joints = next(i for i in range(len(header) + 1) if f"q{i}" not in header) or 7
    groups = csv_columns(n_joints)
    present = {field: names for field, names in groups.items() if any(name in header for name in names)}
    required = ["time", "q", "dq"] + ([] if "tau_cmd" in present else ["tau"])
    missing = [name for field in required for name in groups[field] if name not in header]
    missing += [
        name for field, names in present.items() if field not in required for name in names if name not in header
    ]
    if missing:
        raise FileFormatError(
            f"{path}: missing column(s) {', '.join(missing)}; expected at least time, "
            f"q0..q{n_joints - 1}, dq0..dq{n_joints - 1} and tau_J0..tau_J{n_joints - 1} "
            f"(or tau_d0..tau_d{n_joints - 1})"
        )
    return present


def _parse_phase(path: Path, cells: list[str], first_line: int) -> NDArray[np.int64]:
    labels = np.empty(len(cells), dtype=np.int64)
    for r, cell in enumerate(cells):
        text = cell.strip()
        if text in PHASES:
            labels[r] = PHASES.index(text)
            continue
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not value.is_integer():
            raise FileFormatError(
                f"{path}: line {first_line + r} (data row {r + 1}), column phase: {cell!r}; expected "
                f"an integer label 0..{len(PHASES) - 1} or one of {list(PHASES)}"
            )
        labels[r] = int(value)
    return labels


def _parse_numbers(
    path: Path, rows: list[list[str]], header: list[str], names: list[str], first_line: int
) -> NDArray[np.float64]:
    idx = [header.index(name) for name in names]
    table = [[row[j] for j in idx] for row in rows]
    try:
        return np.array(table, dtype=np.float64).reshape(len(rows), len(names))
    except ValueError:
        for r, row in enumerate(table):
            for name, cell in zip(names, row):
                try:
                    float(cell)
                except ValueError:
                    raise FileFormatError(
                        f"{path}: line {first_line + r} (data row {r + 1}), column {name}: {cell!r} is not a number"
                    ) from None
        raise


def read_franka_csv(path: str | os.PathLike[str], n_joints: int | None = 7) -> RobotLog:
    """The log of a CSV file with a header row, columns named as in `csv_columns` (order free).

    Required: time [s], q0.., dq0.. and tau_J0.. (the last unless tau_d0.. is given); each optional
    group (tau_d, q_d, dq_d, tau_ext, O_T_EE, O_T_EE_d, O_F_ext_hat_K, gripper_width, phase) is
    read when present and must then be complete. `n_joints` columns per joint group (None: as many
    q<i> columns as the header holds). Leading lines starting with '#' are comments; those of the
    form `# meta: {json}` set metadata (strict JSON objects, merged in order). Unknown columns are
    ignored and listed in meta["notes"]. Defaults: meta["source"] = the path, torque_side "link"
    when tau_J is given. The log is validated (`n_joints` joints).

    FileFormatError (one line, starting with the path) names the missing column(s), the line and
    column of a cell that is not a number (or not a phase), a row with the wrong cell count, and
    any validation failure. FileNotFoundError if there is no file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no robot log CSV at {path}")
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except UnicodeDecodeError as exc:
        raise FileFormatError(f"{path}: not a text CSV file ({exc.reason} at byte {exc.start})") from None
    start, file_meta = _csv_preamble(path, lines)
    rows = list(csv.reader(lines[start:]))
    header = [name.strip() for name in rows[0]]
    if duplicated := sorted({name for name in header if header.count(name) > 1}):
        raise FileFormatError(f"{path}: duplicated column(s) {', '.join(duplicated)}; expected each column once")
    fields = _csv_fields(path, header, n_joints)
    body = [(start + 2 + r, row) for r, row in enumerate(rows[1:]) if row]  # blank lines skipped
    for line, row in body:
        if len(row) != len(header):
            raise FileFormatError(f"{path}: line {line}: {len(row)} cells; expected {len(header)} as the header")
    data = [row for _, row in body]
    first_line = body[0][0] if body else start + 2
    arrays: dict[str, Any] = {}
    numeric = [name for field, names in fields.items() if field != "phase" for name in names]
    table = _parse_numbers(path, data, header, numeric, first_line)
    col = 0
    for field, names in fields.items():
        if field == "phase":
            arrays["phase"] = _parse_phase(path, [row[header.index("phase")] for row in data], first_line)
            continue
        block = table[:, col : col + len(names)]
        col += len(names)
        if field in ("tool_pose", "tool_target"):  # column-major: entry i is X[i % 4, i // 4]
            block = block.reshape(-1, 4, 4).transpose(0, 2, 1)
        arrays[field] = block[:, 0] if field in ("time", "gripper_width") else block
    known = {name for names in fields.values() for name in names}
    unknown = [name for name in header if name not in known]
    meta: dict[str, Any] = {"source": str(path), **({"torque_side": "link"} if "tau" in arrays else {})}
    meta.update(file_meta)
    if unknown:
        meta["notes"] = list(meta.get("notes", [])) + [f"ignored columns: {', '.join(unknown)}"]
    return _validated(RobotLog(**arrays, meta=meta), path, n_joints)


def write_franka_csv(log: RobotLog, path: str | os.PathLike[str]) -> Path:
    """Write `log` (validated first, any joint count; nothing is written if it fails) as a CSV
    that `read_franka_csv` reads back to the same arrays: a `# meta: {json}` line, the header
    (columns of `csv_columns` for the present fields), one row per sample with every number in
    its shortest exact form, phases as names. `path` must end in .csv; written atomically."""
    path = Path(path)
    if path.suffix != ".csv":
        raise InputError(f"robot log CSV path {path}: expected a file name ending in .csv")
    log = validate_log(log, n_joints=None)
    check_output_file(path, "robot log CSV")
    header: list[str] = []
    blocks: list[NDArray[np.float64]] = []
    for field, names in csv_columns(log.n_joints).items():
        value = getattr(log, field)
        if value is None or field == "phase":
            continue
        if field in ("tool_pose", "tool_target"):
            value = value.transpose(0, 2, 1)
        header += names
        blocks.append(value.reshape(log.n_samples, -1))
    table = np.hstack(blocks).tolist()
    phases = None if log.phase is None else [PHASES[k] for k in log.phase.tolist()]
    out = ["# meta: " + json.dumps(log.meta, allow_nan=False), ",".join(header + (["phase"] if phases else []))]
    for k, row in enumerate(table):
        out.append(",".join([repr(x) for x in row] + ([phases[k]] if phases else [])))
    return write_atomic(path, "\n".join(out) + "\n")


# ---------------------------------------------------------------------------------------------- any format


def load_log(path: str | os.PathLike[str], n_joints: int | None = 7) -> RobotLog:
    """Read and validate a robot log (see `sim2real.log.validate_log`; `n_joints` None accepts any
    count).

    `path` is one of: a folder in the layout of the Gaz et al. 2019 log (`read_gaz_layout`) or a
    folder holding a log.npz, a .csv file as Franka users export it (`read_franka_csv`), or a .npz
    written by `sim2real.log.save_log` (loaded with allow_pickle=False). Raises FileNotFoundError
    if nothing is at `path`, and FileFormatError (one line, starting with the path) when the file
    is empty, truncated, foreign, holds unknown arrays or bad metadata, or the log fails validation."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no robot log at {path}")
    if path.is_dir() and (path / "log.npz").is_file() and not has_gaz_layout(path):
        path = path / "log.npz"  # a data folder of the project (data/panda-gaz2019)
    if path.is_dir():
        log = read_gaz_layout(path)
    elif path.suffix.lower() == ".csv":
        log = read_franka_csv(path, n_joints=n_joints)
    else:
        log = read_npz_log(path)
    try:
        return validate_log(log, n_joints)
    except InputError as exc:
        raise FileFormatError(f"{path}: {exc}") from None
