"""The pick with the real fingers against the grasp geometry: per simulated pick, the grasp error
predicted from where the pick aimed and the one measured after the lift.

    .venv/bin/python benchmarks/grasp_map.py --picks 15 --offset-std 0.002 --json docs/results/grasp_map.json

Each pick: one gear at a random pose in the placement region (assembly.world.random_gear_poses),
the scripted pick aimed at the truth plus N(0, offset-std) in x and y. Prints, per gear, the
residual along the fingers' closing axis (tool y: they centre the gear), the error along the other
axis (tool x) against the aimed one, and the yaw against the aimed one.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from assembly.gearset import GEAR_NAMES  # noqa: E402
from assembly.world import random_gear_poses  # noqa: E402
from goflow_common.files import check_output_file, write_json  # noqa: E402
from planning.pick import simulate_pick  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--picks", type=int, default=15, help="picks per gear")
    p.add_argument("--offset-std", type=float, default=0.002, help="aim offset std in x and y [m]")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--gears", nargs="+", default=list(GEAR_NAMES), choices=list(GEAR_NAMES))
    p.add_argument("--json", type=Path)
    args = p.parse_args(argv)
    if args.picks < 1 or not (np.isfinite(args.offset_std) and 0 <= args.offset_std <= 0.005):
        p.error(f"--picks {args.picks}, --offset-std {args.offset_std}: expected >= 1 and [0, 0.005] m "
                "(the open fingers clear the gear by 6 mm a side)")
    if args.json:
        check_output_file(args.json)
    rng = np.random.default_rng(args.seed)
    rows, t0 = [], time.perf_counter()
    for gear in args.gears:
        for _ in range(args.picks):
            truth = np.array(random_gear_poses(rng, gears=(gear,))[gear])
            believed = truth + [*rng.normal(0.0, args.offset_std, 2), 0.0]
            r = simulate_pick(gear, tuple(truth), tuple(believed))
            rows.append({"gear": gear, "truth": truth.tolist(), "believed": believed.tolist(),
                         "tool": r.tool.tolist(), "xi_aimed": r.xi_aimed.tolist(),
                         "xi_held": None if r.xi_held is None else r.xi_held.tolist(),
                         "lifted": r.lifted, "sim_error": r.sim_error})
    summary = []
    print("| gear | picks lifted | closing axis (tool y) held: mean / std / max abs [mm] | tool x held - aimed: mean / std [mm] | yaw held - aimed: mean / std [mrad] |")
    print("|---|---|---|---|---|")
    for gear in args.gears:
        rs = [r for r in rows if r["gear"] == gear and r["lifted"]]
        held = np.array([r["xi_held"] for r in rs]).reshape(-1, 3)
        aimed = np.array([r["xi_aimed"] for r in rs]).reshape(-1, 3)
        n = sum(r["gear"] == gear for r in rows)
        s = {"gear": gear, "picks": n, "lifted": len(rs),
             "closing_mean_m": float(held[:, 1].mean()) if len(rs) else None,
             "closing_std_m": float(held[:, 1].std()) if len(rs) else None,
             "closing_max_abs_m": float(np.abs(held[:, 1]).max()) if len(rs) else None,
             "along_mean_m": float((held[:, 0] - aimed[:, 0]).mean()) if len(rs) else None,
             "along_std_m": float((held[:, 0] - aimed[:, 0]).std()) if len(rs) else None,
             "yaw_mean_rad": float((held[:, 2] - aimed[:, 2]).mean()) if len(rs) else None,
             "yaw_std_rad": float((held[:, 2] - aimed[:, 2]).std()) if len(rs) else None,
             "aimed_closing_std_m": float(aimed[:, 1].std()) if len(rs) else None}
        summary.append(s)
        if rs:
            print(f"| {gear} | {len(rs)} of {n} | {1e3 * s['closing_mean_m']:.3f} / {1e3 * s['closing_std_m']:.3f} / "
                  f"{1e3 * s['closing_max_abs_m']:.3f} (aimed std {1e3 * s['aimed_closing_std_m']:.2f}) | "
                  f"{1e3 * s['along_mean_m']:.3f} / {1e3 * s['along_std_m']:.3f} | "
                  f"{1e3 * s['yaw_mean_rad']:.2f} / {1e3 * s['yaw_std_rad']:.2f} |")
    print(f"{len(rows)} picks in {time.perf_counter() - t0:.0f} s")
    if args.json:
        write_json(args.json, {"command": " ".join(sys.argv), "summary": summary, "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
