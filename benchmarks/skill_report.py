"""Report on the shipped insertion skills: success on the uniform box and on samples of each
skill's own flow, in the fast variant and on the full Panda station, plus how wide each flow is
and, for a file that holds a measured feasible set, the flow's mass on it and coverage of it.

    .venv/bin/python -m benchmarks.skill_report [--gears small medium large] [--episodes 100]
        [--panda-episodes 100] [--xi flow uniform] [--json docs/results/skills.json]
    .venv/bin/python -m benchmarks.skill_report --xi radius:0.002 radius:0.005 --panda-episodes 0   # capture ranges

Prints one table; the JSON holds every row (the `goflow evaluate` schema plus the flow's width and
its report against the feasible set, learning.feasible_grid.flow_report).
The trust threshold eps is given relative to the uniform density over the box (eps = ratio / volume).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from learning.skill_evaluation import evaluate_skill, feasible_report, flow_width, xi_source
from learning.skill_file import load_skill, skill_path
from goflow_common.files import write_json


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gears", nargs="+", default=["small", "medium", "large"])
    parser.add_argument("--episodes", type=int, default=100, help="episodes per row, fast variant")
    parser.add_argument("--panda-episodes", type=int, default=100, help="episodes per row, panda variant")
    parser.add_argument(
        "--eps-ratio",
        type=float,
        nargs="+",
        default=[1.0, 10.0, 100.0],
        help="trust thresholds as multiples of the uniform density",
    )
    parser.add_argument(
        "--xi",
        nargs="+",
        default=["flow", "uniform"],
        type=xi_source,
        help="where the episodes' grasp errors come from: flow, uniform or radius:R (the disk of radius R "
        "metres around the skill's centre, `goflow evaluate --xi-from radius:R`)",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path)
    parser.add_argument(
        "--skill-dir",
        type=Path,
        help="skill files insert-<gear>.pt to report on instead of the shipped ones (e.g. another recipe's exports)",
    )
    args = parser.parse_args()
    rows = []
    print(f"{'gear':<7} {'variant':<6} {'xi':<14} {'success':>8} {'+-':>6} {'return':>7} {'seconds':>8}")
    for gear in args.gears:
        path = args.skill_dir / f"insert-{gear}.pt" if args.skill_dir else skill_path("insert", gear)
        if not path.is_file():
            print(f"{gear:<7} no skill file {path}")
            continue
        skill = load_skill("insert", gear, path=path)
        volume = float((skill.space.high - skill.space.low).prod())
        widths = [flow_width(skill, eps=ratio / volume) for ratio in args.eps_ratio]
        feasible = feasible_report(skill)
        for variant, episodes in (("fast", args.episodes), ("panda", args.panda_episodes)):
            for xi in args.xi if episodes > 0 else ():
                result = evaluate_skill(skill, variant=variant, xi=xi, episodes=episodes, seed=args.seed).to_json()
                result["flow"] = widths
                result["feasible_set"] = feasible
                result["provenance"] = {
                    k: skill.provenance.get(k) for k in ("command", "steps", "train_seconds", "final_uniform_success")
                }
                rows.append(result)
                print(
                    f"{gear:<7} {variant:<6} {xi:<14} {result['success_rate']:8.3f} {result['success_se']:6.3f} "
                    f"{result['mean_return']:7.2f} {result['seconds']:8.0f}",
                    flush=True,
                )
        for w in widths:
            print(
                f"{gear:<7} flow entropy {w['entropy']:.2f} nats (uniform {w['uniform_entropy']:.2f}); density > "
                f"{w['eps_uniform_ratio']:g} x uniform on {100 * w['trusted_fraction']:.2f} % of the box"
            )
        if feasible is not None:
            print(
                f"{gear:<7} measured feasible set: {100 * feasible['share']:.3f} % of the box; "
                f"flow mass on it {feasible['mass_on']:.3f}, coverage {feasible['coverage10']:.3f} (10 %) "
                f"{feasible['coverage1']:.3f} (1 %)"
            )
        if args.json:
            args.json.parent.mkdir(parents=True, exist_ok=True)
            write_json(args.json, {"rows": rows})


if __name__ == "__main__":
    main()
