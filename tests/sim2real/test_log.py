"""sim2real.log and sim2real.importers: the robot-log format, its validation, the npz / CSV / Gaz
et al. folder readers, and the converted real log in data/panda-gaz2019."""

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from goflow_common.errors import FileFormatError, InputError
from sim2real.importers import GAZ_FILES, load_log, read_franka_csv, read_gaz_layout, write_franka_csv
from sim2real.log import (
    FIELDS,
    LOG_FORMAT,
    PHASES,
    UNITS,
    RobotLog,
    save_log,
    slice_log,
    validate_log,
    with_meta,
)

ROOT = Path(__file__).resolve().parents[2]
CONVERTED = ROOT / "data" / "panda-gaz2019" / "log.npz"
ORIGINAL = ROOT.parent / "shared" / "data" / "panda-gaz2019"
T = 60


def _rot_z(angle: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    R = np.zeros(angle.shape + (3, 3))
    R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1], R[..., 2, 2] = c, -s, s, c, 1.0
    return R


def _poses(angle: np.ndarray, offset: float) -> np.ndarray:
    X = np.zeros(angle.shape + (4, 4))
    X[:, :3, :3] = _rot_z(angle)
    X[:, :3, 3] = np.stack([0.4 + offset + 0.01 * angle, -0.1 + 0.0 * angle, 0.3 + 0.02 * angle], axis=-1)
    X[:, 3, 3] = 1.0
    return X


def full_log(**changes) -> RobotLog:
    """A 7-joint log with every field, 1 kHz, physically plausible values."""
    rng = np.random.default_rng(0)
    time = 0.001 * np.arange(T) + 0.123
    q = 0.5 * np.sin(time[:, None] * np.arange(1, 8)) + rng.normal(0, 0.01, (T, 7))
    angle = np.linspace(0, 1.0, T)
    fields = dict(
        time=time,
        q=q,
        dq=rng.normal(0, 0.5, (T, 7)),
        tau=rng.normal(0, 10, (T, 7)),
        tau_cmd=rng.normal(0, 10, (T, 7)),
        q_cmd=q + 0.001,
        dq_cmd=rng.normal(0, 0.5, (T, 7)),
        tau_ext=rng.normal(0, 1, (T, 7)),
        tool_pose=_poses(angle, 0.0),
        tool_target=_poses(angle, 0.01),
        wrench=rng.normal(0, 2, (T, 6)),
        gripper_width=np.full(T, 0.04),
        phase=np.arange(T) * len(PHASES) // T,
        meta={"robot": "franka_panda", "end_effector": "hand", "torque_side": "link", "controller": {"kp": [1.5] * 7}},
    )
    fields.update(changes)
    return RobotLog(**fields)


def assert_same_arrays(a: RobotLog, b: RobotLog) -> None:
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert x.dtype == y.dtype and np.array_equal(x, y), name


# ---------------------------------------------------------------------------------------------- round trips


def test_npz_round_trip_keeps_every_array_and_the_meta(tmp_path):
    log = validate_log(full_log())
    assert log.phase.dtype == np.int64 and log.q.dtype == np.float64
    assert log.meta["units"] == {name: UNITS[name] for name in FIELDS if name in UNITS}
    assert log.meta["joint_names"] == [f"panda_joint{i}" for i in range(1, 8)]
    path = save_log(log, tmp_path / "runs" / "log.npz")
    back = load_log(path)
    assert_same_arrays(log, back)
    assert back.meta == log.meta
    with np.load(path, allow_pickle=False) as data:
        assert str(data["format"][()]) == LOG_FORMAT
        assert json.loads(str(data["meta"][()]))["controller"] == {"kp": [1.5] * 7}


def test_absent_fields_are_not_stored(tmp_path):
    log = RobotLog(time=np.arange(20) * 0.01, q=np.zeros((20, 7)), dq=np.zeros((20, 7)), tau=np.ones((20, 7)))
    path = save_log(log, tmp_path / "state.npz")
    with np.load(path, allow_pickle=False) as data:
        assert sorted(data.files) == ["dq", "format", "meta", "q", "tau", "time"]
    back = load_log(path)
    assert back.tool_pose is None and back.phase is None and back.meta["units"]["tau"] == "N m"


def test_csv_round_trip(tmp_path):
    log = validate_log(full_log())
    path = write_franka_csv(log, tmp_path / "log.csv")
    header = path.read_text().splitlines()[1].split(",")
    assert header[:3] == ["time", "q0", "q1"] and "tau_J6" in header and "O_T_EE_d15" in header
    back = load_log(path)
    assert_same_arrays(log, back)
    assert back.meta["end_effector"] == "hand" and back.meta["controller"] == {"kp": [1.5] * 7}
    assert_same_arrays(read_franka_csv(path, n_joints=None), back)


def test_csv_as_libfranka_users_write_it(tmp_path):
    """Column-major O_T_EE (translation in entries 12..14), phase names and numbers, a meta comment,
    extra columns noted, tau_d alone as the torque channel."""
    n = 12
    cols = (
        ["time"]
        + [f"q{i}" for i in range(7)]
        + [f"dq{i}" for i in range(7)]
        + [f"tau_d{i}" for i in range(7)]
        + [f"O_T_EE{i}" for i in range(16)]
        + ["gripper_width", "phase", "success_rate"]
    )
    pose = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0.5, -0.2, 0.3, 1]  # column-major: x, y, z at 12, 13, 14
    rows = [
        [f"{0.001 * k:.3f}"]
        + ["0.1"] * 7
        + ["0"] * 7
        + ["1.5"] * 7
        + [str(v) for v in pose]
        + ["0.04", PHASES[k % 4] if k % 2 else str(k % 4), "n/a"]
        for k in range(n)
    ]
    path = tmp_path / "franka.csv"
    path.write_text(
        "# exported by our logger\n"
        '# meta: {"end_effector": "hand+gear_small", "controller": "joint impedance"}\n'
        + "\n".join(",".join(r) for r in [cols] + rows)
        + "\n"
    )
    log = load_log(path)
    assert log.tau is None and np.all(log.tau_cmd == 1.5)
    assert np.array_equal(log.tool_pose[0, :3, 3], [0.5, -0.2, 0.3])
    assert np.array_equal(log.tool_pose[0, 3], [0, 0, 0, 1]) and np.array_equal(log.tool_pose[0, :3, :3], np.eye(3))
    assert log.phase.tolist() == [k % 4 for k in range(n)]
    assert log.meta["end_effector"] == "hand+gear_small" and "torque_side" not in log.meta
    assert log.meta["notes"] == ["ignored columns: success_rate"]


# ---------------------------------------------------------------------------------------------- the real log


def test_the_converted_real_log_loads():
    log = load_log(CONVERTED)
    assert (log.n_samples, log.n_joints) == (20544, 7)
    assert log.meta["end_effector"] == "none" and log.meta["torque_side"] == "link"
    assert log.meta["license"] == "GPL-3.0" and len(log.meta["commanded_trajectory"]["a"]) == 7
    assert log.tau_cmd is None and log.q_cmd is None
    assert CONVERTED.stat().st_size < 4e6
    assert (CONVERTED.parent / "LICENSE").is_file() and "Gaz" in (CONVERTED.parent / "README.md").read_text()


@pytest.mark.skipif(not ORIGINAL.is_dir(), reason="the original Gaz et al. folder is not on this machine")
def test_the_original_folder_gives_the_same_arrays():
    original = load_log(ORIGINAL)
    assert_same_arrays(original, load_log(CONVERTED))
    assert original.meta["commanded_trajectory"]["q0"][0] == -0.9584


@pytest.mark.skipif(not ORIGINAL.is_dir(), reason="the original Gaz et al. folder is not on this machine")
def test_the_conversion_script_reproduces_the_committed_folder(tmp_path):
    run = subprocess.run(
        [sys.executable, str(ROOT / "tools" / "convert_gaz2019.py"), "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr
    for name in ("log.npz", "LICENSE", "README.md"):
        assert (tmp_path / name).read_bytes() == (CONVERTED.parent / name).read_bytes(), name


def _gaz_folder(folder: Path, n: int = 15, cut: dict | None = None, meta: dict | None = None) -> Path:
    """A small log in the Gaz et al. layout, files directly in `folder`; `cut` drops lines per field."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(1)
    values = {
        "time": 0.001 * np.arange(n),
        "q": rng.normal(0, 0.5, 7 * n),
        "dq": rng.normal(0, 0.5, 7 * n),
        "tau": rng.normal(0, 5, 7 * n),
    }
    for name, file in GAZ_FILES.items():
        v = values[name][: len(values[name]) - (cut or {}).get(name, 0)]
        (folder / file).write_text("\n".join(f"{x:.6g}" for x in v) + "\n")
    if meta is not None:
        (folder / "meta.json").write_text(json.dumps(meta))
    return folder


def test_the_gaz_layout_without_rbt_log_and_with_a_meta_file(tmp_path):
    log = read_gaz_layout(_gaz_folder(tmp_path / "flat", meta={"end_effector": "hand", "operator": "x"}))
    assert log.n_samples == 15 and log.meta["end_effector"] == "hand" and log.meta["operator"] == "x"
    assert log.meta["torque_side"] == "link" and "notes" not in log.meta


def test_the_gaz_layout_accepts_one_missing_sample_at_the_end(tmp_path):
    log = load_log(_gaz_folder(tmp_path / "cut", cut={"tau": 7, "time": 1}))
    assert log.n_samples == 14
    assert log.meta["notes"] == [
        f"truncated to the common length of 14 samples: {GAZ_FILES['q']}, {GAZ_FILES['dq']} had one sample more"
    ]


@pytest.mark.parametrize(
    "cut, match",
    [
        ({"dq": 3}, r"exciting_traj_velocity\.txt: 102 lines, not a whole number of 7-line samples"),
        ({"q": 14}, r"exciting_traj_time\.txt: 15 samples, but exciting_traj_positions\.txt has 13"),
    ],
)
def test_the_gaz_layout_refuses_inconsistent_counts(tmp_path, cut, match):
    with pytest.raises(FileFormatError, match=match):
        load_log(_gaz_folder(tmp_path / "bad", cut=cut))


def test_a_folder_that_is_not_a_log(tmp_path):
    with pytest.raises(FileFormatError, match=r"no rbt_log/exciting_traj_time\.txt"):
        load_log(tmp_path)
    _gaz_folder(tmp_path / "x")
    (tmp_path / "x" / GAZ_FILES["dq"]).unlink()
    with pytest.raises(FileFormatError, match=r"missing exciting_traj_velocity\.txt"):
        load_log(tmp_path / "x")


# ---------------------------------------------------------------------------------------------- validation


def _deg(log):
    return {"q": np.rad2deg(log.q)}


def _swap(log):
    t = log.time.copy()
    t[40], t[41] = t[41], t[40]
    return {"time": t}


def _repeat(log):
    t = log.time.copy()
    t[30] = t[29]
    return {"time": t}


def _nan(log):
    dq = log.dq.copy()
    dq[37, 2] = np.nan
    return {"dq": dq}


def _scaled_pose(log):
    X = log.tool_pose.copy()
    X[20, :3, :3] *= 1.1
    return {"tool_pose": X}


def _bad_last_row(log):
    X = log.tool_target.copy()
    X[5, 3, 0] = 0.2
    return {"tool_target": X}


def _mirror(log):
    X = log.tool_pose.copy()
    X[:, 2, 2] = -1.0
    return {"tool_pose": X}


def _mm_pose(log):
    X = log.tool_pose.copy()
    X[:, :3, 3] *= 1000
    return {"tool_pose": X}


def _phase7(log):
    p = log.phase.copy()
    p[12] = 7
    return {"phase": p}


MALFORMED = [
    ("missing q", lambda log: {"q": None}, r"^q is missing"),
    (
        "no torque channel",
        lambda log: {"tau": None, "tau_cmd": None, "q_cmd": None},
        r"tau, tau_cmd and q_cmd are all missing",
    ),
    ("units in meta", lambda log: {"meta": {"units": {"q": "deg"}}}, r"meta units for q = 'deg'; expected 'rad'"),
    ("unknown unit key", lambda log: {"meta": {"units": {"force": "N"}}}, r"meta units names 'force'"),
    ("degrees", _deg, r"^q out of range: q\[\d+, \d+\] = .* looks like degrees"),
    ("deg/s", lambda log: {"dq": log.dq * 60}, r"^dq out of range: .* looks like deg/s"),
    ("mN m", lambda log: {"tau": log.tau * 1000}, r"^tau out of range: .* looks like mN m"),
    ("ms timestamps", lambda log: {"time": log.time * 2000}, r"^time jumps by 2 s at sample 1; .* ms or ns"),
    ("ns timestamps", lambda log: {"time": log.time * 1e9}, r"^time spans .* look like ms or ns"),
    ("time goes back", _swap, r"^time goes back at sample 41"),
    ("time repeats", _repeat, r"^time repeats at sample 30"),
    ("NaN", _nan, r"^dq is not finite: dq\[37, 2\] = nan \(sample 37, t = 0\.16 s\)"),
    ("inf time", lambda log: {"time": np.r_[log.time[:-1], np.inf]}, r"^time is not finite: time\[59\] = inf"),
    ("6 joints", lambda log: {"q": log.q[:, :6]}, r"^q has 6 joints; expected 7"),
    ("dq joints", lambda log: {"dq": log.dq[:, :6]}, r"^dq has 6 joints; expected 7"),
    ("dq samples", lambda log: {"dq": log.dq[:-1]}, r"^dq has 59 samples; expected 60 \(as time\)"),
    ("q flat", lambda log: {"q": log.q.ravel()}, r"^q has shape \(420,\); expected \(T, 7\)"),
    ("wrench shape", lambda log: {"wrench": log.wrench[:, :3]}, r"^wrench has shape \(60, 3\); expected \(60, 6\)"),
    (
        "too short",
        lambda log: {name: getattr(log, name)[:5] for name in FIELDS},
        r"^time has 5 samples; expected at least 10",
    ),
    ("phase label", _phase7, r"^phase label out of range: phase\[12\] = 7 \(sample 12"),
    ("phase fraction", lambda log: {"phase": log.phase + 0.5}, r"^phase label phase\[0\] = 0\.5 .* not an integer"),
    ("phase names", lambda log: {"phase": np.array(["free"] * T)}, r"^phase holds <U4 values"),
    ("not rigid", _scaled_pose, r"^tool_pose is not a rigid transform at sample 20 .* not orthonormal"),
    ("last row", _bad_last_row, r"^tool_target is not a rigid transform at sample 5 .* last row"),
    ("reflection", _mirror, r"^tool_pose is not a rigid transform at sample 0 .* reflection"),
    ("mm pose", _mm_pose, r"^tool_pose translation out of range: .* millimetres"),
    ("gripper mm", lambda log: {"gripper_width": log.gripper_width * 1000}, r"^gripper_width out of range"),
    (
        "end effector",
        lambda log: {"meta": {"end_effector": "gripper"}},
        r"^meta end_effector = 'gripper'; expected one of",
    ),
    ("torque side", lambda log: {"meta": {"torque_side": "joint"}}, r"^meta torque_side = 'joint'; expected one of"),
    ("joint names", lambda log: {"meta": {"joint_names": ["a"]}}, r"^meta joint_names = \['a'\]; expected a list of 7"),
    ("meta NaN", lambda log: {"meta": {"k": float("nan")}}, r"^meta is not strict JSON: meta\.k = nan"),
    ("meta object", lambda log: {"meta": {"k": object()}}, r"^meta is not strict JSON"),
]


@pytest.mark.parametrize("change, match", [c[1:] for c in MALFORMED], ids=[c[0] for c in MALFORMED])
def test_a_malformed_log_is_named_and_nothing_is_written(tmp_path, change, match):
    log = full_log()
    bad = dataclasses.replace(log, **change(log))
    with pytest.raises(InputError, match=match) as info:
        validate_log(bad)
    assert "\n" not in str(info.value)
    with pytest.raises(InputError):  # save_log accepts any joint count: "6 joints" fails on dq there
        save_log(bad, tmp_path / "out" / "log.npz")
    assert not (tmp_path / "out").exists()


def test_the_joint_count_is_free_when_asked(tmp_path):
    log = full_log(q=full_log().q[:, :6])
    six = {name: getattr(log, name)[:, :6] for name in ("dq", "tau", "tau_cmd", "q_cmd", "dq_cmd", "tau_ext")}
    log = validate_log(dataclasses.replace(log, **six), n_joints=None)
    assert log.meta["joint_names"] == [f"joint{i}" for i in range(1, 7)]
    path = save_log(log, tmp_path / "six.npz")
    assert load_log(path, n_joints=None).n_joints == 6
    with pytest.raises(FileFormatError, match=r"six\.npz: q has 6 joints; expected 7"):
        load_log(path)


# ---------------------------------------------------------------------------------------------- bad files


def _csv_with(tmp_path, edit) -> Path:
    path = write_franka_csv(full_log(), tmp_path / "log.csv")
    lines = path.read_text().splitlines()
    path.write_text("\n".join(edit(lines)) + "\n")
    return path


def _drop_column(lines, name):
    i = lines[1].split(",").index(name)
    return [lines[0]] + [",".join(c for j, c in enumerate(line.split(",")) if j != i) for line in lines[1:]]


def _set_cell(lines, row, name, value):
    i = lines[1].split(",").index(name)
    cells = lines[2 + row].split(",")
    cells[i] = value
    return lines[: 2 + row] + [",".join(cells)] + lines[3 + row :]


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda lines: _drop_column(lines, "q3"), r"missing column\(s\) q3; expected at least time, q0\.\.q6"),
        (lambda lines: _drop_column(_drop_column(lines, "tau_J0"), "tau_d2"), r"missing column\(s\) tau_J0, tau_d2"),
        (lambda lines: _drop_column(lines, "O_T_EE7"), r"missing column\(s\) O_T_EE7"),
        (lambda lines: _set_cell(lines, 2, "dq2", "abc"), r"line 5 \(data row 3\), column dq2: 'abc' is not a number"),
        (lambda lines: _set_cell(lines, 0, "phase", "landing"), r"line 3 \(data row 1\), column phase: 'landing'"),
        (lambda lines: _set_cell(lines, 0, "phase", "9"), r"phase label out of range: phase\[0\] = 9"),
        (lambda lines: _set_cell(lines, 1, "q0", "nan"), r"q is not finite: q\[1, 0\] = nan"),
        (lambda lines: lines[:4] + [lines[4] + ",1"] + lines[5:], r"line 5: 91 cells; expected 90 as the header"),
        (lambda lines: ['# meta: {"units": {"dq": "deg/s"}}'] + lines[1:], r"meta units for dq = 'deg/s'"),
        (lambda lines: ["# meta: {bad"] + lines[1:], r"line 1: the meta comment is not strict JSON"),
        (lambda lines: lines[:1], r"no header row"),
    ],
)
def test_a_malformed_csv_is_named(tmp_path, edit, match):
    path = _csv_with(tmp_path, edit)
    with pytest.raises(FileFormatError, match=match) as info:
        load_log(path)
    assert str(info.value).startswith(str(path)) and "\n" not in str(info.value)


def _npz(path: Path, **arrays) -> Path:
    with open(path, "wb") as f:
        np.savez(f, **arrays)
    return path


def test_foreign_truncated_and_unsafe_npz_files_are_refused(tmp_path):
    good = save_log(full_log(), tmp_path / "good.npz")
    arrays = {"time": np.arange(20) * 0.01, "q": np.zeros((20, 7)), "dq": np.zeros((20, 7)), "tau": np.zeros((20, 7))}
    cases = {
        "foreign.npz": (_npz(tmp_path / "foreign.npz", x=np.ones(3), y=np.ones(2)), r"unknown arrays \['x', 'y'\]"),
        "no_meta.npz": (_npz(tmp_path / "no_meta.npz", **arrays), r"no 'meta' array"),
        "bad_json.npz": (
            _npz(tmp_path / "bad_json.npz", meta=np.array("{'a': 1}"), **arrays),
            "meta is not strict JSON",
        ),
        "nan_json.npz": (
            _npz(tmp_path / "nan_json.npz", meta=np.array('{"a": NaN}'), **arrays),
            "NaN is not valid JSON",
        ),
        "list_json.npz": (_npz(tmp_path / "list_json.npz", meta=np.array("[1]"), **arrays), "meta is a JSON list"),
        "format.npz": (
            _npz(tmp_path / "format.npz", format=np.array("other-2"), meta=np.array("{}"), **arrays),
            "format = 'other-2'",
        ),
        "pickled.npz": (
            _npz(tmp_path / "pickled.npz", meta=np.array([{"a": 1}], dtype=object), **arrays),
            "refused: it holds pickled objects",
        ),
        "invalid.npz": (
            _npz(tmp_path / "invalid.npz", meta=np.array("{}"), **{**arrays, "q": np.zeros((20, 6))}),
            "q has 6 joints; expected 7",
        ),
    }
    (tmp_path / "cut.npz").write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    cases["cut.npz"] = (tmp_path / "cut.npz", "truncated or foreign file")
    (tmp_path / "empty.npz").write_bytes(b"")
    cases["empty.npz"] = (tmp_path / "empty.npz", "the file is empty")
    (tmp_path / "text.npz").write_text("time,q0\n")
    cases["text.npz"] = (tmp_path / "text.npz", "not a zip archive")
    for name, (path, match) in cases.items():
        with pytest.raises(FileFormatError, match=match) as info:
            load_log(path)
        assert str(info.value).startswith(str(path)) and "\n" not in str(info.value), name
    with pytest.raises(FileNotFoundError, match="no robot log at"):
        load_log(tmp_path / "missing.npz")


def test_output_names_are_checked(tmp_path):
    with pytest.raises(InputError, match=r"expected a file name ending in \.npz"):
        save_log(full_log(), tmp_path / "log.npy")
    with pytest.raises(InputError, match=r"expected a file name ending in \.csv"):
        write_franka_csv(full_log(), tmp_path / "log.txt")
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------------------------- helpers


def test_slice_and_meta_helpers():
    log = validate_log(full_log())
    part = slice_log(log, 10, 25)
    assert part.n_samples == 15 and part.time[0] == log.time[10] and part.tool_pose.shape == (15, 4, 4)
    part.q[0, 0] = 99.0
    assert log.q[10, 0] != 99.0
    for start, stop in ((5, 5), (-1, 3), (0, T + 1)):
        with pytest.raises(InputError, match="expected"):
            slice_log(log, start, stop)
    tagged = with_meta(log, end_effector="none")
    assert tagged.meta["end_effector"] == "none" and log.meta["end_effector"] == "hand"
    assert validate_log(tagged).meta["end_effector"] == "none"
