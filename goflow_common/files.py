"""Files goflow writes and reads: atomic writes, strict JSON, tensor files loaded as data only,
output paths checked before the work, and run-folder locks.
"""

from __future__ import annotations

import io
import json
import math
import os
import pickle
import tempfile
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from goflow_common.errors import FileFormatError, OutputPathError, RunFolderBusyError

__all__ = [
    "write_atomic",
    "write_json",
    "read_json",
    "reject_json_constant",
    "to_strict_json",
    "save_tensors",
    "load_tensors",
    "check_output_file",
    "check_output_dir",
    "run_folder_lock",
]


def write_atomic(path: str | os.PathLike[str], data: bytes | str, mode: int = 0o644) -> Path:
    """Write `data` to `path` through a temporary file in the same folder and an atomic rename, so
    that a reader (or an interrupted writer) never sees a partial file; the folder must exist."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data.encode() if isinstance(data, str) else data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def to_strict_json(obj: Any, nonfinite: str = "null", where: str = "$") -> Any:
    """`obj` as plain strict-JSON data: tuples become lists, Paths strings, numpy/torch scalars
    numbers. Strict JSON has no NaN or Infinity: a non-finite float becomes None with
    `nonfinite="null"`, or raises ValueError naming where it is with `nonfinite="error"`."""
    if hasattr(obj, "item") and getattr(obj, "ndim", None) == 0:  # numpy / torch scalars
        obj = obj.item()
    if isinstance(obj, float):
        if math.isfinite(obj):
            return obj
        if nonfinite == "error":
            raise ValueError(f"{where} = {obj}: not a finite number, which strict JSON cannot hold")
        return None
    if isinstance(obj, dict):
        return {str(k): to_strict_json(v, nonfinite, f"{where}.{k}") for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_strict_json(v, nonfinite, f"{where}[{i}]") for i, v in enumerate(obj)]
    if isinstance(obj, Path):
        return str(obj)
    return obj


def write_json(path: str | os.PathLike[str], obj: Any, indent: int | None = 2, nonfinite: str = "null") -> Path:
    """Write `obj` as strict JSON, atomically, creating the folder. Non-finite floats become null
    (`nonfinite="null"`) or raise ValueError before anything is written (`nonfinite="error"`)."""
    path = Path(path)
    text = json.dumps(to_strict_json(obj, nonfinite), indent=indent, allow_nan=False)
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_atomic(path, text)


def reject_json_constant(name: str) -> Any:
    """json.loads' `parse_constant` for strict JSON: raises ValueError naming NaN / Infinity."""
    raise ValueError(f"{name} is not valid JSON")


def read_json(path: str | os.PathLike[str], what: str = "JSON file") -> Any:
    """Parse `path` as strict JSON; FileNotFoundError if missing, FileFormatError naming the file
    if it is empty or not strict JSON (NaN and Infinity are refused)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no {what} at {path}")
    text = path.read_text(errors="replace")
    if not text.strip():
        raise FileFormatError(f"{path}: the file is empty; expected a {what}")
    try:
        return json.loads(text, parse_constant=reject_json_constant)
    except ValueError as exc:
        raise FileFormatError(f"{path}: not a {what} (invalid JSON: {exc})") from exc


def save_tensors(path: str | os.PathLike[str], obj: Any) -> Path:
    """Save tensors and plain data (dicts, lists, numbers, strings) with torch.save, atomically.

    What is saved must load with `load_tensors` (torch.load(weights_only=True)): no arbitrary
    objects, which would need code to run at load time."""
    import torch

    buf = io.BytesIO()
    torch.save(obj, buf)
    return write_atomic(path, buf.getvalue())


def load_tensors(path: str | os.PathLike[str], what: str) -> Any:
    """Load a file written by `save_tensors` as data only (torch.load with weights_only=True).

    Raises FileNotFoundError if there is no file, and FileFormatError naming the file and `what`
    was expected if it is empty, truncated, not a torch file, or holds anything but tensors and
    plain data (such a file is refused before any of its code could run)."""
    import torch

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no {what} at {path}")
    if path.stat().st_size == 0:
        raise FileFormatError(f"{path}: the file is empty; expected a {what}")
    if not zipfile.is_zipfile(path):  # torch.save writes a zip archive; its end is read first
        raise FileFormatError(f"{path}: not a readable {what} (truncated or foreign file: not a torch archive)")
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        first = str(exc).strip().splitlines()
        reason = next(
            (line.strip() for line in first if "Unsupported" in line or "global" in line.lower()),
            first[0] if first else "",
        )
        raise FileFormatError(
            f"{path}: refused: it holds objects other than tensors and plain data ({reason[:160]}); expected a {what}"
        ) from None
    except (RuntimeError, EOFError, zipfile.BadZipFile, OSError, ValueError, KeyError) as exc:
        reason = str(exc).strip().splitlines()[0][:160] if str(exc).strip() else type(exc).__name__
        raise FileFormatError(f"{path}: not a readable {what} (truncated or foreign file: {reason})") from None


def _probe_writable(folder: Path, what: str, shown: Path) -> None:
    try:
        fd, tmp = tempfile.mkstemp(prefix=".goflow-probe.", dir=folder)
    except OSError as exc:
        raise OutputPathError(f"{what} {shown}: cannot write in {folder} ({exc.strerror or exc})") from None
    os.close(fd)
    os.unlink(tmp)


def check_output_file(path: str | os.PathLike[str], what: str = "output") -> Path:
    """Check before the work that a file can be written at `path`: its folder is created if
    missing (the convention for every output), and OutputPathError names the path when the folder
    cannot be created or written, or `path` is a folder."""
    path = Path(path)
    if path.is_dir():
        raise OutputPathError(f"{what} {path}: is a folder; expected a file path")
    blocking = next((p for p in reversed(path.parents) if p.exists() and not p.is_dir()), None)
    if blocking is not None:
        raise OutputPathError(f"{what} {path}: cannot create the folder {path.parent} ({blocking} is a file)")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputPathError(
            f"{what} {path}: cannot create the folder {path.parent} ({exc.strerror or exc})"
        ) from None
    if path.exists() and not os.access(path, os.W_OK):
        raise OutputPathError(f"{what} {path}: the file exists and is not writable")
    _probe_writable(path.parent, what, path)
    return path


def check_output_dir(path: str | os.PathLike[str], what: str = "output folder") -> Path:
    """Check before the work that `path` is (or can be created as) a writable folder; creates it.
    OutputPathError names the path otherwise."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputPathError(f"{what} {path}: is a file; expected a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputPathError(f"{what} {path}: cannot create it ({exc.strerror or exc})") from None
    _probe_writable(path, what, path)
    return path


LOCK_NAME = ".lock"


@contextmanager
def run_folder_lock(folder: str | os.PathLike[str]) -> Iterator[Path]:
    """Hold an OS file lock on `folder` (created if missing) for the duration of the block.

    A second writer, in this or another process, gets RunFolderBusyError at once instead of
    overwriting the first one's files. The lock is released when the block ends or the process
    dies (it is the operating system's lock, through the `filelock` package)."""
    from filelock import FileLock, Timeout

    folder = check_output_dir(folder, "run folder")
    lock = FileLock(str(folder / LOCK_NAME), timeout=0)
    try:
        lock.acquire()
    except Timeout:
        raise RunFolderBusyError(
            f"run folder {folder} is in use by another run (it holds {folder / LOCK_NAME}); "
            "wait for it to finish or choose another folder"
        ) from None
    try:
        yield folder
    finally:
        lock.release()
