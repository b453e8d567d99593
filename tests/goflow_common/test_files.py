"""goflow_common.files: atomic writes, strict JSON, data-only tensor loads, output paths, run locks."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch

from goflow_common.errors import FileFormatError, OutputPathError, RunFolderBusyError
from goflow_common.files import (
    check_output_dir,
    check_output_file,
    load_tensors,
    read_json,
    run_folder_lock,
    save_tensors,
    write_json,
)


class _Exploit:
    """A pickle that runs a shell command when it is loaded (what a crafted .pt file does)."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def test_a_crafted_file_is_refused_before_its_code_runs(tmp_path):
    marker = tmp_path / "pwned"
    crafted = tmp_path / "skill.pt"
    torch.save({"format": "goflow-skill-1", "payload": _Exploit(marker)}, crafted)
    with pytest.raises(FileFormatError, match=r"skill\.pt: refused.*expected a goflow skill file"):
        load_tensors(crafted, "goflow skill file")
    assert not marker.exists()


@pytest.mark.parametrize(
    "content, match",
    [
        (b"", "empty"),
        (b"not a torch file at all", "not a readable"),
    ],
)
def test_empty_and_foreign_files_get_one_line(tmp_path, content, match):
    path = tmp_path / "x.pt"
    path.write_bytes(content)
    with pytest.raises(FileFormatError, match=match) as info:
        load_tensors(path, "thing")
    assert "\n" not in str(info.value) and str(path) in str(info.value)


def test_a_truncated_file_gets_one_line(tmp_path):
    path = tmp_path / "t.pt"
    save_tensors(path, {"w": torch.ones(1000), "meta": {"a": [1, 2.5, "s"]}})
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(FileFormatError, match="truncated or foreign"):
        load_tensors(path, "thing")


def test_tensors_and_plain_data_round_trip(tmp_path):
    state = {"w": torch.arange(5.0), "meta": {"a": [1, 2.5, "s", None, True]}, "t": (1, 2)}
    back = load_tensors(save_tensors(tmp_path / "s.pt", state), "state")
    assert torch.equal(back["w"], state["w"]) and back["meta"] == state["meta"]
    with pytest.raises(FileNotFoundError, match="no state at"):
        load_tensors(tmp_path / "missing.pt", "state")


def test_json_is_strict(tmp_path):
    path = write_json(tmp_path / "a" / "b.json", {"x": float("inf"), "y": [float("nan"), 1.0], "p": tmp_path})
    text = path.read_text()
    assert "Infinity" not in text and "NaN" not in text
    assert json.loads(text)["x"] is None
    with pytest.raises(ValueError, match=r"\$\.y\[0\] = nan"):
        write_json(tmp_path / "c.json", {"y": [float("nan")]}, nonfinite="error")
    assert not (tmp_path / "c.json").exists()
    (tmp_path / "bad.json").write_text('{"x": Infinity}')
    with pytest.raises(FileFormatError, match="Infinity"):
        read_json(tmp_path / "bad.json")


def test_output_paths_are_checked_before_the_work(tmp_path):
    created = check_output_file(tmp_path / "new" / "folder" / "out.json")
    assert created.parent.is_dir() and not created.exists()
    a_file = tmp_path / "file"
    a_file.write_text("x")
    with pytest.raises(OutputPathError, match="cannot create the folder"):
        check_output_file(a_file / "out.json", "--json")
    with pytest.raises(OutputPathError, match="is a folder"):
        check_output_file(tmp_path, "--json")
    with pytest.raises(OutputPathError, match="is a file"):
        check_output_dir(a_file, "--out")


def test_a_run_folder_has_one_writer(tmp_path):
    run = tmp_path / "run"
    with run_folder_lock(run):
        with pytest.raises(RunFolderBusyError, match="in use by another run"):  # same process
            with run_folder_lock(run):
                pass
        code = textwrap.dedent(f"""
            from goflow_common.files import run_folder_lock
            from goflow_common.errors import RunFolderBusyError
            try:
                with run_folder_lock({str(run)!r}):
                    print("acquired")
            except RunFolderBusyError:
                print("busy")
        """)
        other = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=Path.cwd())
        assert other.stdout.strip() == "busy", other.stderr
    with run_folder_lock(run):  # released when the first writer is done
        pass
