"""The seed's Fig. 3 in small: train Cartpole policies with domain randomization drawn from NFPDE's
and DROPO's estimates (and, as references, from the true distribution and the uniform box), and
compare their returns on episodes whose parameters come from the TRUE distribution.

The estimates are fitted here on a Cartpole dataset (48 random-policy trajectories, seed 0) with
the table's simulator budget. Targets:
  mixture, gaussian   the table's targets (docs/nfpde.md). Most of their mass has slider friction
                      near the actuator's 100 N, so no policy balances the pole there;
  feasible-mixture    the same L of three Gaussians, in the corner of the box where the pole can be
                      balanced: pole and cart 1-4 kg, friction ~0.05 (FEASIBLE_MIXTURE).
Every finished run is appended to docs/results/nfpde_policy-<target>.json (a rerun skips it); the
plot is docs/results/nfpde-policy-<target>.png.

Usage: .venv/bin/python benchmarks/nfpde_policy.py --target feasible-mixture --seeds 3 --iterations 60
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from assembly.samplers import FullDR  # noqa: E402
from learning.estimation.collect import CollectConfig, collect  # noqa: E402
from learning.estimation.estimate import EstimateConfig, estimate  # noqa: E402
from learning.estimation.metrics import ot_cost  # noqa: E402
from learning.estimation.estimate_file import load_estimate, save_estimate  # noqa: E402
from learning.estimation.targets import TargetConfig, TargetSampler  # noqa: E402
from learning.estimation.transfer import TransferConfig, train_and_evaluate  # noqa: E402
from common.files import write_json  # noqa: E402

ENV = "goflow/Cartpole-v0"
#: The L of the table's mixture moved to the balanceable corner of Cartpole's box (unit-box coordinates:
#: pole and cart mass 0.05 -> 1.0 kg, 0.2 -> 4.0 kg; slider friction 0.05 +- 0.02).
FEASIBLE_MIXTURE = TargetConfig(kind="mixture", mean=0.05, std=0.02, l_std=0.03,
                                l_means=((0.05, 0.2), (0.05, 0.05), (0.2, 0.05)))
TARGETS = {"gaussian": TargetConfig(kind="gaussian"), "mixture": TargetConfig(kind="mixture"),
           "feasible-mixture": FEASIBLE_MIXTURE}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--target", default="mixture", choices=list(TARGETS))
    p.add_argument("--seeds", type=int, default=2)
    p.add_argument("--iterations", type=int, default=20, help="PPO iterations (1920 env steps each)")
    p.add_argument("--eval-every", type=int, default=5, help="PPO iterations between evaluations")
    p.add_argument("--budget", type=int, default=100_000, help="simulator calls per estimate")
    p.add_argument("--train-on", nargs="+", default=["true", "fulldr", "nfpde-softmax", "dropo"],
                   choices=["true", "fulldr", "nfpde-softmax", "dropo"], help="samplers to train with")
    p.add_argument("--out", default=str(ROOT / "docs" / "results"))
    p.add_argument("--estimates", default=str(ROOT / "runs" / "nfpde_policy"), help="estimate files")
    args = p.parse_args()
    out, est_dir = Path(args.out), Path(args.estimates)
    out.mkdir(parents=True, exist_ok=True)
    est_dir.mkdir(parents=True, exist_ok=True)
    res_path = out / f"nfpde_policy-{args.target}.json"
    doc = json.loads(res_path.read_text()) if res_path.exists() else {"runs": [], "estimates": {}}
    doc["command"] = "python benchmarks/nfpde_policy.py " + " ".join(sys.argv[1:])

    target = TARGETS[args.target]
    ds, truth = collect(CollectConfig(env=ENV, xi=target.kind, target=target, episodes=48, seed=0))
    true_sampler = TargetSampler(ds.space, target)
    u_true = ds.space.normalize(truth)
    samplers = {"true": true_sampler, "fulldr": FullDR(ds.space)}
    for method in ("nfpde-softmax", "dropo"):
        path = est_dir / f"{args.target}-{method}.json"
        if path.exists():
            sampler, _ = load_estimate(path)
        else:
            sampler, info, _ = estimate(ds, EstimateConfig(method=method, seed=0, sim_budget=args.budget))
            save_estimate(path, sampler, method, ENV, info)
            doc["estimates"][method] = {"seconds": info["seconds"], "sim_calls": info["sim_calls"]}
        u = ds.space.normalize(sampler.sample(500, np.random.default_rng(1)))
        doc["estimates"].setdefault(method, {})["ot"] = ot_cost(u, u_true)
        samplers[method] = sampler
    done = {(r["train_on"], r["seed"]) for r in doc["runs"]}
    for seed in range(args.seeds):
        for name, sampler in samplers.items():
            if (name, seed) in done or name not in args.train_on:
                continue
            res = train_and_evaluate(sampler, true_sampler, TransferConfig(
                env=ENV, seed=seed, iterations=args.iterations, eval_every=args.eval_every))
            doc["runs"].append({"train_on": name, "seed": seed, "target": args.target, **res})
            write_json(res_path, doc)  # atomic: an interrupted run keeps every finished one
            print(f"train on {name:<14} seed {seed}: return on the truth {res['final_mean_return']:.1f}, "
                  f"success {res['final_success']:.2f} ({res['seconds']:.0f} s)", flush=True)

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 4))
    for k, name in enumerate(samplers):
        runs = [r for r in doc["runs"] if r["train_on"] == name]
        if not runs:
            continue
        n = min(len(r["curve"]) for r in runs)
        c = np.array([[pt[1] for pt in r["curve"][:n]] for r in runs])
        steps = [pt[0] for pt in runs[0]["curve"][:n]]
        se = c.std(0, ddof=1) / np.sqrt(len(runs)) if len(runs) > 1 else np.zeros(n)
        ax.plot(steps, c.mean(0), color=f"C{k}", label=f"DR on {name}")
        ax.fill_between(steps, c.mean(0) - se, c.mean(0) + se, color=f"C{k}", alpha=0.2)
    ax.set_xlabel("training env steps")
    ax.set_ylabel("mean return on the true distribution")
    ax.set_title(f"{ENV}, {args.target} target")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / f"nfpde-policy-{args.target}.png", dpi=110)
    summary = {}
    for name in samplers:
        finals = [r["final_mean_return"] for r in doc["runs"] if r["train_on"] == name]
        if finals:
            summary[name] = {"final_return_mean": float(np.mean(finals)),
                             "final_return_se": float(np.std(finals, ddof=1) / np.sqrt(len(finals))) if len(finals) > 1 else 0.0,
                             "seeds": len(finals)}
    doc["summary"] = summary
    write_json(res_path, doc)
    for name, s in summary.items():
        print(f"{name:<14} {s['final_return_mean']:8.1f} +- {s['final_return_se']:.1f} ({s['seeds']} seeds)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
