"""Calibrate the simulated Panda logger: log_statistics of the real log beside a simulated nominal log.

Run as `.venv/bin/python -m benchmarks.sim2real_calibration [--duration 21] [--seed 0] [--json PATH]`;
prints (statistic, joint, real, simulated, ratio) and writes the statistics of both as JSON
(default docs/results/sim2real_calibration.json).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path
from typing import Any

__all__ = ["compare", "rows", "main"]

ROOT = Path(__file__).resolve().parents[1]
REAL_LOG = ROOT / "data" / "panda-gaz2019" / "log.npz"
DEFAULT_JSON = ROOT / "docs" / "results" / "sim2real_calibration.json"


def _flatten(stats: dict[str, Any], prefix: str = "") -> dict[tuple[str, str], float]:
    out: dict[tuple[str, str], float] = {}
    for key, value in stats.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(_flatten(value, name + " "))
        elif isinstance(value, list):
            out.update({(name, str(j + 1)): float(v) for j, v in enumerate(value)})
        else:
            out[(name, "")] = float(value)
    return out


def rows(real: dict[str, Any], sim: dict[str, Any]) -> list[dict[str, Any]]:
    """One row per statistic and joint: statistic, joint ("" when not per joint), real, simulated, ratio."""
    a, b = _flatten(real), _flatten(sim)
    out = []
    for key in a:
        r, s = a[key], b.get(key, math.nan)
        ratio = s / r if r and math.isfinite(r) and math.isfinite(s) else math.nan
        out.append({"statistic": key[0], "joint": key[1], "real": r, "simulated": s, "ratio": ratio})
    return out


def compare(duration: float = 21.0, seed: int = 0) -> dict[str, Any]:
    """log_statistics of the real log and of a simulated nominal log (no effects, no end effector,
    sensors "panda") of `duration` [s] and `seed`, with their side-by-side rows."""
    from sim2real.importers import load_log
    from sim2real.logger import PANDA_LOGGER, log_statistics
    from sim2real.reality import RealityConfig, make_arm_log
    from goflow_common.config import config_to_dict

    start = time.perf_counter()
    real = log_statistics(load_log(REAL_LOG))
    sim_log = make_arm_log({}, RealityConfig(duration=duration, end_effector="none", sensors="panda", seed=seed))
    sim = log_statistics(sim_log)
    return {
        "real_log": str(REAL_LOG.relative_to(ROOT)),
        "duration": duration,
        "seed": seed,
        "logger": config_to_dict(PANDA_LOGGER),
        "real": real,
        "simulated": sim,
        "rows": rows(real, sim),
        "seconds": time.perf_counter() - start,
    }


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=21.0, help="simulated log length [s]")
    parser.add_argument("--seed", type=int, default=0, help="the simulated log's seed")
    parser.add_argument("--json", type=Path, default=DEFAULT_JSON, help="where to write the statistics")
    args = parser.parse_args(argv)
    result = compare(args.duration, args.seed)
    print(f"{'statistic':<24} {'joint':>5} {'real':>11} {'simulated':>11} {'ratio':>7}")
    for row in result["rows"]:
        print(
            f"{row['statistic']:<24} {row['joint']:>5} {row['real']:>11.4g} {row['simulated']:>11.4g} "
            f"{row['ratio']:>7.3f}"
        )
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=1, allow_nan=True) + "\n")
    print(f"wrote {args.json} ({result['seconds']:.1f} s)")
    return result


if __name__ == "__main__":
    main()
