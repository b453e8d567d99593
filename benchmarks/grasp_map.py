"""The pick with the real fingers against the grasp geometry: per simulated pick, the grasp error
predicted from where the pick aimed and the one measured after the lift; and the pick model the
planner loads (planning/data/pick_model.json, `planning.grasp.PICK_MODEL`).

    .venv/bin/python -m benchmarks.grasp_map --picks 15 --offset-std 0.002 --json docs/results/grasp_map.json \
        [--model planning/data/pick_model.json]
    .venv/bin/python -m benchmarks.grasp_map --from docs/results/grasp_map.json --model planning/data/pick_model.json

Each pick: one gear at a random pose in the placement region (assembly.world.random_gear_poses),
the scripted pick aimed at the truth plus N(0, offset-std) in x and y. Prints, per gear, the
residual along the fingers' closing axis (tool y: they centre the gear), the error along the other
axis (tool x) against the aimed one, and the yaw against the aimed one. `--model` writes those
(mean, std) per gear, metres to the micrometre and radians to 1e-5, with the command, date and
commit (the shipped file is written only when named); `--from` takes the picks of an earlier
`--json` instead of simulating them.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from assembly.gearset import GEAR_NAMES  # noqa: E402
from assembly.world import random_gear_poses  # noqa: E402
from benchmarks.provenance import command, provenance  # noqa: E402
from goflow_common.files import check_output_file, read_json, write_json  # noqa: E402
from planning.pick import simulate_pick  # noqa: E402

# the pick model's resolution: metres to the micrometre, radians to 1e-5
ROUNDING = {"m": 6, "rad": 5}


def pick_summary(rows: list[dict], gears: list[str]) -> list[dict]:
    """Per gear of `gears`, over its lifted picks in `rows` (as `main` records them): the closing
    axis' residual, the error along tool x and the yaw against the aimed ones (mean, std [m, rad]);
    None where no pick of the gear was lifted."""
    summary = []
    for gear in gears:
        rs = [r for r in rows if r["gear"] == gear and r["lifted"]]
        held = np.array([r["xi_held"] for r in rs]).reshape(-1, 3)
        aimed = np.array([r["xi_aimed"] for r in rs]).reshape(-1, 3)
        n = sum(r["gear"] == gear for r in rows)
        summary.append(
            {
                "gear": gear,
                "picks": n,
                "lifted": len(rs),
                "closing_mean_m": float(held[:, 1].mean()) if len(rs) else None,
                "closing_std_m": float(held[:, 1].std()) if len(rs) else None,
                "closing_max_abs_m": float(np.abs(held[:, 1]).max()) if len(rs) else None,
                "along_mean_m": float((held[:, 0] - aimed[:, 0]).mean()) if len(rs) else None,
                "along_std_m": float((held[:, 0] - aimed[:, 0]).std()) if len(rs) else None,
                "yaw_mean_rad": float((held[:, 2] - aimed[:, 2]).mean()) if len(rs) else None,
                "yaw_std_rad": float((held[:, 2] - aimed[:, 2]).std()) if len(rs) else None,
                "aimed_closing_std_m": float(aimed[:, 1].std()) if len(rs) else None,
            }
        )
    return summary


def pick_model(summary: list[dict]) -> dict[str, dict[str, list[float]]]:
    """planning.grasp.PICK_MODEL from `pick_summary`: per gear, (mean, std) of "closing" and "along"
    [m] and "yaw" [rad], rounded to ROUNDING. ValueError naming a gear none of whose picks lifted."""
    model = {}
    for s in summary:
        if not s["lifted"]:
            raise ValueError(f"gear {s['gear']!r}: no pick lifted; expected at least one for the pick model")
        model[s["gear"]] = {
            "closing": [round(s["closing_mean_m"], ROUNDING["m"]), round(s["closing_std_m"], ROUNDING["m"])],
            "along": [round(s["along_mean_m"], ROUNDING["m"]), round(s["along_std_m"], ROUNDING["m"])],
            "yaw": [round(s["yaw_mean_rad"], ROUNDING["rad"]), round(s["yaw_std_rad"], ROUNDING["rad"])],
        }
    return model


def simulate_picks(gears: list[str], picks: int, offset_std: float, seed: int) -> list[dict]:
    """`picks` simulated picks per gear (planning.pick.simulate_pick), each aimed at the truth
    plus N(0, offset_std) in x and y: one row per pick."""
    rng = np.random.default_rng(seed)
    rows = []
    for gear in gears:
        for _ in range(picks):
            truth = np.array(random_gear_poses(rng, gears=(gear,))[gear])
            believed = truth + [*rng.normal(0.0, offset_std, 2), 0.0]
            r = simulate_pick(gear, tuple(truth), tuple(believed))
            rows.append(
                {
                    "gear": gear,
                    "truth": truth.tolist(),
                    "believed": believed.tolist(),
                    "tool": r.tool.tolist(),
                    "xi_aimed": r.xi_aimed.tolist(),
                    "xi_held": None if r.xi_held is None else r.xi_held.tolist(),
                    "lifted": r.lifted,
                    "sim_error": r.sim_error,
                }
            )
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--picks", type=int, default=15, help="picks per gear")
    p.add_argument("--offset-std", type=float, default=0.002, help="aim offset std in x and y [m]")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--gears", nargs="+", default=list(GEAR_NAMES), choices=list(GEAR_NAMES))
    p.add_argument("--json", type=Path, help="write the picks and their summary")
    p.add_argument(
        "--from",
        dest="source",
        type=Path,
        metavar="JSON",
        help="the picks of an earlier --json instead of simulating them",
    )
    p.add_argument(
        "--model",
        type=Path,
        metavar="PATH",
        help="write the pick model the planner loads (planning/data/pick_model.json)",
    )
    args = p.parse_args(argv)
    if args.picks < 1 or not (np.isfinite(args.offset_std) and 0 <= args.offset_std <= 0.005):
        p.error(
            f"--picks {args.picks}, --offset-std {args.offset_std}: expected >= 1 and [0, 0.005] m "
            "(the open fingers clear the gear by 6 mm a side)"
        )
    for path in (args.json, args.model):
        if path:
            check_output_file(path)
    t0 = time.perf_counter()
    if args.source:
        recorded = read_json(args.source, "grasp_map result (--json)")
        if not isinstance(recorded, dict) or not isinstance(recorded.get("rows"), list):
            p.error(f"--from {args.source}: expected a --json result of this script (with 'rows')")
        rows, measured_by = recorded["rows"], f"{recorded.get('command')} (read from {args.source})"
        args.gears = [g for g in args.gears if any(r["gear"] == g for r in rows)]
    else:
        rows, measured_by = (
            simulate_picks(args.gears, args.picks, args.offset_std, args.seed),
            command("grasp_map", argv),
        )
    summary = pick_summary(rows, args.gears)
    print(
        "| gear | picks lifted | closing axis (tool y) held: mean / std / max abs [mm] | tool x held - aimed: mean / std [mm] | yaw held - aimed: mean / std [mrad] |"
    )
    print("|---|---|---|---|---|")
    for s in summary:
        if s["lifted"]:
            print(
                f"| {s['gear']} | {s['lifted']} of {s['picks']} | {1e3 * s['closing_mean_m']:.3f} / "
                f"{1e3 * s['closing_std_m']:.3f} / {1e3 * s['closing_max_abs_m']:.3f} "
                f"(aimed std {1e3 * s['aimed_closing_std_m']:.2f}) | "
                f"{1e3 * s['along_mean_m']:.3f} / {1e3 * s['along_std_m']:.3f} | "
                f"{1e3 * s['yaw_mean_rad']:.2f} / {1e3 * s['yaw_std_rad']:.2f} |"
            )
    print(f"{len(rows)} picks in {time.perf_counter() - t0:.0f} s")
    if args.json:
        write_json(args.json, {"command": measured_by, "summary": summary, "rows": rows})
    if args.model:
        try:
            model = pick_model(summary)
        except ValueError as exc:
            p.error(str(exc))
        write_json(
            args.model,
            {
                "what": "the real-finger pick per gear (planning.grasp.PICK_MODEL): (mean, std) of the residual "
                "along the fingers' closing axis (tool y) [m], of the push along tool x [m] and of the "
                "yaw change [rad]",
                **provenance("grasp_map", argv),
                "picks_measured_by": measured_by,
                "rounding": {"m": 10.0 ** -ROUNDING["m"], "rad": 10.0 ** -ROUNDING["rad"]},
                "pick_model": model,
            },
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
