"""A trained run's flow refitted to where its frozen policy succeeds (the skills' stage 4 on any
`goflow train` run folder), and the result against the environment's own feasible set.

    .venv/bin/python -m benchmarks.frozen_refit --runs runs/toy2d/toy2d-circle-entropy/goflow/seed0 ... \
        [--cells 100] [--repeats 8] [--level 0.8] [--rounds 20] [--episodes 256] [--json PATH]

For each run: the deterministic policy runs `--repeats` episodes (reset seeds 0, 1, ...) at the
centre of each of `--cells` cells per axis over the parameter box (learning.feasible_grid; for a
2-D box, 100 x 100). A cell belongs to the set F_pi where the policy succeeds when its success
rate reaches `--level` (with one repeat: when the episode succeeds, as for a deterministic
environment). The run's GoFlow flow is then refitted to F_pi in the constrained mode
(`refit_flow`: one update from the grid, `--rounds` from `--episodes` of its own draws, each
labelled by one episode).
Printed per run: the flow's mass on and coverage of F_pi, and of the environment's feasible set F
(an env with `feasible_set(points)`, e.g. Toy2D), before and after the refit.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch

from goflow_common.files import write_json
from learning.experiment import load_run, probe_env
from learning.feasible_grid import FeasibleGridConfig, FlowRefitConfig, flow_report, refit_flow
from learning.feasible_sets import report_on
from learning.skill_evaluation import rollout_return


def success_rate(agent, env, xi: np.ndarray, threshold: float, repeats: int) -> np.ndarray:
    """The deterministic policy's success rate (return >= threshold) at each row of xi over
    `repeats` episodes, reset with seeds 0 .. repeats - 1."""
    policy = SimpleNamespace(act=lambda obs: agent.act(obs, deterministic=True))
    return np.array(
        [np.mean([rollout_return(policy, x, env, seed=r) >= threshold for r in range(repeats)]) for x in xi]
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, nargs="+", required=True, help="goflow train run folders (GoFlow)")
    parser.add_argument("--cells", type=int, default=100, help="grid cells per axis over the box")
    parser.add_argument("--repeats", type=int, default=8, help="episodes per cell")
    parser.add_argument("--level", type=float, default=0.8, help="success rate from which a cell is in F_pi")
    parser.add_argument("--rounds", type=int, default=20)
    parser.add_argument("--episodes", type=int, default=256)
    parser.add_argument("--steps", type=int, default=FlowRefitConfig.steps)
    parser.add_argument("--classifier-steps", type=int, default=FlowRefitConfig.classifier_steps)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    if args.cells < 1 or args.repeats < 1:
        raise SystemExit(f"--cells and --repeats must be >= 1, got {args.cells} and {args.repeats}")
    if not 0.0 < args.level <= 1.0:
        raise SystemExit(f"--level must lie in (0, 1], got {args.level}")
    refit = FlowRefitConfig(
        rounds=args.rounds, episodes=args.episodes, steps=args.steps, classifier_steps=args.classifier_steps
    )
    torch.set_num_threads(1)
    rows = []
    print(
        f"{'run':48} {'F_pi':>6} {'F':>6} {'mass F_pi before/after':>23} {'cover F_pi':>11} "
        f"{'mass F before/after':>20} {'cover F before/after':>21} {'s':>5}"
    )
    for run in args.runs:
        t0 = time.perf_counter()
        loaded = load_run(run)
        env = probe_env(loaded.config.env, loaded.config.env_kwargs)
        if not hasattr(env, "feasible_set"):
            raise SystemExit(f"{loaded.config.env} has no feasible_set(points) to compare with")
        space = loaded.space
        plan = FeasibleGridConfig(
            fine_width=tuple(space.high - space.low),
            fine_cells=args.cells,
            coarse_cells=1,
            centre=tuple(space.center()),
        ).plan(space, space.center())
        threshold = loaded.state["log"]["success_threshold"]
        # a cell's value is its success rate, F_pi = {rate >= level}
        feasible = plan.feasible_set(
            success_rate(loaded.agent, env, plan.points(), threshold, args.repeats), args.level, "own"
        )
        before = (
            flow_report(loaded.sampler, feasible),
            report_on(loaded.sampler, env.feasible_set, space, np.random.default_rng(1)),
        )
        sampler, records = refit_flow(
            loaded.sampler, feasible, lambda xi, update: success_rate(loaded.agent, env, xi, threshold, 1), refit
        )
        after = (flow_report(sampler, feasible), report_on(sampler, env.feasible_set, space, np.random.default_rng(1)))
        row = {
            "run": str(run),
            "policy_set": {"before": before[0], "after": after[0]},
            "env_set": {"before": before[1], "after": after[1]},
            "updates": records,
            "seconds": time.perf_counter() - t0,
        }
        rows.append(row)
        print(
            f"{str(run)[-48:]:48} {after[0]['share']:6.3f} {after[1]['share']:6.3f} "
            f"{before[0]['mass_on']:>11.3f} / {after[0]['mass_on']:.3f} {after[0]['coverage10']:>11.3f} "
            f"{before[1]['mass_on']:>8.3f} / {after[1]['mass_on']:.3f} "
            f"{before[1]['coverage10']:>9.3f} / {after[1]['coverage10']:.3f} {row['seconds']:5.0f}",
            flush=True,
        )
        if args.json:
            write_json(args.json, {"cells": args.cells, "refit": refit.to_dict(), "rows": rows})


if __name__ == "__main__":
    main()
