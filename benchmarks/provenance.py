"""Where a shipped number came from: the command, the date and the git commit, for the data files
that calibration scripts write and the code loads (e.g. planning/data/pick_model.json)."""

from __future__ import annotations

import subprocess
import sys
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _git(*args: str) -> str | None:
    try:
        out = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def command(module: str, argv: list[str] | None = None) -> str:
    """The command line that runs benchmarks.`module` with `argv` (default: this process's)."""
    args = sys.argv[1:] if argv is None else argv
    return " ".join([".venv/bin/python -m", f"benchmarks.{module}", *args])


def provenance(module: str, argv: list[str] | None = None) -> dict[str, str | None]:
    """{"command", "date" (UTC, ISO 8601), "commit"} of this run of benchmarks.`module`: the commit
    is HEAD's hash, with "+dirty" where the working tree differs from it, None outside a git
    checkout."""
    commit = _git("rev-parse", "HEAD")
    if commit and _git("status", "--porcelain", "--untracked-files=no"):
        commit += "+dirty"
    return {
        "command": command(module, argv),
        "date": datetime.now(timezone.utc).replace(microsecond=0).isoformat(),
        "commit": commit,
    }


__all__ = ["command", "provenance"]
