"""Leave-one-effect-out validation of the sim-to-real diagnosis, on logs made by the simulated
reality and diagnosed without being told.

--grid realistic (default; sim2real/realistic.py): torque-only logs with the calibrated Panda
logger, in the real log's folder layout and the Franka CSV layout, every torque-only effect at
in-band SNR 8 and 2.5, pairs, noise-only logs and effects outside the catalogue, 20 s each:

    .venv/bin/python -m benchmarks.sim2real_validation --seeds 0 1 2 --workers 2 --json docs/results/sim2real_realistic.json

--grid easy: the white-noise, uniformly sampled logs with every channel (the grid of the version
before; every arm effect at three magnitudes, pairs, effects outside the catalogue) and the
station contact case:

    .venv/bin/python -m benchmarks.sim2real_validation --grid easy [--seeds 0 1] [--duration 10] [--workers 2]
        [--out runs/sim2real_validation] [--json docs/results/sim2real.json] [--no-contact]

Each case writes <out>/<case>.json atomically and is skipped when present with the same --duration
and --torque-filter, by a diagnosis with the same structure thresholds (rerun to resume; a case made
with other settings is made again). The
summary (rates per magnitude group and per effect, sim2real.validation.rates_by_magnitude) and every case's
row go to --json, and a table is printed.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from goflow_common.files import check_output_dir, check_output_file, read_json, write_json
from learning.execution import Job, make_backend, run_grid
from sim2real.realistic import UNIT_SETTINGS, realistic_cases, run_realistic, summarize_realistic
from sim2real.validation import MAGNITUDES, cases, run_case, rates_by_magnitude

ROOT = Path(__file__).resolve().parents[1]


def _realistic_job(case, duration: float, path: str) -> dict:
    """One realistic case, or its saved result when made with the same log length and settings."""
    from sim2real.diagnosis import DiagnosisConfig

    settings = {"duration": duration, "config": repr(DiagnosisConfig())}
    if Path(path).is_file():
        saved = read_json(path, "validation case")
        if saved.get("settings") == settings:
            return saved
    result = run_realistic(case, duration)
    result["settings"] = settings
    write_json(path, result)
    return result


def _run_realistic(args, argv) -> int:
    out = check_output_dir(args.out, "--out")
    summary_path = check_output_file(args.json or out / "summary.json", "--json")
    grid = realistic_cases(tuple(args.seeds), tuple(args.effects) if args.effects else None)
    jobs = [Job(c.name, _realistic_job, (c, args.duration, str(out / f"{c.name}.json"))) for c in grid]
    with make_backend(None, args.workers) as backend:
        results = run_grid(jobs, backend, desc="sim2real realistic validation")
    summary = {
        "command": "benchmarks/sim2real_validation.py " + " ".join(argv or sys.argv[1:]),
        "duration": args.duration,
        "seeds": args.seeds,
        "summary": summarize_realistic(results),
        "cases": results,
    }
    write_json(summary_path, summary)
    pct = lambda v: "-" if v is None else f"{100 * v:.0f} %"  # noqa: E731
    print("| group | cases | named right | where right | explained / unexplained / no gap | diagnosis [s] |")
    print("|---|---|---|---|---|---|")
    for group, row in summary["summary"].items():
        if group in ("per_effect", "floor_check"):
            continue
        v = row["verdicts"]
        print(
            f"| {group} | {row['cases']} | {pct(row['right'])} | {pct(row['where_right'])} | "
            f"{v['explained']} / {v['unexplained']} / {v['no gap']} | {row['diagnose_s_median']:.1f} |"
        )
    fc = summary["summary"].get("floor_check")
    if fc:
        print(f"\nfloor check ({fc['logs']} noise-only logs), predicted / observed in-band residual per joint:")
        print("| | " + " | ".join(f"J{j + 1}" for j in range(7)) + " |\n|---|" + "---|" * 7)
        for k in ("mean", "min", "max"):
            print(f"| {k} | " + " | ".join(f"{v:.2f}" for v in fc[k]) + " |")
    print("\n| effect (SNR) | n | named right | where right | missed as |\n|---|---|---|---|---|")
    for name, row in summary["summary"]["per_effect"].items():
        print(f"| {name} | {row['n']} | {row['right']} | {row['where']} | {row['missed_as'] or ''} |")
    return 0


def _case_job(case, duration: float, path: str, torque_filter: str = "matched", band: bool = False) -> dict:
    """One case, or its saved result when that was made with the same log length and filter."""
    from sim2real.diagnosis import DiagnosisConfig

    c = DiagnosisConfig()
    settings = {"duration": duration, "torque_filter": torque_filter, "structure": [c.structure, c.structure_rest]}
    if band:
        settings["band"] = repr(c.band)
    if Path(path).is_file():
        saved = read_json(path, "validation case")
        if saved.get("settings") == settings:
            return saved
    from sim2real.replay import ReplayConfig

    result = run_case(
        case, duration, DiagnosisConfig(replay=ReplayConfig(torque_filter=torque_filter), band=c.band if band else None)
    )
    result["settings"] = settings
    write_json(path, result)
    return result


def _contact_job(path: str, episodes: int) -> dict:
    """The station case: shaft friction withheld from the sim; localisation, naming, success gap."""
    if Path(path).is_file():
        return read_json(path, "contact case")
    from sim2real.contact import diagnose_insertion, downstream
    from sim2real.station_logs import CONTACT_CASE, make_insertion_log, with_sensor_noise

    log, _ = make_insertion_log(CONTACT_CASE, gear="medium", seed=0)
    log = with_sensor_noise(log)  # the "real" log's sensors
    d = diagnose_insertion(log, episodes=episodes, truth_success=lambda: downstream(CONTACT_CASE, "medium", episodes))
    s = d.summary()
    out = {
        "case": "contact shaft_friction mu=1.0",
        "selected": [r["effect"] for r in s["selected"]],
        "fitted": {r["effect"]: {k: v["value"] for k, v in r["params"].items()} for r in s["selected"]},
        "dominant_phase": s["where"]["dominant_phase"],
        "phase_excess_per_sample": {k: v["excess"] / v["samples"] for k, v in s["where"]["phases"].items()},
        "closed": s["how_far"]["closed_total"],
        "verdict": s["verdict"]["label"],
        "downstream": s.get("downstream"),
    }
    write_json(path, out)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--grid",
        choices=["realistic", "easy"],
        default="realistic",
        help="realistic: torque-only logs with the Panda's logger; easy: white noise, every channel",
    )
    p.add_argument("--seeds", type=int, nargs="+", default=None, help="default: 0 1 2 (realistic), 0 1 (easy)")
    p.add_argument("--duration", type=float, default=None, help="seconds per log (default: 20 realistic, 10 easy)")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--out", type=Path, default=ROOT / "runs" / "sim2real_validation")
    p.add_argument("--json", type=Path, default=None, help="summary JSON (default <out>/summary.json)")
    p.add_argument("--no-contact", action="store_true", help="skip the station contact case")
    p.add_argument("--episodes", type=int, default=10, help="episodes per success rate of the contact case")
    p.add_argument(
        "--torque-filter",
        default="matched",
        choices=["none", "matched"],
        help="the replay's torque filter (sim2real.replay.ReplayConfig.torque_filter)",
    )
    p.add_argument(
        "--band",
        choices=["none", "auto"],
        default="none",
        help="easy grid: judge every sample against the broadband floor (none, default: these logs' "
        "in-band noise is under the simulated reality's own misfit) or in the band (auto)",
    )
    p.add_argument(
        "--effects",
        nargs="+",
        choices=sorted(set(MAGNITUDES) | set(UNIT_SETTINGS)),
        metavar="NAME",
        help="only these effects' cases and the effects outside the catalogue (default: the whole grid)",
    )
    args = p.parse_args(argv)
    realistic = args.grid == "realistic"
    args.seeds = args.seeds or ([0, 1, 2] if realistic else [0, 1])
    args.duration = args.duration or (20.0 if realistic else 10.0)
    if realistic:
        if args.effects and not set(args.effects) <= set(UNIT_SETTINGS):
            p.error(
                f"--effects {sorted(set(args.effects) - set(UNIT_SETTINGS))}: not shown by a torque-only log; "
                f"expected some of {sorted(UNIT_SETTINGS)}"
            )
        if args.out == ROOT / "runs" / "sim2real_validation":
            args.out = ROOT / "runs" / "sim2real_realistic"
        return _run_realistic(args, argv)
    if args.effects and not set(args.effects) <= set(MAGNITUDES):
        p.error(
            f"--effects {sorted(set(args.effects) - set(MAGNITUDES))}: not in the easy grid; expected some of "
            f"{sorted(MAGNITUDES)}"
        )
    out = check_output_dir(args.out, "--out")
    summary_path = check_output_file(args.json or out / "summary.json", "--json")
    grid = cases(seeds=tuple(args.seeds), effects=tuple(args.effects) if args.effects else None, pairs=not args.effects)
    jobs = [
        Job(c.name, _case_job, (c, args.duration, str(out / f"{c.name}.json"), args.torque_filter, args.band == "auto"))
        for c in grid
    ]
    if not args.no_contact:
        jobs.append(Job("contact", _contact_job, (str(out / "contact.json"), args.episodes)))
    with make_backend(None, args.workers) as backend:
        results = run_grid(jobs, backend, desc="sim2real validation")
    arm = [r for r in results if "magnitude" in r]
    summary = {
        "command": "benchmarks/sim2real_validation.py " + " ".join(argv or sys.argv[1:]),
        "torque_filter": args.torque_filter,
        "duration": args.duration,
        "seeds": args.seeds,
        "summary": rates_by_magnitude(arm),
        "cases": arm,
    }
    if not args.no_contact:
        summary["contact"] = results[-1]
    write_json(summary_path, summary)
    pct = lambda v: "-" if v is None else f"{100 * v:.0f} %"  # noqa: E731
    no_gap = lambda row: f"{row['no_gap']}" + (f" ({row['inactive']} never acted)" if row["inactive"] else "")  # noqa: E731
    print(
        "| group | cases | top-1 | located | verdict explained | no gap above the floor | closed (median) | closed >= 80 % |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for group, row in summary["summary"].items():
        if group == "per_effect":
            continue
        print(
            f"| {group} | {row['cases']} | {pct(row['top1'])} | {pct(row['located'])} | {pct(row['explained'])} | {no_gap(row)} | "
            f"{pct(row['closed_median'])} | {pct(row['closed_ge_80'])} |"
        )
    print("\n| effect (magnitude) | n | top-1 | located | no gap | closed (mean) |\n|---|---|---|---|---|---|")
    for name, row in summary["summary"]["per_effect"].items():
        print(
            f"| {name} | {row['n']} | {pct(row['top1'])} | {pct(row['located'])} | {no_gap(row)} | "
            f"{pct(row['closed'])} |"
        )
    if not args.no_contact:
        print("\ncontact:", summary["contact"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
