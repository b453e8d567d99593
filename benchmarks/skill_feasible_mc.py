"""A shipped skill's flow against where its policy succeeds, by Monte Carlo episodes instead of
the measured grid (issue 21, items 4-5).

    .venv/bin/python -m benchmarks.skill_feasible_mc --gear medium [--draws 600] [--uniform 4000] \\
        [--seed 0] [--out runs/skill_mc] [--json PATH]

The skill's measured feasible set (`Skill.feasible`) labels each 0.3 mm grid cell by one episode
at its centre, so its edge is a staircase that is right only to a cell; on the medium and large
gears' sets a third of the cells lie on that edge, more than the 1 % of mass and 5 % of F the
targets allow. This script measures the same two numbers against the policy itself:
- mass on F: the share of `--draws` draws of the skill's flow on which the deterministic policy
  succeeds (return >= J_T) in every variant the measured set was made in (e.g. "fast+panda": a
  fast-variant success is run again on the full Panda station and must succeed there too);
- coverage of F at 10 % (1 %) of the uniform-on-F density: `--uniform` points uniform on the
  grid's fine region, each run the same way; the successes are points uniform on F there, F's
  share of the box is the fine region's times their rate, and coverage is the share of them where
  the flow's density exceeds the level (`learning.feasible_sets.coverage`). The grid's coarse cells
  outside the fine region are reported with their successes: where they hold none, F lies in the
  fine region.
Each estimate comes with its binomial standard error, beside the grid's numbers
(`learning.feasible_grid.flow_report`) and the grid's agreement with the episodes at the same
points. Every part of `--part` episodes is saved in `--out` as it finishes, and the same command
resumes from there.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch


from assembly.gearset import GEARS
from goflow_common.checks import InputErrorParser, check_int
from goflow_common.errors import GoflowError, InputError
from goflow_common.files import check_output_file, write_json
from learning.feasible_grid import flow_report
from learning.feasible_sets import coverage
from learning.skill_evaluation import rollout_return
from learning.skill_file import load_skill, Skill

NAME = "skill_feasible_mc"


def successes(skill: Skill, xi: np.ndarray, variants: list[str], store: Path, label: str, part: int) -> np.ndarray:
    """Whether the policy succeeds at each row of `xi` in every one of `variants` (run in order,
    each only where the ones before succeeded); parts of `part` rows are kept in `store` (JSON)."""
    done: dict[str, list[float]] = json.loads(store.read_text()) if store.is_file() else {}
    ok = np.ones(len(xi), bool)
    for variant in variants:
        rows = np.flatnonzero(ok)
        returns = np.full(len(xi), -math.inf)
        env = None
        try:
            for start in range(0, len(rows), part):
                key = f"{label}/{variant}/{start}/{len(rows)}"
                if key not in done:
                    env = env or skill.make_env(variant)
                    t0 = time.perf_counter()
                    done[key] = [rollout_return(skill, x, env) for x in xi[rows[start : start + part]]]
                    write_json(store, done)
                    print(
                        f"{NAME}: {skill.gear} {label} {variant} rows {start}-{start + part} of {len(rows)} "
                        f"({time.perf_counter() - t0:.0f} s)",
                        flush=True,
                    )
                returns[rows[start : start + part]] = done[key]
        finally:
            if env is not None:
                env.close()
        ok &= returns >= skill.success_threshold
    return ok


def binomial(k: int, n: int) -> tuple[float, float]:
    """A share and its binomial standard error."""
    p = k / n if n else float("nan")
    return p, math.sqrt(p * (1 - p) / n) if n else float("nan")


def measure(gear: str, draws: int, uniform: int, seed: int, out: Path, part: int) -> dict[str, Any]:
    """The flow of the shipped `gear` skill against its policy's successes (module docstring)."""
    skill = load_skill("insert", gear=gear)
    feasible = skill.feasible
    if feasible is None:
        raise InputError(
            f"--gear {gear}: the shipped skill holds no measured feasible set; expected one "
            f"(goflow skill refit --gear {gear})"
        )
    variants = feasible.variant.split("+")
    space = feasible.space
    volume = float(np.prod(space.high - space.low))
    out.mkdir(parents=True, exist_ok=True)
    store = out / f"{gear}-seed{seed}.json"
    rng = np.random.default_rng([seed, 1])
    xi_draws = skill.sampler.sample(draws, rng)
    xi_fine = feasible.fine_low + (feasible.fine_high - feasible.fine_low) * rng.random((uniform, space.dim))
    ok_draws = successes(skill, xi_draws, variants, store, f"draws{draws}", part)
    ok_fine = successes(skill, xi_fine, variants, store, f"uniform{uniform}", part)
    fine_share = float(np.prod((feasible.fine_high - feasible.fine_low) / (space.high - space.low)))
    rate, rate_se = binomial(int(ok_fine.sum()), uniform)
    share = fine_share * rate
    inside = xi_fine[ok_fine]
    row: dict[str, Any] = {
        "gear": gear,
        "variants": feasible.variant,
        "draws": draws,
        "uniform": uniform,
        "seed": seed,
        "grid": flow_report(skill.sampler, feasible),
    }
    mass, mass_se = binomial(int(ok_draws.sum()), draws)
    row["episodes"] = {
        "mass_on": mass,
        "mass_on_se": mass_se,
        "share": share,
        "share_se": fine_share * rate_se,
        "successes_uniform": int(ok_fine.sum()),
    }
    for name, level in (("coverage10", 0.1), ("coverage1", 0.01)):
        value = coverage(skill.sampler.log_prob, inside, share, level, volume) if len(inside) else 0.0
        row["episodes"][name], row["episodes"][f"{name}_se"] = (
            value,
            binomial(round(value * len(inside)), len(inside))[1],
        )
    # the grid against the episodes at the same points: how far its staircase is from the policy
    in_grid = feasible.contains(xi_fine)
    row["grid_vs_episodes"] = {
        "episodes_in_grid_set": float(in_grid[ok_fine].mean()) if ok_fine.any() else None,
        "grid_set_succeeds": float(ok_fine[in_grid].mean()) if in_grid.any() else None,
        "draws_in_grid_set": float(feasible.contains(xi_draws).mean()),
        "coarse_successes": int(feasible.coarse_success.sum()),
    }
    return row


def make_parser() -> argparse.ArgumentParser:
    """The benchmark's flags."""
    p = InputErrorParser(prog="benchmarks/skill_feasible_mc.py", description=__doc__.splitlines()[0])
    p.add_argument("--gear", required=True, help=f"one of {list(GEARS)}")
    p.add_argument("--draws", type=int, default=600, help="draws of the flow, one episode each")
    p.add_argument("--uniform", type=int, default=4000, help="points uniform on the grid's fine region")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--part", type=int, default=50, help="episodes between saves")
    p.add_argument("--out", type=Path, default=Path("runs/skill_mc"), help="folder of the saved parts")
    p.add_argument("--json", type=Path, default=None, help="write the row here")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; 0 on success, 2 with one line on stderr for bad input."""
    try:
        args = make_parser().parse_args(argv)
        if args.gear not in GEARS:
            raise InputError(f"--gear {args.gear!r}; expected one of {list(GEARS)}")
        check_int(args.draws, "--draws", 1)
        check_int(args.uniform, "--uniform", 1)
        check_int(args.seed, "--seed", 0)
        check_int(args.part, "--part", 1)
        if args.json is not None:
            check_output_file(args.json, "--json")
        torch.set_num_threads(1)
        row = measure(args.gear, args.draws, args.uniform, args.seed, args.out, args.part)
        row["command"] = "benchmarks/skill_feasible_mc.py " + " ".join(argv if argv is not None else sys.argv[1:])
        g, e = row["grid"], row["episodes"]
        print(
            f"| gear | F share (grid / episodes) | mass on F (grid / episodes) | coverage 10 % (grid / episodes) "
            f"| coverage 1 % (grid / episodes) |\n|---|---|---|---|---|\n"
            f"| {args.gear} | {g['share']:.4%} / {e['share']:.4%} +- {e['share_se']:.4%} | {g['mass_on']:.3f} / "
            f"{e['mass_on']:.3f} +- {e['mass_on_se']:.3f} | {g['coverage10']:.3f} / {e['coverage10']:.3f} +- "
            f"{e['coverage10_se']:.3f} | {g['coverage1']:.3f} / {e['coverage1']:.3f} +- {e['coverage1_se']:.3f} |"
        )
        print(f"{NAME}: grid against episodes: {row['grid_vs_episodes']}")
        if args.json is not None:
            write_json(args.json, row)
            print(f"{NAME}: -> {args.json}")
        return 0
    except GoflowError as exc:
        print(f"{NAME}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
