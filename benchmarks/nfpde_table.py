"""Our version of the NFPDE seed's Tables II and III (OT cost and wall time per method, Gaussian and
mixed-Gaussian targets) and its Fig. 2 (samples), plus OT against wall time and simulator calls.

For every (env, target, seed): collect a dataset (48 random-policy trajectories, true xi from the
target, dataset seed = seed), run every method with the same simulator budget and estimator seed,
and score snapshots of each estimate by the OT cost (POT ot.emd2, Euclidean ground cost, unit-box
coordinates) between 500 samples and the 48 true per-trajectory parameters. Every finished run is
appended to docs/results/nfpde_runs.json at once (a rerun skips what is there); the summary
docs/results/nfpde.json and the plots are rewritten from all runs at the end.

seconds_mean: the wall time to converge, the first snapshot from which the OT stays within 10 %
(+ 0.01) of the run's final OT (BayesSim trains once at the end: its total time). Timing excludes
scoring (snapshots are drawn outside the timed region).

Variants of one method side by side: `--variant LABEL=METHOD[:KEY=VALUE,...]` runs METHOD with
those options (fields of its config dataclass) under the name LABEL, after `--methods` in each cell;
`--name NAME` writes NAME_runs.json, NAME.json and NAME-<env>-*.png instead of nfpde* (`--no-plots`
skips the plots). `cpu_seconds` per run: the process CPU time of the estimation (simulator included:
one worker runs in-process), less sensitive than wall time to other jobs on a shared machine.

The runs are independent jobs (learning.execution): `--workers N` runs N at once in local processes,
`--ray local|auto|HOST:PORT` as Ray tasks (docs/cluster.md); each finished run is saved as it comes,
and the numbers are the same wherever a run went (its dataset and estimator are seeded by the cell).

Usage: .venv/bin/python -m benchmarks.nfpde_table --envs goflow/Cartpole-v0 --seeds 3
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from contextlib import ExitStack
from pathlib import Path

import numpy as np

from goflow_common.errors import GoflowError, GridError
from goflow_common.files import read_json, write_json
from learning.execution import InlineBackend, Job, add_ray_flag, make_backend, run_grid
from learning.estimation import ESTIMATORS
from learning.estimation.collect import CollectConfig, collect
from learning.estimation.estimate import EstimateConfig, estimate
from learning.estimation.metrics import ot_cost
from learning.estimation.targets import TARGETS, TargetConfig, sample_target

ROOT = Path(__file__).resolve().parents[1]

RESULTS = ROOT / "docs" / "results"


def _key(run: dict) -> tuple:
    return run["env"], run["target"], run["method"], run["seed"]


def converge_seconds(trace: list[dict]) -> float:
    """The first snapshot time from which the OT stays within 10 % (+ 0.01) of the final OT."""
    final = trace[-1]["ot"]
    k = len(trace) - 1
    while k > 0 and trace[k - 1]["ot"] <= 1.1 * final + 0.01:
        k -= 1
    return trace[k]["seconds"]


def parse_variant(text: str) -> tuple[str, str, dict]:
    """ "LABEL=METHOD[:KEY=VALUE,...]" -> (label, method, options); values parsed as JSON when they are."""
    label, eq, rest = text.partition("=")
    method, _, opts = rest.partition(":")
    if not eq or not label or method not in ESTIMATORS:
        raise SystemExit(
            f"nfpde_table: --variant {text!r}: expected LABEL=METHOD[:KEY=VALUE,...] with METHOD one "
            f"of {list(ESTIMATORS)}"
        )
    options = {}
    for pair in filter(None, opts.split(",")):
        key, eq, value = pair.partition("=")
        if not eq:
            raise SystemExit(f"nfpde_table: --variant {text!r}: option {pair!r} is not KEY=VALUE")
        try:
            options[key] = json.loads(value)
        except json.JSONDecodeError:
            options[key] = value
    try:  # unknown or bad options fail here, not mid-run
        EstimateConfig(method=method, options=options).method_config()
    except ValueError as exc:
        raise SystemExit(f"nfpde_table: --variant {text!r}: {exc}") from None
    return label, method, options


def dataset(env: str, target: str, seed: int, episodes: int, data_cache: dict) -> tuple:
    """The cell's dataset and its true per-trajectory parameters in the unit box (collected once
    per (env, target, seed), dataset seed = seed)."""
    if (env, target, seed) not in data_cache:
        ds, truth = collect(CollectConfig(env=env, xi=target, episodes=episodes, seed=seed))
        data_cache[(env, target, seed)] = (ds, ds.space.normalize(truth))
    return data_cache[(env, target, seed)]


def score(sampler, u_true: np.ndarray, seed: int) -> tuple[np.ndarray, float]:
    """The final score of an estimate: 500 draws (unit box) and their OT cost to the truth."""
    final_u = sampler.space.normalize(sampler.sample(500, np.random.default_rng(seed + 1000)))
    return final_u, ot_cost(final_u, u_true)


def run_one(
    env: str,
    target: str,
    method: str,
    seed: int,
    budget: int,
    episodes: int,
    data_cache: dict,
    options: dict | None = None,
    label: str | None = None,
) -> dict:
    """One estimation run, scored along its trace (recorded under `label`, default the method)."""
    ds, u_true = dataset(env, target, seed, episodes, data_cache)
    cpu0 = time.process_time()
    sampler, info, budget_state = estimate(
        ds, EstimateConfig(method=method, seed=seed, sim_budget=budget, options=dict(options or {}))
    )
    cpu = time.process_time() - cpu0
    trace = [{"calls": t["calls"], "seconds": t["seconds"], "ot": ot_cost(t["u"], u_true)} for t in budget_state.trace]
    final_u, final_ot = score(sampler, u_true, seed)
    return {
        "env": env,
        "target": target,
        "method": label or method,
        "estimator": method,
        "options": dict(options or {}),
        "seed": seed,
        "sim_budget": budget,
        "ot": final_ot,
        "seconds_total": info["seconds"],
        "cpu_seconds": cpu,
        "sim_calls": info["sim_calls"],
        "seconds_converge": converge_seconds(trace),
        "trace": trace,
        "details": info["details"],
        "samples_u": final_u[:300].round(4).tolist(),
        "true_u": u_true.round(4).tolist(),
    }


def oracle_ot(env: str, target: str, seed: int, data_cache: dict) -> float:
    """OT of 500 fresh draws from the TRUE target against the 48 true parameters: the floor."""
    ds, u_true = data_cache[(env, target, seed)]
    xi = sample_target(TargetConfig(kind=target), ds.space, 500, np.random.default_rng(seed + 2000))
    return ot_cost(ds.space.normalize(xi), u_true)


_CACHE: dict = {}  # datasets of the cells this process has collected (each is seeded: the same in every process)


def run_cell(
    env: str, target: str, method: str, seed: int, budget: int, episodes: int, options: dict, label: str
) -> tuple[dict, float, float]:
    """One run as a grid job: (the run, the cell's oracle OT, wall seconds with scoring)."""
    import torch

    torch.optim.Adam([torch.zeros(1, requires_grad=True)])  # torch._dynamo's import (~3 s) outside the timing
    t0 = time.perf_counter()
    run = run_one(env, target, method, seed, budget, episodes, _CACHE, options, label)
    return run, oracle_ot(env, target, seed, _CACHE), time.perf_counter() - t0


def _labels(runs: list[dict]) -> list[str]:
    """Method labels: the estimators first (in their order), then variants in order of appearance."""
    seen = list(dict.fromkeys(r["method"] for r in runs))
    return [m for m in ESTIMATORS if m in seen] + [m for m in seen if m not in ESTIMATORS]


def table_rows(runs: list[dict], oracle: dict) -> dict:
    """The rows of docs/results/nfpde.json."""
    rows = []
    for env in dict.fromkeys(r["env"] for r in runs):
        for target in TARGETS:
            for method in _labels(runs):
                sel = [r for r in runs if (r["env"], r["target"], r["method"]) == (env, target, method)]
                if not sel:
                    continue
                ot = np.array([r["ot"] for r in sel])
                rows.append(
                    {
                        "env": env,
                        "target": target,
                        "method": method,
                        "ot_mean": float(ot.mean()),
                        "ot_se": float(ot.std(ddof=1) / np.sqrt(len(ot))) if len(ot) > 1 else 0.0,
                        "seconds_mean": float(np.mean([converge_seconds(r["trace"]) for r in sel])),
                        "seconds_total_mean": float(np.mean([r["seconds_total"] for r in sel])),
                        **(
                            {"cpu_seconds_mean": float(np.mean([r["cpu_seconds"] for r in sel]))}
                            if all("cpu_seconds" in r for r in sel)
                            else {}
                        ),
                        "sim_calls_mean": float(np.mean([r["sim_calls"] for r in sel])),
                        "seeds": len(sel),
                        "oracle_ot_mean": float(
                            np.mean(
                                [
                                    oracle[f"{env}|{target}|{r['seed']}"]
                                    for r in sel
                                    if f"{env}|{target}|{r['seed']}" in oracle
                                ]
                                or [np.nan]
                            )
                        ),
                    }
                )
    return {"rows": rows}


def plot(runs: list[dict], out: Path, name: str = "nfpde") -> None:
    """Per env: samples (first two params) per method and target; OT vs seconds and vs calls."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = _labels(runs)
    for env in dict.fromkeys(r["env"] for r in runs):
        stem = env.split("/")[-1].split("-v")[0].lower()
        targets = [t for t in TARGETS if any((r["env"], r["target"]) == (env, t) for r in runs)]
        fig, axs = plt.subplots(
            len(targets), len(labels), figsize=(3.2 * len(labels), 3.2 * len(targets)), squeeze=False
        )
        for i, target in enumerate(targets):
            for j, method in enumerate(labels):
                ax = axs[i, j]
                sel = [r for r in runs if (r["env"], r["target"], r["method"], r["seed"]) == (env, target, method, 0)]
                if sel:
                    u, t = np.array(sel[0]["samples_u"]), np.array(sel[0]["true_u"])
                    ax.scatter(u[:, 0], u[:, 1], s=3, alpha=0.5, label="estimate")
                    ax.scatter(t[:, 0], t[:, 1], s=12, c="r", label="true xi")
                    ax.set_title(f"{method} / {target}\nOT {sel[0]['ot']:.3f}", fontsize=9)
                ax.set_xlim(0, 1)
                ax.set_ylim(0, 1)
        axs[0, 0].legend(fontsize=7)
        fig.suptitle(f"{env}: samples of the estimate (seed 0), first two parameters, unit box")
        fig.tight_layout()
        fig.savefig(out / f"{name}-{stem}-samples.png", dpi=100)
        plt.close(fig)

        for xkey, label in (("seconds", "wall time [s]"), ("calls", "simulator calls")):
            fig, axs = plt.subplots(1, len(targets), figsize=(5 * len(targets), 4), squeeze=False)
            for ax, target in zip(axs[0], targets):
                for method in labels:
                    sel = [r for r in runs if (r["env"], r["target"], r["method"]) == (env, target, method)]
                    for k, r in enumerate(sel):
                        x = [t[xkey] for t in r["trace"]]
                        y = [t["ot"] for t in r["trace"]]
                        color = f"C{labels.index(method)}"
                        ax.plot(
                            x,
                            y,
                            "-o" if len(x) == 1 else "-",
                            color=color,
                            ms=4,
                            alpha=0.7,
                            label=method if k == 0 else None,
                        )
                ax.set_xlabel(label)
                ax.set_ylabel("OT cost (unit box)")
                ax.set_title(f"{env} / {target}")
                ax.legend(fontsize=8)
            fig.tight_layout()
            fig.savefig(out / f"{name}-{stem}-ot-vs-{xkey}.png", dpi=100)
            plt.close(fig)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--envs", nargs="+", default=["goflow/Cartpole-v0"])
    p.add_argument("--targets", nargs="+", default=["gaussian", "mixture"], choices=TARGETS)
    p.add_argument("--methods", nargs="*", default=list(ESTIMATORS), choices=ESTIMATORS)
    p.add_argument(
        "--variant",
        action="append",
        default=[],
        metavar="LABEL=METHOD[:KEY=VALUE,...]",
        help="also run METHOD with these options, recorded as LABEL",
    )
    p.add_argument("--name", default="nfpde", help="stem of the result files")
    p.add_argument("--no-plots", action="store_true")
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--budget", type=int, default=100_000, help="simulator calls per run")
    p.add_argument("--episodes", type=int, default=48)
    p.add_argument("--out", default=str(RESULTS))
    p.add_argument("--workers", type=int, default=1, help="runs at once, one local process each (1: this process)")
    add_ray_flag(p)
    args = p.parse_args()
    try:
        backend = make_backend(args.ray, args.workers, inline=True)
    except GoflowError as exc:
        raise SystemExit(f"nfpde_table: {exc}") from None
    runs_to_do = [(m, m, {}) for m in args.methods] + [parse_variant(v) for v in args.variant]
    if len({label for label, _, _ in runs_to_do}) < len(runs_to_do):
        raise SystemExit("nfpde_table: a label is used twice in --methods/--variant")
    with ExitStack() as stack:
        try:  # a Ray cluster that cannot be reached fails here, before anything is written
            stack.enter_context(backend)
        except GoflowError as exc:
            raise SystemExit(f"nfpde_table: {exc}") from None
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        runs_path = out / f"{args.name}_runs.json"
        doc = read_json(runs_path, "runs file") if runs_path.exists() else {"runs": [], "oracle": {}}
        done = {_key(r) for r in doc["runs"]}
        doc["command"] = "python -m benchmarks.nfpde_table " + " ".join(sys.argv[1:])
        doc.setdefault("commands", []).append(doc["command"])  # every invocation on this runs file
        cells = [
            (env, target, method, seed, args.budget, args.episodes, options, label)
            for env in args.envs
            for target in args.targets
            for seed in range(args.seeds)
            for label, method, options in runs_to_do
            if (env, target, label, seed) not in done
        ]

        def save(index: int, result: tuple[dict, float, float]) -> None:
            run, oracle, seconds = result
            env, target, _, seed, *_ = cells[index]
            doc["oracle"][f"{env}|{target}|{seed}"] = oracle
            doc["runs"].append(run)
            write_json(runs_path, doc, indent=None)
            print(
                f"{env} {target} seed {seed} {run['method']}: OT {run['ot']:.3f}, converged "
                f"{run['seconds_converge']:.1f} s of {run['seconds_total']:.1f} s, cpu {run['cpu_seconds']:.1f} s "
                f"({seconds:.0f} s with scoring)",
                flush=True,
            )

        failed = None
        try:
            run_grid(
                [Job(f"{c[0]} {c[1]} seed {c[3]} {c[7]}", run_cell, c) for c in cells],
                backend,
                progress=not isinstance(backend, InlineBackend),
                desc="nfpde",
                on_result=save,
            )
        except GridError as exc:  # the other runs are saved; the summary below covers them
            failed = exc
    summary = table_rows(doc["runs"], doc["oracle"])
    summary["command"] = doc["command"]
    summary["commands"] = doc.get("commands", [doc["command"]])
    write_json(out / f"{args.name}.json", summary)
    if not args.no_plots:
        plot(doc["runs"], out, args.name)
    for r in summary["rows"]:
        print(
            f"{r['env']:<22} {r['target']:<9} {r['method']:<16} OT {r['ot_mean']:.3f} +- {r['ot_se']:.3f}  "
            f"converge {r['seconds_mean']:6.1f} s  total {r['seconds_total_mean']:6.1f} s  "
            f"(oracle {r['oracle_ot_mean']:.3f})"
        )
    if failed is not None:
        print(f"nfpde_table: {failed}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
