"""Real-time factor of the station, by phase of the scripted medium-gear pick-and-insert.

Prints one table: for each (contact model, time step, discrete approximation) the real-time factor
(simulated seconds per wall second, one process, one core) in
  free motion  - the arm moving with nothing in the hand (the other gears resting on the table),
  insertion    - the gear on the shaft: align, insert, settle,
and whether the gear ended seated. Run:

    .venv/bin/python -m benchmarks.sim_speed                 # the station's defaults + point contact
    .venv/bin/python -m benchmarks.sim_speed --sweep         # time steps x approximations
    .venv/bin/python -m benchmarks.sim_speed --json docs/results/sim_speed.json
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from assembly.demo import AssemblyConfig, build_assembly
from assembly.station import StationConfig
from goflow_common.files import write_json

# Phases of the scripted pick-and-insert motion (labels "<gear>: <phase>") and the bucket each one counts toward.
FREE = ("approach", "steady above gear", "descend")
INSERTION = ("steady above shaft", "insert", "settle")


def measure(contact_model: str, time_step: float, approximation: str, gear: str = "medium") -> dict:
    """Real-time factors of one configuration over the phases of a single-gear insertion."""
    config = AssemblyConfig(
        station=StationConfig(
            time_step=time_step, contact_model=contact_model, discrete_contact_approximation=approximation
        ),
        order=(gear,),
    )
    run = build_assembly(config)
    buckets = {"free": [0.0, 0.0], "insertion": [0.0, 0.0]}
    error = None
    for previous, keyframe in zip(run.plan.keyframes, run.plan.keyframes[1:]):
        phase = keyframe.label.split(": ", 1)[-1]
        start = time.perf_counter()
        try:
            run.simulator.AdvanceTo(keyframe.t)
        except RuntimeError as exc:
            error = str(exc).splitlines()[0]
            break
        wall = time.perf_counter() - start
        bucket = "free" if phase in FREE else "insertion" if phase in INSERTION else None
        if bucket:
            buckets[bucket][0] += keyframe.t - previous.t
            buckets[bucket][1] += wall
    err = run.station.insertion_error(run.root_context, gear)
    return {
        "contact_model": contact_model,
        "time_step": time_step,
        "approximation": approximation,
        "rtf_free": buckets["free"][0] / max(buckets["free"][1], 1e-9),
        "rtf_insertion": buckets["insertion"][0] / max(buckets["insertion"][1], 1e-9),
        "seated": bool(err.inserted),
        "lateral_mm": 1e3 * err.lateral_m,
        "height_mm": 1e3 * err.height_m,
        "error": error,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--sweep", action="store_true", help="also sweep time steps {1, 2, 4, 5, 8} ms and approximations"
    )
    parser.add_argument("--json", type=Path, help="write the rows as JSON")
    args = parser.parse_args()
    default = StationConfig()
    configs = [
        ("hydroelastic_with_fallback", default.time_step, default.discrete_contact_approximation),
        ("point", default.time_step, default.discrete_contact_approximation),
    ]
    if args.sweep:
        configs += [
            ("hydroelastic_with_fallback", dt, approx)
            for approx in ("lagged", "similar", "sap")
            for dt in (0.001, 0.002, 0.004, 0.005, 0.008)
            if (dt, approx) != (default.time_step, default.discrete_contact_approximation)
        ]
    rows = []
    header = (
        f"{'contact':<27} {'dt [ms]':>7} {'approx':<8} {'RTF free':>9} {'RTF insert':>10} "
        f"{'seated':<6} {'lat [mm]':>8} {'h [mm]':>7}"
    )
    print(header)
    print("-" * len(header))
    for contact, dt, approx in configs:
        row = measure(contact, dt, approx)
        rows.append(row)
        print(
            f"{contact:<27} {1e3 * dt:>7.1f} {approx:<8} {row['rtf_free']:>9.2f} "
            f"{row['rtf_insertion']:>10.2f} {str(row['seated']):<6} {row['lateral_mm']:>8.2f} "
            f"{row['height_mm']:>7.2f}" + (f"  FAILED: {row['error']}" if row["error"] else ""),
            flush=True,
        )
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        write_json(args.json, {"rows": rows})


if __name__ == "__main__":
    main()
