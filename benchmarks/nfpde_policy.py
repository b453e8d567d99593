"""The NFPDE paper's Fig. 3: train policies with domain randomization drawn from NFPDE-Softmax's and
DROPO's estimates (and, as references, from the true distribution and the uniform box), and compare
their returns on episodes whose parameters come from the TRUE distribution. Learners: our PPO
(`--algos ppo`) and stable-baselines3's SAC, as the paper used (`--algos sac`, the extra `sb3`).

The estimates are fitted here on one dataset (seed 0; Cartpole: 48 random-policy trajectories,
the locomotion envs: 10 of 100 steps as in Tables II-III) with the table's simulator budget, and
kept in --estimates (a rerun loads them). Targets:
  mixture, mixture5, gaussian   the tables' targets (docs/nfpde.md);
  feasible-mixture              Cartpole only: the L of three Gaussians in the corner of the box where
                                the pole can be balanced (FEASIBLE_MIXTURE). The table's Cartpole
                                targets put slider friction near the actuator's 100 N.
Every finished run is appended to docs/results/nfpde_policy-[<env>-]<target>.json (a rerun skips it,
so an interrupted sweep resumes); the plot is docs/results/nfpde-policy-[<env>-]<target>.png. Cartpole
keeps the names without <env>.

Usage: .venv/bin/python -m benchmarks.nfpde_policy --target feasible-mixture --seeds 3 --iterations 60
       .venv/bin/python -m benchmarks.nfpde_policy --env goflow/Hopper-v0 --target mixture5 --algos sac ppo --seeds 3
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from assembly.samplers import FullDR
from goflow_common.errors import InputError
from goflow_common.files import check_output_dir, write_json
from learning.estimation.collect import CollectConfig, collect
from learning.estimation.estimate import EstimateConfig, estimate
from learning.estimation.estimate_file import load_estimate, save_estimate
from learning.estimation.metrics import ot_cost
from learning.estimation.targets import TARGETS, TargetConfig, TargetSampler
from learning.estimation.transfer import ALGOS, SACConfig, TransferConfig, train_and_evaluate
from learning.ppo import PPOConfig

ROOT = Path(__file__).resolve().parents[1]

CARTPOLE = "goflow/Cartpole-v0"
#: The L of the table's mixture moved to the balanceable corner of Cartpole's box (unit-box coordinates:
#: pole and cart mass 0.05 -> 1.0 kg, 0.2 -> 4.0 kg; slider friction 0.05 +- 0.02).
FEASIBLE_MIXTURE = TargetConfig(
    kind="mixture", mean=0.05, std=0.02, l_std=0.03, l_means=((0.05, 0.2), (0.05, 0.05), (0.2, 0.05))
)
TARGET_CONFIGS = {**{kind: TargetConfig(kind=kind) for kind in TARGETS}, "feasible-mixture": FEASIBLE_MIXTURE}
TRAIN_ON = ("true", "fulldr", "nfpde-softmax", "dropo")


def ppo_config(env: str) -> PPOConfig:
    """Cartpole: docs/results/cartpole.json's settings. Locomotion: CleanRL's MuJoCo settings on 8
    envs (lr 3e-4, 2048 steps per rollout) with episodes running on across rollouts, since their
    1000-step horizon is longer than a rollout."""
    if env == CARTPOLE:
        return PPOConfig(num_steps=240, learning_rate=1e-3)
    return PPOConfig(num_steps=256, learning_rate=3e-4, reset_each_rollout=False)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--env", default=CARTPOLE)
    p.add_argument("--target", default="mixture", choices=list(TARGET_CONFIGS))
    p.add_argument("--algos", nargs="+", default=["ppo"], choices=list(ALGOS))
    p.add_argument("--seeds", type=int, default=2)
    p.add_argument("--first-seed", type=int, default=0, help="seeds first-seed .. first-seed + seeds - 1")
    p.add_argument(
        "--iterations", type=int, default=20, help="PPO iterations (Cartpole 1920, locomotion 2048 env steps each)"
    )
    p.add_argument("--eval-every", type=int, default=5, help="PPO iterations between evaluations")
    p.add_argument("--sac-steps", type=int, default=SACConfig.steps, help="SAC env steps")
    p.add_argument("--sac-eval-every", type=int, default=SACConfig.eval_every, help="SAC env steps between evaluations")
    p.add_argument("--eval-episodes", type=int, default=None, help="episodes per evaluation (Cartpole 32, else 10)")
    p.add_argument("--episodes", type=int, default=None, help="dataset trajectories (Cartpole 48, else 10)")
    p.add_argument("--budget", type=int, default=100_000, help="simulator calls per estimate")
    p.add_argument(
        "--train-on", nargs="+", default=list(TRAIN_ON), choices=list(TRAIN_ON), help="samplers to train with"
    )
    p.add_argument("--out", default=str(ROOT / "docs" / "results"))
    p.add_argument("--estimates", default=str(ROOT / "runs" / "nfpde_policy"), help="estimate files")
    args = p.parse_args()
    cartpole = args.env == CARTPOLE
    if args.target == "feasible-mixture" and not cartpole:
        p.error(f"--target feasible-mixture is Cartpole's; for {args.env} use one of {list(TARGETS)}")
    try:
        sac = SACConfig(steps=args.sac_steps, eval_every=args.sac_eval_every)
        base = TransferConfig(
            env=args.env,
            iterations=args.iterations,
            eval_every=args.eval_every,
            eval_episodes=args.eval_episodes or (32 if cartpole else 10),
            ppo=ppo_config(args.env),
            sac=sac,
        )
    except ValueError as exc:
        p.error(str(exc))
    try:
        out, est_dir = check_output_dir(args.out, "--out"), check_output_dir(args.estimates, "--estimates")
    except InputError as exc:
        p.error(str(exc))
    stem = "" if cartpole else args.env.split("/")[-1].split("-v")[0].lower() + "-"
    res_path = out / f"nfpde_policy-{stem}{args.target}.json"
    doc = json.loads(res_path.read_text()) if res_path.exists() else {"runs": [], "estimates": {}}
    command = "python -m benchmarks.nfpde_policy " + " ".join(sys.argv[1:])

    target = TARGET_CONFIGS[args.target]
    episodes = args.episodes or (48 if cartpole else 10)
    try:
        ds, truth = collect(CollectConfig(env=args.env, xi=target.kind, target=target, episodes=episodes, seed=0))
    except InputError as exc:
        p.error(str(exc))
    true_sampler = TargetSampler(ds.space, target)
    u_true = ds.space.normalize(truth)
    samplers = {"true": true_sampler, "fulldr": FullDR(ds.space)}
    for method in ("nfpde-softmax", "dropo"):
        if method not in args.train_on:
            continue
        path = est_dir / f"{stem}{args.target}-{method}.json"
        recorded = doc["estimates"].get(method, {}).get("ot")  # the estimate the file's runs were trained on
        fitted = None
        if path.exists():
            sampler, saved = load_estimate(path)
            info = saved.get("info", {})  # what fitting it cost, for a results file that lost it
            for key in ("seconds", "sim_calls"):
                if key in info:
                    doc["estimates"].setdefault(method, {}).setdefault(key, info[key])
        else:
            sampler, fitted, _ = estimate(ds, EstimateConfig(method=method, seed=0, sim_budget=args.budget))
        u = ds.space.normalize(sampler.sample(500, np.random.default_rng(1)))
        ot = ot_cost(u, u_true)
        if recorded is not None and any(r["train_on"] == method for r in doc["runs"]) and abs(ot - recorded) > 1e-6:
            where = "fitted here" if fitted is not None else f"in {path}"
            raise SystemExit(
                f"nfpde_policy: the {method} estimate {where} has OT {ot:.4f}, but the runs in {res_path} were "
                f"trained on one with OT {recorded:.4f}; refusing to mix two estimates in one figure. Put that "
                f"estimate's file back in --estimates, or start a new figure with another --out"
            )
        if fitted is not None:  # kept only once it is the figure's estimate
            save_estimate(path, sampler, method, args.env, fitted)
            doc["estimates"][method] = {"seconds": fitted["seconds"], "sim_calls": fitted["sim_calls"]}
        doc["estimates"].setdefault(method, {})["ot"] = ot
        samplers[method] = sampler
    done = {(r.get("algo", "ppo"), r["train_on"], r["seed"]) for r in doc["runs"]}
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        for algo in args.algos:
            for name in args.train_on:
                if (algo, name, seed) in done:
                    continue
                config = TransferConfig(**{**vars(base), "seed": seed, "algo": algo})
                res = train_and_evaluate(samplers[name], true_sampler, config)
                run = {"algo": algo, "train_on": name, "seed": seed, "target": args.target, **res}
                doc["runs"].append(run)
                doc.setdefault("commands", []).append(command)
                merge_with_file(res_path, doc)
                write_json(res_path, doc)  # atomic: an interrupted run keeps every finished one
                print(
                    f"{algo} on {name:<14} seed {seed}: return on the truth {res['final_mean_return']:.1f}, "
                    f"success {res['final_success']:.2f} ({res['seconds']:.0f} s)",
                    flush=True,
                )

    doc.pop("command", None)
    merge_with_file(res_path, doc)
    doc["summary"] = return_summary(doc["runs"])
    write_json(res_path, doc)
    plot(doc["runs"], out / f"nfpde-policy-{stem}{args.target}.png", f"{args.env}, {args.target} target")
    for key, s in doc["summary"].items():
        print(
            f"{key:<20} final {s['final_return_mean']:8.1f} +- {s['final_return_se']:.1f}, over the curve "
            f"{s['curve_return_mean']:8.1f} +- {s['curve_return_se']:.1f} ({s['seeds']} seeds)"
        )
    return 0


def merge_with_file(path: Path, doc: dict) -> None:
    """Join into `doc` what another process has written to `path` since it was read: one run per
    algo, sampler and seed, each command once in order (an older file's "command" first), and each
    estimate's record, so that processes sharing a results file (one per sampler, say) keep each
    other's runs and estimates. `doc`'s own entries win."""
    old = json.loads(path.read_text()) if path.exists() else {}
    key = lambda r: (r.get("algo", "ppo"), r["train_on"], r["seed"])  # noqa: E731
    runs = {key(r): r for r in old.get("runs", [])}
    runs.update({key(r): r for r in doc.get("runs", [])})
    seen = ([old["command"]] if "command" in old else []) + old.get("commands", []) + doc.get("commands", [])
    estimates = {m: dict(e) for m, e in old.get("estimates", {}).items()}
    for method, record in doc.get("estimates", {}).items():
        estimates.setdefault(method, {}).update(record)
    doc.update(runs=list(runs.values()), commands=list(dict.fromkeys(seen)), estimates=estimates)


def _groups(runs: list[dict]) -> dict[tuple[str, str], list[dict]]:
    groups: dict[tuple[str, str], list[dict]] = {}
    for r in runs:
        groups.setdefault((r.get("algo", "ppo"), r["train_on"]), []).append(r)
    return groups


def return_summary(runs: list[dict]) -> dict[str, dict]:
    """Per "<algo>/<train_on>", mean and standard error over seeds of the final return on the truth
    and of the mean return over the curve's evaluations (how soon a policy is good)."""

    def mean_se(values: list[float]) -> tuple[float, float]:
        se = float(np.std(values, ddof=1) / np.sqrt(len(values))) if len(values) > 1 else 0.0
        return float(np.mean(values)), se

    summary = {}
    for (algo, name), group in _groups(runs).items():
        final, final_se = mean_se([r["final_mean_return"] for r in group])
        area, area_se = mean_se([float(np.mean([pt[1] for pt in r["curve"]])) for r in group])
        summary[f"{algo}/{name}"] = {
            "final_return_mean": final,
            "final_return_se": final_se,
            "curve_return_mean": area,
            "curve_return_se": area_se,
            "seeds": len(group),
        }
    return summary


def plot(runs: list[dict], path: Path, title: str) -> None:
    """Learning curves on the truth, mean +- standard error over seeds, one panel per learner."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = _groups(runs)
    algos = [a for a in ALGOS if any(k[0] == a for k in groups)]
    fig, axes = plt.subplots(1, len(algos), figsize=(6 * len(algos), 4), squeeze=False)
    for ax, algo in zip(axes[0], algos):
        for k, name in enumerate(TRAIN_ON):
            group = groups.get((algo, name))
            if not group:
                continue
            n = min(len(r["curve"]) for r in group)
            c = np.array([[pt[1] for pt in r["curve"][:n]] for r in group])
            steps = [pt[0] for pt in group[0]["curve"][:n]]
            se = c.std(0, ddof=1) / np.sqrt(len(group)) if len(group) > 1 else np.zeros(n)
            ax.plot(steps, c.mean(0), color=f"C{k}", label=f"DR on {name} ({len(group)} seeds)")
            ax.fill_between(steps, c.mean(0) - se, c.mean(0) + se, color=f"C{k}", alpha=0.2)
        ax.set_xlabel("training env steps")
        ax.set_ylabel("mean return on the true distribution")
        ax.set_title(f"{title}: {algo.upper()}")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
