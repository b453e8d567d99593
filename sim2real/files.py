"""File-level entry points of the diagnosis: what `goflow diagnose` and `goflow sim2real make-log`
run (a log path in, a report folder or a log file out, paths checked before the work)."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

from common.checks import check_choice
from common.files import check_output_dir, check_output_file
from sim2real.diagnosis import Diagnosis, DiagnosisConfig, diagnose

__all__ = ["diagnose_file", "make_log_file", "MODELS"]

MODELS = ("arm", "station")


def _bar(progress: bool):
    """A progress callback drawing one tqdm bar per stage, or None."""
    if not progress:
        return None
    from tqdm import tqdm
    state: dict[str, Any] = {}

    def say(stage: str, i: int, n: int) -> None:
        if state.get("stage") != stage:
            if "bar" in state:
                state["bar"].close()
            state["stage"] = stage
            state["bar"] = tqdm(total=n, desc=stage, file=sys.stderr, leave=False)
        bar = state["bar"]
        bar.total = n
        bar.n = i
        bar.refresh()
        if i >= n and stage == "audit":
            bar.close()

    return say


def diagnose_file(log_path: str | Path, out: str | Path, model: str = "arm",
                  config: DiagnosisConfig | None = None, progress: bool = False) -> tuple[Diagnosis, list[Path]]:
    """Load the log at `log_path` (npz, Franka CSV or the Gaz et al. folder layout), diagnose it
    against `model` ("arm": the arm's torque and state channels; "station": an insertion log,
    contact effects included) and write the report into `out` (checked before any work)."""
    from sim2real.log import load_log
    from sim2real.report import write_report

    check_choice(model, MODELS, "--model")
    check_output_dir(out, "--out")
    log = load_log(log_path)
    start = time.perf_counter()
    if model == "station":
        from sim2real.contact import diagnose_insertion
        d = diagnose_insertion(log, config, progress=_bar(progress))
    else:
        d = diagnose(log, config, progress=_bar(progress))
    seconds = time.perf_counter() - start
    if not d.log_meta.get("source"):
        d.log_meta["source"] = str(log_path)
    paths = write_report(d, out, extra={"seconds": seconds})
    return d, paths


def make_log_file(effects: list[str], out: str | Path, overrides: dict[str, Any] | None = None) -> Path:
    """Make a log of the simulated arm reality with the effects given as NAME=VALUE or
    NAME.PARAM=VALUE strings (sim2real.catalogue.parse_effect_values) and RealityConfig field
    overrides, and save it at `out` (.npz, or .csv in the Franka layout); returns the path."""
    from common.config import config_with_overrides
    from sim2real.catalogue import parse_effect_values
    from sim2real.log import save_log
    from sim2real.importers import write_franka_csv
    from sim2real.reality import RealityConfig, make_arm_log

    values = parse_effect_values(effects)
    config = config_with_overrides(RealityConfig, None, overrides or {}, "sim2real make-log")
    path = check_output_file(out, "--out")
    if path.suffix not in (".npz", ".csv"):
        from common.errors import InputError
        raise InputError(f"--out {out}: expected a .npz or .csv file name")
    log = make_arm_log(values, config)
    (write_franka_csv if path.suffix == ".csv" else save_log)(log, path)
    return path
