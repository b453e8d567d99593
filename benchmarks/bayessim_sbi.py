"""BayesSim's mixture density network, ours or sbi's (issue 15): both fitted on the same simulations.

For every (env, target, seed): the table's dataset (benchmarks/nfpde_table.py: 48 random-policy
trajectories, true xi from the target, dataset seed = seed), then BayesSim's simulation step
(learning/estimation/bayessim.py `simulate_bayessim`: prior draws, segments and summary statistics,
the same code and seed as `bayessim` in the table) run ONCE, and on exactly those (xi, statistics)
pairs:

- ours: `fit_mdn`, BayesSim's own MDN (2 x 64 tanh, 5 diagonal components, 200 epochs, batch 128,
  lr 1e-3): its OT equals the table's `bayessim` run of the same cell and seed bit for bit;
- sbi-mdn: sbi's neural posterior estimation with its mixture-density estimator,
  `NPE(prior=BoxUniform(0, 1), density_estimator=posterior_nn("mdn",
  z_score_theta="transform_to_unconstrained", x_dist=prior, hidden_features=64, num_components=5))`
  (2 x 64 ReLU, a mixture over logit(u), statistics z-scored by sbi), with sbi's training defaults
  (batch 200, lr 5e-4, 10 % held out, stop after 20 epochs without improvement, best validation
  weights, gradient norm clipped at 5). sbi's MDN has full covariances; the estimate file has only
  the diagonal `GaussianMixtureAggregate`, so its upper-triangular precision layer is zeroed and
  frozen when the network is built: its posteriors are then exactly such a mixture;
- sbi-mdn-our-training (`--sbi-training ours`): sbi-mdn trained with our batch size, learning
  rate and number of epochs (`max_num_epochs` = `stop_after_epochs` = 200: no early stop).

Each posterior is averaged over the logged segments as BayesSim does and scored like the table
(`score`: OT of 500 draws to the 48 true parameters, unit box). The seed fixes each network's
initialization and batches (sbi: the torch RNG seeded with it around the fit). Times: the
simulation step once per cell (wall and process CPU), then each network's fit (training and the
posteriors of the logged segments); torch runs on one thread, as `goflow estimate` does.

sbi is benchmark-only: `.venv/bin/pip install -e ".[sbi]"` (sbi 0.27.0). `--recorded RUNS.json`
puts the OT of earlier runs (e.g. docs/results/bayessim_sbi_runs.json) beside each new one.
Writes runs/results/bayessim_sbi.json unless `--json` names another file.

Usage: .venv/bin/python -m benchmarks.bayessim_sbi --envs goflow/PointMass-v0 --targets mixture gaussian \\
           --seeds 3 --budget 80000 --sbi-training sbi ours --recorded docs/results/bayessim_sbi_runs.json
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import sys
import time
import warnings
from typing import Any

import numpy as np

from benchmarks.nfpde_table import dataset, oracle_ot, score
from goflow_common.files import read_json, write_json
from learning.estimation.bayessim import BayesSimConfig, BayesSimSimulations, fit_mdn, simulate_bayessim
from learning.estimation.distributions import GaussianMixtureAggregate
from learning.samplers.estimated import EstimatedSampler

SBI_VERSION = "0.27.0"
LABELS = {"sbi": "sbi-mdn", "ours": "sbi-mdn-our-training"}  # --sbi-training value -> label


def import_sbi() -> Any:
    """sbi's module (SystemExit with the install command when it is missing)."""
    try:
        import sbi
        import sbi.inference  # noqa: F401
        import sbi.neural_nets  # noqa: F401
        import sbi.utils  # noqa: F401
    except ImportError:
        raise SystemExit(
            'bayessim_sbi: sbi is not installed; install it with .venv/bin/pip install -e ".[sbi]"'
        ) from None
    if sbi.__version__ != SBI_VERSION:
        print(f"bayessim_sbi: note: sbi {sbi.__version__} is installed; the recorded results used {SBI_VERSION}")
    return sbi


class _NoTracker:
    """sbi's tracker protocol, logging nothing (its default writes TensorBoard files into ./sbi-logs)."""

    log_dir = None

    def log_metric(self, name: str, value: float, step: int | None = None) -> None:
        pass

    def log_metrics(self, metrics: dict, step: int | None = None) -> None:
        pass

    def log_params(self, params: dict) -> None:
        pass

    def add_figure(self, name: str, figure: Any, step: int | None = None) -> None:
        pass

    def flush(self) -> None:
        pass


def fit_sbi(
    sbi: Any, sims: BayesSimSimulations, config: BayesSimConfig, seed: int, training: str
) -> tuple[GaussianMixtureAggregate, dict]:
    """sbi's NPE with its MDN (diagonal precisions) on the simulations; its posteriors of the logged
    segments averaged. `training`: "sbi" (sbi's defaults) or "ours" (config's batch, lr, epochs)."""
    import torch

    d = sims.u.shape[1]
    t_wall, t_cpu = time.perf_counter(), time.process_time()
    prior = sbi.utils.BoxUniform(torch.zeros(d), torch.ones(d))
    build_full = sbi.neural_nets.posterior_nn(
        "mdn",
        z_score_theta="transform_to_unconstrained",
        x_dist=prior,
        hidden_features=64,
        num_components=config.components,
    )

    def build_diagonal(batch_theta: torch.Tensor, batch_x: torch.Tensor) -> Any:
        estimator = build_full(batch_theta, batch_x)
        upper = estimator.net._upper_layer  # precision factors above the diagonal (None when d = 1)
        if upper is not None:
            with torch.no_grad():
                upper.weight.zero_()
                upper.bias.zero_()
            upper.requires_grad_(False)
        return estimator

    train_kwargs = (
        {}
        if training == "sbi"
        else {
            "training_batch_size": config.batch_size,
            "learning_rate": config.lr,
            "max_num_epochs": config.epochs,
            "stop_after_epochs": config.epochs,
        }
    )
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        # sbi's warnings (e.g. on outliers of the statistics) go into the details, not on the screen
        with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            inference = sbi.inference.NPE(
                prior=prior, density_estimator=build_diagonal, show_progress_bars=False, tracker=_NoTracker()
            )
            inference.append_simulations(
                torch.as_tensor(sims.u, dtype=torch.float32), torch.as_tensor(sims.stats, dtype=torch.float32)
            )
            estimator = inference.train(**train_kwargs)
    estimator.eval()
    with torch.no_grad():
        mog = estimator.get_uncorrected_mog(torch.as_tensor(sims.observed, dtype=torch.float32))
        prec = mog.precisions
        off_diagonal = prec - torch.diag_embed(torch.diagonal(prec, dim1=-2, dim2=-1))
        if torch.any(off_diagonal != 0):
            raise RuntimeError("bayessim_sbi: sbi's MDN has non-diagonal precisions; the frozen layer moved")
        weights = torch.softmax(mog.logits, dim=-1)
        stds = torch.diagonal(prec, dim1=-2, dim2=-1).double().rsqrt()
    dist = GaussianMixtureAggregate(weights.double().numpy(), mog.means.double().numpy(), stds.numpy())
    train_wall, train_cpu = time.perf_counter() - t_wall, time.process_time() - t_cpu
    summary = inference.summary
    return dist, {
        "epochs": int(summary["epochs_trained"][-1]),
        "best_validation_loss": float(summary["best_validation_loss"][-1]),
        "train_seconds": train_wall,
        "train_cpu_seconds": train_cpu,
        "sbi_warnings": sorted({str(w.message) for w in caught if "max_num_epochs" not in str(w.message)}),
    }  # ours: no early stop


def simulate(ds: Any, budget_calls: int, config: BayesSimConfig, seed: int) -> tuple[BayesSimSimulations, dict]:
    """BayesSim's simulation step on the dataset's own simulator (in-process, as `goflow estimate`
    with one worker), with its wall and CPU time."""
    from assembly.transition import ParallelTransitionSim
    from learning.estimation.budget import Budget

    sim = ParallelTransitionSim(ds.env_id, workers=1)
    budget = Budget(ds, sim, budget_calls)
    t_wall, t_cpu = time.perf_counter(), time.process_time()
    try:
        sims = simulate_bayessim(budget, config, seed)
    finally:
        budget.close()
        if hasattr(sim, "close"):
            sim.close()
    return sims, {
        "sim_calls": budget.calls,
        "simulations": sims.simulations,
        "valid_simulations": len(sims.u),
        "observed_segments": len(sims.observed),
        "sim_seconds": time.perf_counter() - t_wall,
        "sim_cpu_seconds": time.process_time() - t_cpu,
    }


def recorded_ots(path: str | None) -> dict:
    """(env, target, method, seed) -> OT of an earlier runs file (nfpde_table's format)."""
    if not path:
        return {}
    return {(r["env"], r["target"], r["method"], r["seed"]): r["ot"] for r in read_json(path, "runs file")["runs"]}


def ot_rows(runs: list[dict], oracle: dict) -> list[dict]:
    """One row per (env, target, method): OT mean, standard error and per seed; mean times."""
    rows = []
    for env in dict.fromkeys(r["env"] for r in runs):
        for target in dict.fromkeys(r["target"] for r in runs if r["env"] == env):
            for method in dict.fromkeys(r["method"] for r in runs):
                sel = [r for r in runs if (r["env"], r["target"], r["method"]) == (env, target, method)]
                if not sel:
                    continue
                ot = np.array([r["ot"] for r in sel])
                row = {
                    "env": env,
                    "target": target,
                    "method": method,
                    "seeds": len(sel),
                    "ot_mean": float(ot.mean()),
                    "ot_se": float(ot.std(ddof=1) / np.sqrt(len(ot))) if len(ot) > 1 else 0.0,
                    "ot_per_seed": [round(float(x), 4) for x in ot],
                }
                for key in ("train_seconds", "train_cpu_seconds", "sim_seconds", "sim_cpu_seconds", "epochs"):
                    row[f"{key}_mean"] = float(np.mean([r[key] for r in sel]))
                row["oracle_ot_mean"] = float(np.mean([oracle[f"{env}|{target}|{r['seed']}"] for r in sel]))
                rec = [r.get("recorded_ot") for r in sel]
                if all(x is not None for x in rec):
                    row["recorded_ot_mean"] = float(np.mean(rec))
                    row["recorded_ot_per_seed"] = [round(float(x), 4) for x in rec]
                    row["max_abs_diff_to_recorded"] = float(np.max(np.abs(ot - np.array(rec))))
                rows.append(row)
    return rows


def print_rows(rows: list[dict]) -> None:
    """The summary as a text table."""
    print(
        f"\n{'env':<20} {'target':<9} {'MDN':<21} {'OT mean +- se':<16} {'OT per seed':<22} "
        f"{'recorded per seed':<22} {'train wall':>10} {'train CPU':>9} {'epochs':>6}"
    )
    for r in rows:
        rec = ", ".join(f"{x:.4f}" for x in r.get("recorded_ot_per_seed", [])) or "-"
        print(
            f"{r['env'].split('/')[-1]:<20} {r['target']:<9} {r['method']:<21} "
            f"{r['ot_mean']:.4f} +- {r['ot_se']:.4f} {', '.join(f'{x:.4f}' for x in r['ot_per_seed']):<22} "
            f"{rec:<22} {r['train_seconds_mean']:9.1f}s {r['train_cpu_seconds_mean']:8.1f}s "
            f"{r['epochs_mean']:6.0f}"
        )


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--envs", nargs="+", default=["goflow/PointMass-v0"])
    p.add_argument("--targets", nargs="+", default=["gaussian", "mixture"], choices=["gaussian", "mixture"])
    p.add_argument("--seeds", type=int, default=3, help="seeds 0 .. SEEDS-1 (dataset and estimator seed)")
    p.add_argument("--budget", type=int, default=80_000, help="simulator calls per run (the table's 80000)")
    p.add_argument("--episodes", type=int, default=48)
    p.add_argument(
        "--sbi-training",
        nargs="*",
        default=["sbi"],
        choices=list(LABELS),
        help="sbi's MDN trained with sbi's defaults (sbi -> sbi-mdn) and/or with ours "
        "(ours -> sbi-mdn-our-training); none: only our MDN",
    )
    p.add_argument("--no-ours", action="store_true", help="skip our MDN")
    p.add_argument(
        "--recorded",
        default=None,
        metavar="RUNS.json",
        help="earlier runs to put beside the new ones (docs/results/bayessim_sbi_runs.json)",
    )
    p.add_argument("--json", default="runs/results/bayessim_sbi.json", help="output file")
    args = p.parse_args()
    sbi = import_sbi() if args.sbi_training else None

    import torch

    torch.set_num_threads(1)  # as `goflow estimate` trains (small networks)
    torch.optim.Adam([torch.zeros(1, requires_grad=True)])  # pay torch._dynamo's import here, not in a fit

    config = BayesSimConfig()  # the table's BayesSim
    recorded = recorded_ots(args.recorded)
    doc: dict = {
        "command": "python -m benchmarks.bayessim_sbi " + " ".join(sys.argv[1:]),
        "versions": {"sbi": getattr(sbi, "__version__", None), "torch": torch.__version__},
        "bayessim_config": dataclasses.asdict(config),
        "runs": [],
        "oracle": {},
    }
    fits = [("ours", lambda sims, seed: fit_mdn(sims, config, seed))] if not args.no_ours else []
    fits += [(LABELS[t], lambda sims, seed, t=t: fit_sbi(sbi, sims, config, seed, t)) for t in args.sbi_training]
    if not fits:
        raise SystemExit("bayessim_sbi: nothing to fit (--no-ours and no --sbi-training)")
    cache: dict = {}
    t_start = time.perf_counter()
    for env in args.envs:
        for target in args.targets:
            for seed in range(args.seeds):
                ds, u_true = dataset(env, target, seed, args.episodes, cache)
                doc["oracle"][f"{env}|{target}|{seed}"] = oracle_ot(env, target, seed, cache)
                sims, sim_info = simulate(ds, args.budget, config, seed)
                for label, fit in fits:
                    dist, details = fit(sims, seed)
                    _, ot = score(EstimatedSampler.of(ds.space, dist), u_true, seed)
                    run = {
                        "env": env,
                        "target": target,
                        "method": label,
                        "seed": seed,
                        "sim_budget": args.budget,
                        "ot": ot,
                        **sim_info,
                        **details,
                    }
                    run.setdefault("epochs", config.epochs)
                    rec = recorded.get((env, target, label, seed))
                    if rec is not None:
                        run["recorded_ot"] = rec
                    doc["runs"].append(run)
                    write_json(args.json, {**doc, "rows": ot_rows(doc["runs"], doc["oracle"])})
                    print(
                        f"{env} {target} seed {seed} {label}: OT {ot:.4f}"
                        + (f" (recorded {rec:.4f}, diff {ot - rec:+.4f})" if rec is not None else "")
                        + f", train {details['train_seconds']:.1f} s wall / {details['train_cpu_seconds']:.1f} s CPU, "
                        f"epochs {run['epochs']}; simulation {sim_info['sim_seconds']:.1f} s",
                        flush=True,
                    )
    doc["wall_seconds"] = time.perf_counter() - t_start
    doc["rows"] = ot_rows(doc["runs"], doc["oracle"])
    write_json(args.json, doc)
    print_rows(doc["rows"])
    print(f"\n{args.json} ({doc['wall_seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
