"""File-level entry points of the diagnosis: what `goflow diagnose` and `goflow sim2real make-log`
run (a log path in, a report folder or a log file out, paths checked before the work)."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

from goflow_common.checks import check_choice
from goflow_common.files import check_output_dir, check_output_file
from sim2real.diagnosis import Diagnosis, DiagnosisConfig, diagnose

__all__ = ["diagnose_file", "make_log_file", "MODELS"]

MODELS = ("arm", "station", "perception")


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


def diagnose_file(
    log_path: str | Path,
    out: str | Path,
    model: str = "arm",
    config: DiagnosisConfig | None = None,
    progress: bool = False,
    episodes: int = 10,
) -> tuple[Diagnosis, list[Path]]:
    """Load the log at `log_path` (npz, Franka CSV or the Gaz et al. folder layout), diagnose it
    against `model` ("arm": the arm's torque and state channels; "perception": a perception log
    of sim2real.perception_channel, its pose channel; "station": an insertion log,
    contact effects included, with the skill's success rate over `episodes` episodes before and
    after the selected effects; 0 skips it) and write the report into folder `out`, created once
    the log has been read and checked before the diagnosis.

    Returns (the diagnosis, the report's files). Raises FileNotFoundError or FileFormatError for a
    missing or bad log (nothing is created then), OutputPathError for an unwritable `out`."""
    from sim2real.importers import load_log
    from sim2real.report import write_report

    check_choice(model, MODELS, "--model")
    start = time.perf_counter()
    if model == "perception":
        from sim2real.perception_channel import diagnose_perception, load_perception_log

        perception_log = load_perception_log(log_path)
        check_output_dir(out, "--out-dir")
        d = diagnose_perception(perception_log, progress=_bar(progress))
        d.log_meta.setdefault("source", str(log_path))
        return d, write_report(d, out, extra={"seconds": time.perf_counter() - start})
    log = load_log(log_path)  # the log is read before the report folder is made: a bad log leaves nothing
    check_output_dir(out, "--out-dir")
    if model == "station":
        from sim2real.contact import diagnose_insertion

        d = diagnose_insertion(log, config, progress=_bar(progress), episodes=episodes)
    else:
        d = diagnose(log, config, progress=_bar(progress))
    seconds = time.perf_counter() - start
    if not d.log_meta.get("source"):
        d.log_meta["source"] = str(log_path)
    paths = write_report(d, out, extra={"seconds": seconds})
    return d, paths


def make_log_file(
    effects: list[str], out: str | Path, overrides: dict[str, Any] | None = None, model: str = "arm"
) -> Path:
    """Make a log of a simulated reality with the effects given as NAME=VALUE or NAME.PARAM=VALUE
    strings (sim2real.catalogue.parse_effect_values) and save it at `out` (.npz, or .csv in the
    Franka layout for the arm); returns the path. model "arm": the arm on an exciting trajectory,
    `overrides` are RealityConfig fields; "perception": the scene camera's first look on random
    scenes (`overrides`: scenes, seed; sim2real.perception_channel); "station": one insertion
    episode of the shipped skill,
    `overrides` may set gear, seed, xi (sim2real.station_logs.make_insertion_log) and noise (default
    true: sensor noise on torques, tool position and contact force, station_logs.with_sensor_noise).
    InputError names a bad effect, option or file name before anything is simulated."""
    from goflow_common.config import config_with_overrides
    from goflow_common.errors import InputError
    from sim2real.catalogue import parse_effect_values
    from sim2real.importers import write_franka_csv
    from sim2real.log import save_log

    check_choice(model, MODELS, "--model")
    values = parse_effect_values(effects)
    path = check_output_file(out, "--out")
    if path.suffix not in (".npz", ".csv") or (model != "arm" and path.suffix != ".npz"):
        raise InputError(f"--out {out}: expected a .npz{' or .csv' if model == 'arm' else ''} file name")
    if model == "perception":
        from sim2real.perception_channel import make_perception_log, save_perception_log

        options = dict(overrides or {})
        unknown = set(options) - {"scenes", "seed"}
        if unknown:
            raise InputError(f"--model-kwarg {sorted(unknown)}: expected scenes or seed for a perception log")
        return save_perception_log(make_perception_log(values, **options), path)
    if model == "station":
        from sim2real.station_logs import make_insertion_log, with_sensor_noise

        options = dict(overrides or {})
        unknown = set(options) - {"gear", "seed", "xi", "noise"}
        if unknown:
            raise InputError(f"--model-kwarg {sorted(unknown)}: expected gear, seed, xi or noise for a station log")
        noise = options.pop("noise", True)
        if not isinstance(noise, bool):
            raise InputError(f"--model-kwarg noise={noise!r}; expected true or false")
        log, _ = make_insertion_log(values, **options)
        return save_log(with_sensor_noise(log, options.get("seed", 0)) if noise else log, path)
    from sim2real.reality import RealityConfig, make_arm_log

    config = config_with_overrides(RealityConfig, None, overrides or {}, "--model-kwarg")
    log = make_arm_log(values, config)
    (write_franka_csv if path.suffix == ".csv" else save_log)(log, path)
    return path
