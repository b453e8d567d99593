"""Sampler quality on known feasible sets (issue 21): mass on the set, coverage of it, entropy and KL
to the objective's optimum, against update rounds, for GoFlow in each mode and the baselines.

    .venv/bin/python -m benchmarks.sampler_quality --layouts disks ring --methods uniform lsdr goflow-paper \\
        --seeds 1 --rounds 30 --workers 1 [--out runs/sampler_quality] [--json PATH] [--plot PNG]
    .venv/bin/python -m benchmarks.sampler_quality --layouts strip --methods goflow-constrained \\
        --protocols uniform --sampler leak_target=0.008 --out runs/sq_leak0.008

`--sampler KEY=VALUE` (repeatable) sets a GoFlowConfig field of every goflow-* method of the run,
over the method's own options (values as JSON, else strings: `goflow_common.config.key_values`); it is refused
when a non-goflow method is selected, for `seed` (from `--seeds`) and `mode` (the method's name), and
for `alpha` with a goflow-entropy-<alpha> method. The KL keeps the method's default objective
whatever the flag sets (e.g. `delta`).

A run is (layout, method, protocol, seed). Each round draws a batch of `--batch` points, the
layout's oracle gives the signal (learning/feasible_sets.py), and `sampler.update(batch, signal)`
is timed. Protocols: `uniform`, the batch is uniform on the box (the validation batch); `own`, it is
the sampler's own draws. ADR learns only from its own draws (its boundary rows): it has no uniform
row. Signals: the layout's reward in [0, 1] (0/1 on 0/1 layouts); `goflow-constrained` gets the 0/1
success 1[xi in F] on every layout. ADR and DORAEMON compare the signal with J_T = 0.5; DORAEMON
runs with proposal="uniform" under the uniform protocol (its importance weights are then p'/U).

Measured at rounds 0, 10, 20, 50, 100, 200, ..., 500 (and every 100 beyond, and the last round),
each from its own RNG so that the schedule never changes the training:
- mass: the share of 4096 (`--draws`) sampler draws in F;
- cov10, cov1: the share of 4096 points uniform on F where the density exceeds 10 % / 1 % of the
  uniform-on-F density (the same points for every method of a seed);
- entropy: the sampler's own `entropy()` (nats; the unit box has entropy 0);
- kl: KL(q || p*) on the sampler's draws, p* the optimum of the method's objective: exp(r / alpha)
  for goflow-entropy-<alpha>, (1 - 0.005) U_F + 0.005 U_rest (the constrained optimum) for the rest;
- update_s: the median seconds of the updates since the previous measurement.
Every sampler here has a normalized `log_prob` (none needs a histogram estimate): GoFlow's is exact
(the flow truncated to the box), LSDR's and DORAEMON's analytic (truncated Gaussian, Betas), the
uniform's constant. ADR's is the uniform density on its intervals without its boundary draws'
atoms: its coverage and KL use that density (the KL on uniform draws on its intervals), its mass its
real draws, atoms included.

Each run writes <out>/<layout>/<method>/<protocol>/seed<k>.json atomically and is skipped when
present with the same settings: rounds, batch, draws and the sampler's resolved config, `--sampler`
included (a stored run with other settings is refused, never reused; rerun the command to resume;
Ctrl-C loses at most `--checkpoint-every` rounds of each run in progress, which resumes from its
checkpoint; a changed sampler default reruns a run, a changed sampler
*code* does not: delete the folder then). 2-D runs keep the final log density on a 64 x 64 grid for
the density figure. The summary (mean and standard error over seeds per layout x method x protocol
and round) goes to `--json` (default <out>/summary.json); `--plot PNG` draws mass and coverage
against rounds and, beside it (PNG stem + "_density.png"), the final densities of goflow-constrained
and goflow-paper on every 2-D layout with F's outline (seed = the first seed), the GoFlow paper's
Fig. 2 view.

Determinism: a run depends only on its (layout, method, protocol, seed, rounds, batch, draws,
`--sampler` overrides): the sampler's config seed, the batches, the measurement draws and torch's
global RNG all derive from the seed; the same seed gives the same row (timings aside).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from goflow_common.checks import InputErrorParser, check_int
from goflow_common.errors import GoflowError, InputError
from goflow_common.files import check_output_dir, check_output_file, read_json, to_strict_json, write_json
from learning.execution import Job, add_ray_flag, make_backend, run_grid
from learning.samplers.goflow_config import GoFlowConfig
from learning.feasible_sets import LAYOUTS, Layout, coverage, describe, kl_to_optimum, mass_on, optimum_mass

ROOT = Path(__file__).resolve().parents[1]

NAME = "sampler_quality"
PROTOCOLS = ("uniform", "own")
SCHEDULE = (0, 10, 20, 50, 100, 200, 300, 400, 500)
J_T = 0.5  # ADR's t+ and DORAEMON's success threshold on the [0, 1] signal
DELTA = (
    GoFlowConfig().delta
)  # the constrained objective's delta (GoFlow's default), and the KL reference of every non-entropy method
GRID = 64  # cells per side of the stored 2-D density
LEVELS = {"cov10": 0.1, "cov1": 0.01}
METRICS = ("mass", "cov10", "cov1", "entropy", "kl", "update_s")
#: What a null metric in a run's JSON means (strict JSON has no infinities): a point mass (ADR with a
#: zero-width interval) has entropy -inf and KL +inf.
INFINITE = {"entropy": -math.inf, "kl": math.inf}


@dataclass(frozen=True)
class Method:
    """A benchmarked sampler: registry name, config, the objective its KL is measured against, and
    the signal it learns from ("reward" in [0, 1] or "success" = 1[xi in F])."""

    name: str
    sampler: str
    config: dict[str, Any] = field(default_factory=dict)
    objective: tuple[str, float] = ("constrained", DELTA)
    signal: str = "reward"
    own_only: bool = False  # learns only from its own draws (ADR)


def _methods() -> dict[str, Method]:
    unit = (0.0, 1.0)
    methods = [Method("goflow-paper", "goflow", {"mode": "paper", "alpha": 0.5, "beta": 0.0})]
    for alpha in (0.1, 0.3, 1.0, 3.0):
        methods.append(
            Method(
                f"goflow-entropy-{alpha:g}",
                "goflow",
                {"mode": "entropy", "alpha": alpha, "beta": 0.0, "signal_range": unit},
                objective=("entropy", alpha),
            )
        )
    methods += [
        Method(
            "goflow-constrained", "goflow", {"mode": "constrained", "beta": 0.0, "signal_range": unit}, signal="success"
        ),
        Method("lsdr", "lsdr"),
        Method("doraemon", "doraemon"),
        Method("adr", "adr", own_only=True),
        Method("uniform", "fulldr"),
    ]
    return {m.name: m for m in methods}


#: The benchmarked methods by name; `--methods goflow-entropy` means every goflow-entropy-<alpha>.
METHODS: dict[str, Method] = _methods()
GROUPS = {
    "goflow-entropy": [m for m in METHODS if m.startswith("goflow-entropy-")],
    "goflow": [m for m in METHODS if m.startswith("goflow-")],
}


@dataclass(frozen=True)
class Task:
    """One run and the settings its JSON must match to be reused."""

    layout: str
    method: str
    protocol: str
    seed: int
    rounds: int
    batch: int
    draws: int
    #: `--sampler` overrides of the goflow-* methods' config, (key, value) pairs sorted by key
    overrides: tuple[tuple[str, Any], ...] = ()

    def path(self, out: Path) -> Path:
        """Where the run's JSON goes."""
        return out / self.layout / self.method / self.protocol / f"seed{self.seed}.json"

    def settings(self) -> dict[str, Any]:
        """The settings a stored run must have to be reused (the config includes `overrides`)."""
        return {"rounds": self.rounds, "batch": self.batch, "draws": self.draws, "config": resolved_config(self)}


def to_plain(obj: Any) -> Any:
    """`obj` with tuples as lists (as JSON gives it back), for comparisons with stored settings."""
    if isinstance(obj, dict):
        return {k: to_plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_plain(v) for v in obj]
    return obj


# -- one run ------------------------------------------------------------------------------------


def sampler_config(
    method: Method, protocol: str, seed: int, overrides: Sequence[tuple[str, Any]] = ()
) -> dict[str, Any]:
    """The config `method`'s sampler gets under `protocol` with run seed `seed`: its own options,
    DORAEMON's proposal for uniform batches, `seed` where the config has a seed field, and the
    `--sampler` `overrides` last."""
    from learning.samplers.registry import sampler_config as registered_config

    fields = {f.name for f in dataclasses.fields(registered_config(method.sampler, None))}
    config = dict(method.config)
    if method.sampler == "doraemon" and protocol == "uniform":
        config["proposal"] = "uniform"
    if "seed" in fields:
        config["seed"] = seed
    config.update(overrides)
    return config


def resolved_config(task: Task) -> dict[str, Any]:
    """Every field of `task`'s sampler config as JSON data (`sampler_config` validated by the
    sampler's config dataclass, defaults filled in): a stored run is reused only while this is
    unchanged, so a changed default reruns it. A bad option is an InputError before any run."""
    method = METHODS[task.method]
    return _config_data(method.sampler, sampler_config(method, task.protocol, task.seed, task.overrides))


def default_config(task: Task) -> dict[str, Any]:
    """`task`'s sampler config with every field at its default, as JSON data."""
    return _config_data(METHODS[task.method].sampler, None)


def _config_data(sampler: str, options: dict[str, Any] | None) -> dict[str, Any]:
    """The registered config of `sampler` with `options` (None: its defaults), as JSON data."""
    from goflow_common.config import config_to_dict
    from learning.samplers.registry import sampler_config as registered_config

    return to_plain(config_to_dict(registered_config(sampler, options)))


def _signal(layout: Layout, method: Method, xi: np.ndarray) -> np.ndarray:
    if method.signal == "success":
        return layout.contains(xi).astype(np.float64)
    return layout.reward(xi)


def measure(
    sampler: Any, layout: Layout, method: Method, inside: np.ndarray, draws: int, rng: np.random.Generator
) -> dict[str, float]:
    """Mass, coverage at each level, entropy and KL to the method's optimum of `sampler` now."""
    from learning.samplers.adr import ADRSampler

    own = sampler.sample(draws, rng)
    density = own
    if isinstance(sampler, ADRSampler):  # log_prob is uniform on its intervals, without the boundary atoms
        b = sampler.bounds()
        density = rng.uniform(b[:, 0], b[:, 1], size=(draws, len(b)))
    row = {"mass": mass_on(own, layout.contains)}
    for key, level in LEVELS.items():
        row[key] = coverage(sampler.log_prob, inside, layout.share, level, layout.volume)
    row["entropy"] = float(sampler.entropy())
    row["kl"] = kl_to_optimum(density, sampler.log_prob, layout, method.objective)
    return row


def schedule(rounds: int) -> list[int]:
    """The rounds measured: SCHEDULE up to `rounds`, every 100 beyond 500, and `rounds` itself."""
    extra = range(600, rounds, 100)
    return sorted({s for s in SCHEDULE if s <= rounds} | set(extra) | {rounds})


def density_grid(sampler: Any, grid: int = GRID) -> list[list[float]]:
    """log_prob at the centres of a grid x grid partition of the unit square, rows along p1."""
    c = (np.arange(grid) + 0.5) / grid
    x, y = np.meshgrid(c, c)
    lp = sampler.log_prob(np.stack([x.ravel(), y.ravel()], axis=1)).reshape(grid, grid)
    return np.round(lp, 4).tolist()


def partial_path(task: Task, out: Path) -> Path:
    """Where `task`'s checkpoint goes while it runs (removed once its JSON is written)."""
    return task.path(out).with_name(f"checkpoint-seed{task.seed}.json")


def checkpoint(task: Task, out: Path) -> dict[str, Any] | None:
    """`task`'s checkpoint under `out`, None if there is none; InputError if it has other settings."""
    path = partial_path(task, out)
    if not path.exists():
        return None
    state = read_json(path, "sampler_quality checkpoint")
    _check_settings(path, state, task)
    return state


def _check_settings(path: Path, record: dict[str, Any], task: Task) -> None:
    """InputError naming each difference if `record` (read from `path`) has other settings than
    `task`. A config field the record lacks (one added to the sampler after it was written) reads
    as the field's default: fields are added with defaults that keep the earlier behaviour."""
    want = task.settings()
    have = {k: record.get(k) for k in want}
    if isinstance(have["config"], dict):
        have["config"] = {**default_config(task), **have["config"]}
    if have == want:
        return
    diff = [f"{k} {have[k]!r} (want {want[k]!r})" for k in ("rounds", "batch", "draws") if have[k] != want[k]]
    if have["config"] != want["config"]:
        old, new, absent = have["config"] or {}, want["config"], "absent"
        diff += [
            f"config.{k} {old.get(k, absent)!r} (want {new.get(k, absent)!r})"
            for k in sorted({*old, *new})
            if k not in old or k not in new or old[k] != new[k]
        ]
    raise InputError(f"{path} holds a run with other settings: {', '.join(diff)}; delete it or choose another --out")


def run_task(task: Task, out: Path | None = None, checkpoint_every: int = 0) -> dict[str, Any]:
    """Run `task` and return its record (the run's JSON): settings, the measured rows, every
    update's seconds and, on a 2-D layout, the final log density on the grid.

    With `out` and `checkpoint_every` > 0 the run's state (sampler, batch and torch generators,
    rows so far) is written to `partial_path` every `checkpoint_every` rounds, and a run that finds
    one there resumes from it: the rows are those of an uninterrupted run."""
    import torch
    from learning.samplers.registry import make_sampler

    torch.set_num_threads(1)
    torch.manual_seed(task.seed)
    t_start = time.perf_counter()
    layout, method = LAYOUTS[task.layout], METHODS[task.method]
    config = sampler_config(method, task.protocol, task.seed, task.overrides)
    sampler = make_sampler(method.sampler, layout.space, J_T, config)
    batch_rng = np.random.default_rng([task.seed, 0])
    inside = layout.sample_inside(task.draws, np.random.default_rng([task.seed, 2]))
    plan = schedule(task.rounds)
    rows: list[dict[str, Any]] = []
    seconds: list[float] = []
    start, wall_before = 0, 0.0
    partial = partial_path(task, out) if out is not None and checkpoint_every > 0 else None
    state = checkpoint(task, out) if partial is not None else None
    if state is not None:
        try:
            sampler.load_state_dict(state["sampler"])
            batch_rng.bit_generator.state = state["batch_rng"]
            torch.set_rng_state(torch.tensor(state["torch_rng"], dtype=torch.uint8))
            start, rows, seconds, wall_before = int(state["round"]), state["rows"], state["update_s"], state["wall_s"]
        except (KeyError, TypeError, ValueError, RuntimeError) as exc:
            raise InputError(f"{partial}: not a checkpoint of this run ({exc!r}); delete it to start over") from exc
    for k in range(start, task.rounds + 1):
        if partial is not None and k > start and k % checkpoint_every == 0 and k < task.rounds:
            write_json(
                partial,
                to_strict_json(
                    {
                        "benchmark": NAME,
                        **task.settings(),
                        "round": k,
                        "rows": rows,
                        "update_s": seconds,
                        "wall_s": wall_before + time.perf_counter() - t_start,
                        "sampler": sampler.state_dict(),
                        "batch_rng": batch_rng.bit_generator.state,
                        "torch_rng": torch.get_rng_state().tolist(),
                    }
                ),
            )
        if k in plan:
            row = {
                "round": k,
                **measure(sampler, layout, method, inside, task.draws, np.random.default_rng([task.seed, 1, k])),
            }
            since = seconds[len(seconds) - (k - rows[-1]["round"]) :] if rows else []
            row["update_s"] = float(np.median(since)) if since else None
            rows.append(row)
        if k == task.rounds:
            break
        own = task.protocol == "own" or method.own_only
        xi = sampler.sample(task.batch, batch_rng) if own else batch_rng.random((task.batch, layout.dim))
        signal = _signal(layout, method, xi)
        t0 = time.perf_counter()
        sampler.update(xi, signal)
        seconds.append(time.perf_counter() - t0)
    record = {
        "benchmark": NAME,
        **dataclasses.asdict(task),
        "overrides": dict(task.overrides),
        "sampler": method.sampler,
        "config": resolved_config(task),
        "objective": list(method.objective),
        "signal": method.signal,
        "rows": rows,
        "update_s": [round(s, 5) for s in seconds],
        "update_s_median": float(np.median(seconds)) if seconds else None,
        "wall_s": wall_before + time.perf_counter() - t_start,
    }
    if layout.dim == 2:
        record["density"] = {"grid": GRID, "log_prob": density_grid(sampler)}
    return to_strict_json(record)  # as stored: a non-finite number is null (see INFINITE)


def run_and_save(task: Task, out: Path, checkpoint_every: int = 0) -> dict[str, Any]:
    """Run `task` (resuming from its checkpoint, see `run_task`) and write its JSON atomically
    under `out`; return its record."""
    record = run_task(task, out, checkpoint_every)
    write_json(task.path(out), record)
    partial_path(task, out).unlink(missing_ok=True)
    return record


def run_job(task: Task, out: Path, checkpoint_every: int = 0) -> dict[str, Any]:
    """`run_and_save` on one torch thread (the grid's job: one CPU each)."""
    import torch

    torch.set_num_threads(1)
    return run_and_save(task, out, checkpoint_every)


# -- the plan -----------------------------------------------------------------------------------


def _expand(names: Sequence[str], known: dict[str, Any], groups: dict[str, list[str]], what: str) -> list[str]:
    out: list[str] = []
    for name in names:
        if name == "all":
            chosen = list(known)
        elif name in groups:
            chosen = groups[name]
        elif name in known:
            chosen = [name]
        else:
            raise InputError(f"--{what} {name!r}: unknown; expected one of {['all', *groups, *known]}")
        out += [c for c in chosen if c not in out]
    return out


def parse_seeds(values: Sequence[str]) -> list[int]:
    """`--seeds`: one number N means seeds 0..N-1; several numbers or a comma list ("3," or "0,4")
    are the seeds themselves."""
    items = [v for text in values for v in text.split(",") if v.strip()]
    try:
        numbers = [int(v) for v in items]
    except ValueError:
        raise InputError(f"--seeds {' '.join(values)!r}: expected a count N or a list of seeds (0,3,7)") from None
    if not numbers:
        raise InputError("--seeds is empty; expected a count N or a list of seeds")
    if len(values) == 1 and "," not in values[0]:
        return list(range(check_int(numbers[0], "--seeds (a count)", 1)))
    for s in numbers:
        check_int(s, "--seeds entry", 0)
    return sorted(set(numbers))


def _frozen(value: Any) -> Any:
    """A parsed `--sampler` value with lists as tuples (a Task is frozen and hashable)."""
    return tuple(_frozen(v) for v in value) if isinstance(value, list) else value


def parse_overrides(pairs: Sequence[str] | None, methods: Sequence[str]) -> tuple[tuple[str, Any], ...]:
    """`--sampler KEY=VALUE ...` for `methods`: (key, value) pairs sorted by key, each checked by
    the goflow config of every method (`config_with_overrides`); InputError naming the pair otherwise."""
    from goflow_common.config import config_with_overrides, key_values
    from goflow_common.errors import UnknownOptionError

    values = key_values(pairs, "--sampler")
    if not values:
        return ()
    others = [m for m in methods if METHODS[m].sampler != "goflow"]
    if others:
        raise InputError(
            f"--sampler sets GoFlowConfig fields of the goflow-* methods only; also selected: {others} "
            "(choose --methods among the goflow-* ones)"
        )
    fixed = {"seed": "--seeds sets it", "mode": "the method's name sets it"}
    if any(METHODS[m].objective[0] == "entropy" for m in methods):
        fixed["alpha"] = "a goflow-entropy-<alpha> method's name sets it"
    for key in values:
        if key in fixed:
            raise InputError(f"--sampler {key}=...: not allowed ({fixed[key]})")
    for m in methods:
        base = sampler_config(METHODS[m], PROTOCOLS[0], 0)
        for key, value in values.items():  # one at a time, so that an error names its pair
            try:
                config_with_overrides(GoFlowConfig, base, {key: value}, owner="--sampler")
            except UnknownOptionError:
                raise
            except (InputError, TypeError) as exc:
                raise InputError(f"--sampler {key}={value!r}: {' '.join(str(exc).split())}") from None
        config_with_overrides(GoFlowConfig, base, values, owner="--sampler")  # and together
    return tuple(sorted((k, _frozen(v)) for k, v in values.items()))


def plan(args: argparse.Namespace) -> list[Task]:
    """The runs the flags ask for (ADR only under the `own` protocol), checked before any work."""
    layouts = _expand(args.layouts, LAYOUTS, {}, "layouts")
    methods = _expand(args.methods, METHODS, GROUPS, "methods")
    protocols = _expand(args.protocols, {p: p for p in PROTOCOLS}, {}, "protocols")
    seeds = parse_seeds(args.seeds)
    rounds = check_int(args.rounds, "--rounds", 1)
    batch = check_int(args.batch, "--batch", 2)
    draws = check_int(args.draws, "--draws", 16)
    check_int(args.workers, "--workers", 1)
    overrides = parse_overrides(args.sampler, methods)
    tasks = [
        Task(layout, method, protocol, seed, rounds, batch, draws, overrides)
        for layout in layouts
        for method in methods
        for protocol in protocols
        for seed in seeds
        if not (METHODS[method].own_only and protocol != "own")
    ]
    if not tasks:
        raise InputError(f"no runs: {methods} under protocols {protocols} (ADR runs only under --protocols own)")
    return tasks


def stored(task: Task, out: Path) -> dict[str, Any] | None:
    """The stored record of `task`, None if there is none; InputError if one is there with other
    settings (another --rounds, --batch, --draws or sampler config)."""
    path = task.path(out)
    if not path.exists():
        return None
    record = read_json(path, "sampler_quality run")
    _check_settings(path, record, task)
    return record


# -- the summary --------------------------------------------------------------------------------


def _mean_se(values: list[float | None], infinite: float | None = None) -> tuple[float | None, float | None]:
    """Mean and standard error over seeds (None: no value; se None for one seed). A None value
    means `infinite` when it is given (then the mean is that infinity), else it is left out."""
    if infinite is not None and any(v is None for v in values):
        return infinite, None
    v = np.array([x for x in values if x is not None], dtype=float)
    if len(v) == 0:
        return None, None
    mean = float(np.mean(v))
    se = float(np.std(v, ddof=1) / math.sqrt(len(v))) if len(v) > 1 else None
    return mean, se


def quality_rows(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per (layout, method, protocol): the measured rounds and, per metric, the mean and
    standard error over seeds at each round; the median update seconds and wall time per run."""
    groups: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
    for r in records:
        groups.setdefault((r["layout"], r["method"], r["protocol"]), []).append(r)
    rows = []
    for (layout, method, protocol), runs in groups.items():
        rounds = [row["round"] for row in runs[0]["rows"]]
        metrics = {}
        for metric in METRICS:
            stats = [
                _mean_se([run["rows"][i][metric] for run in runs], INFINITE.get(metric)) for i in range(len(rounds))
            ]
            metrics[metric] = {"mean": [s[0] for s in stats], "se": [s[1] for s in stats]}
        rows.append(
            {
                "layout": layout,
                "method": method,
                "protocol": protocol,
                "seeds": sorted(run["seed"] for run in runs),
                "rounds": rounds,
                "metrics": metrics,
                "update_s_median": _mean_se([run["update_s_median"] for run in runs])[0],
                "wall_s_per_run": _mean_se([run["wall_s"] for run in runs])[0],
            }
        )
    return rows


def _cell(mean: float | None, se: float | None, digits: int = 3) -> str:
    if mean is None:
        return "-"
    if math.isinf(mean):
        return f"{mean}"
    return f"{mean:.{digits}f}" + ("" if se is None else f"±{se:.{digits}f}")


def table(rows: list[dict[str, Any]]) -> str:
    """The printed table: per row, the final round and round 100 (when measured and not final)."""
    head = (
        f"{'layout':<12} {'method':<20} {'protocol':<8} {'n':>2} {'round':>5} {'mass':>13} {'cov10':>13} "
        f"{'cov1':>13} {'kl':>13} {'update[s]':>9} {'run[s]':>7}"
    )
    lines = [head, "-" * len(head)]
    for row in rows:
        final = len(row["rounds"]) - 1
        picks = [i for i, k in enumerate(row["rounds"]) if k == 100 and i != final] + [final]
        for i in picks:
            m = row["metrics"]
            cells = [_cell(m[k]["mean"][i], m[k]["se"][i]) for k in ("mass", "cov10", "cov1", "kl")]
            upd = m["update_s"]["mean"][i]
            lines.append(
                f"{row['layout']:<12} {row['method']:<20} {row['protocol']:<8} {len(row['seeds']):>2} "
                f"{row['rounds'][i]:>5} {cells[0]:>13} {cells[1]:>13} {cells[2]:>13} {cells[3]:>13} "
                f"{'-' if upd is None else f'{upd:.4f}':>9} {row['wall_s_per_run']:>7.1f}"
            )
    return "\n".join(lines)


# -- figures ------------------------------------------------------------------------------------


def plot_quality(rows: list[dict[str, Any]], path: Path) -> None:
    """Mass and coverage at 10 % against rounds: a row of panels per layout, one column per
    (metric, protocol), a line per method (mean; the band is +- one standard error)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    layouts = list(dict.fromkeys(r["layout"] for r in rows))
    protocols = [p for p in PROTOCOLS if any(r["protocol"] == p for r in rows)]
    columns = [(metric, p) for metric in ("mass", "cov10") for p in protocols]
    colours = {m: plt.cm.tab10(i % 10) for i, m in enumerate(METHODS)}
    fig, axes = plt.subplots(
        len(layouts), len(columns), figsize=(3.2 * len(columns), 2.4 * len(layouts)), squeeze=False, sharex=True
    )
    for i, layout in enumerate(layouts):
        for j, (metric, protocol) in enumerate(columns):
            ax = axes[i, j]
            for r in rows:
                if r["layout"] != layout or r["protocol"] != protocol:
                    continue
                x = np.array(r["rounds"], dtype=float)
                mean = np.array([np.nan if v is None else v for v in r["metrics"][metric]["mean"]], dtype=float)
                se = np.array([0.0 if v is None else v for v in r["metrics"][metric]["se"]], dtype=float)
                ax.plot(x, mean, marker=".", color=colours[r["method"]], label=r["method"])
                ax.fill_between(x, mean - se, mean + se, color=colours[r["method"]], alpha=0.2)
            ax.set_ylim(-0.02, 1.02)
            ax.set_title(f"{layout}: {metric}, {protocol} batches", fontsize=8)
            if i == len(layouts) - 1:
                ax.set_xlabel("round")
    handles = {h.get_label(): h for ax in axes.ravel() for h in ax.get_lines()}
    ncol = min(5, len(handles))
    fig.legend(list(handles.values()), list(handles), loc="upper center", ncol=ncol, fontsize=8)
    legend_rows = -(-len(handles) // ncol)
    fig.tight_layout(rect=(0, 0, 1, 1 - (0.15 + 0.25 * legend_rows) / (2.4 * len(layouts))))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_densities(
    records: list[dict[str, Any]], path: Path, methods: Sequence[str] = ("goflow-constrained", "goflow-paper")
) -> bool:
    """The final density exp(log_prob) of `methods` on each 2-D layout, the feasible set's outline
    on top (the GoFlow paper's Fig. 2 view), first seed of each run; the colour scale runs from 0 to
    twice the uniform-on-F density. False when there is nothing to draw."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    picked: dict[tuple[str, str, str], dict[str, Any]] = {}
    for r in sorted(records, key=lambda r: r["seed"]):
        if "density" in r and r["method"] in methods:
            picked.setdefault((r["layout"], r["method"], r["protocol"]), r)
    if not picked:
        return False
    layouts = list(dict.fromkeys(k[0] for k in picked))
    columns = [(m, p) for m in methods for p in PROTOCOLS if any(k[1:] == (m, p) for k in picked)]
    fig, axes = plt.subplots(
        len(layouts), len(columns) + 1, figsize=(2.6 * (len(columns) + 1), 2.6 * len(layouts)), squeeze=False
    )
    c = (np.arange(200) + 0.5) / 200
    gx, gy = np.meshgrid(c, c)
    for i, layout in enumerate(layouts):
        inside = LAYOUTS[layout].contains(np.stack([gx.ravel(), gy.ravel()], axis=1)).reshape(gx.shape)
        axes[i, 0].imshow(inside, origin="lower", extent=(0, 1, 0, 1), cmap="Greens")
        axes[i, 0].set_title(f"{layout}: F ({LAYOUTS[layout].share:.1%})", fontsize=8)
        for j, (method, protocol) in enumerate(columns, start=1):
            ax = axes[i, j]
            r = picked.get((layout, method, protocol))
            if r is None:
                ax.axis("off")
                continue
            lp = np.array([[np.nan if v is None else v for v in row] for row in r["density"]["log_prob"]])
            # one colour scale for every panel: 0 to twice the uniform-on-F density (the
            # constrained optimum sits mid-scale; narrow spikes saturate instead of hiding the rest)
            top = 2.0 / (LAYOUTS[layout].share * LAYOUTS[layout].volume)
            ax.imshow(np.exp(lp), origin="lower", extent=(0, 1, 0, 1), cmap="viridis", vmin=0.0, vmax=top)
            ax.contour(gx, gy, inside.astype(float), levels=[0.5], colors="white", linewidths=0.8)
            ax.set_title(f"{method}, {protocol}, round {r['rounds']}", fontsize=8)
        for ax in axes[i]:
            ax.set_xticks([])
            ax.set_yticks([])
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


# -- command line -------------------------------------------------------------------------------


def make_parser() -> argparse.ArgumentParser:
    """The benchmark's flags."""
    p = InputErrorParser(prog="benchmarks/sampler_quality.py", description=__doc__.splitlines()[0])
    p.add_argument("--layouts", nargs="+", default=["all"], help=f"'all' or some of {list(LAYOUTS)}")
    p.add_argument("--methods", nargs="+", default=["all"], help=f"'all', {list(GROUPS)} or some of {list(METHODS)}")
    p.add_argument("--protocols", nargs="+", default=["all"], help=f"'all' or some of {list(PROTOCOLS)}")
    p.add_argument("--seeds", nargs="+", default=["5"], help="a count N (seeds 0..N-1) or a list (0,3 or 0 3)")
    p.add_argument("--rounds", type=int, default=500, help="updates per run")
    p.add_argument("--batch", type=int, default=256, help="points per update")
    p.add_argument(
        "--draws", type=int, default=4096, help="draws per measurement (mass, KL) and points on F (coverage)"
    )
    p.add_argument("--workers", type=int, default=1, help="processes (one torch thread each)")
    p.add_argument(
        "--checkpoint-every",
        type=int,
        default=50,
        metavar="ROUNDS",
        help="write each run's state every ROUNDS rounds, and resume a run from it (0: never)",
    )
    p.add_argument(
        "--sampler",
        action="append",
        metavar="KEY=VALUE",
        help="a GoFlowConfig field for the goflow-* methods, e.g. leak_target=0.008 (repeatable; value "
        "as JSON, else a string); refused with any non-goflow method, and for seed, mode (and alpha "
        "of goflow-entropy-<alpha>); the KL keeps the method's default objective. Part of each "
        "run's stored config: a stored run with other overrides is refused, never reused",
    )
    add_ray_flag(p)
    p.add_argument(
        "--existing",
        action="store_true",
        help="run nothing: summarize (and plot) the runs of the grid already stored in --out",
    )
    p.add_argument("--out", type=Path, default=ROOT / "runs" / NAME, help="folder of the per-run JSON files")
    p.add_argument("--json", type=Path, default=None, help="summary file (default <out>/summary.json)")
    p.add_argument("--plot", type=Path, default=None, help="figure PNG; the densities go to <stem>_density.png")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; 0 on success, 2 with one line on stderr for bad input, 130 on Ctrl-C."""
    done: list[dict[str, Any]] = []
    tasks: list[Task] = []
    out = Path()
    try:
        args = make_parser().parse_args(argv)
        tasks = plan(args)
        every = check_int(args.checkpoint_every, "--checkpoint-every", 0)
        out = check_output_dir(args.out, "--out")
        summary_path = check_output_file(args.json or out / "summary.json", "--json")
        if args.plot is not None:
            check_output_file(args.plot, "--plot")
        todo = []
        for task in tasks:
            record = stored(task, out)
            (todo.append(task) if record is None else done.append(record))
        if args.existing:  # summarize what is stored, run nothing
            tasks = [t for t in tasks if t not in todo]
            todo = []
            if not tasks:
                raise InputError(f"--existing: no stored run of this grid in {out}")
        skipped = len(done)
        # checkpoints with other settings are refused before any run starts
        resuming = sum(checkpoint(t, out) is not None for t in todo) if every else 0
        print(
            f"{NAME}: {len(tasks)} runs, {skipped} already in {out}, {len(todo)} to run ({resuming} from a "
            f"checkpoint), {args.workers} worker(s)"
        )
        for task in todo:  # sampler configs are checked before any run starts
            resolved_config(task)

        def report(record: dict[str, Any]) -> None:
            done.append(record)
            print(
                f"[{len(done) - skipped}/{len(todo)}] {record['layout']} {record['method']} {record['protocol']} "
                f"seed{record['seed']}: {record['rounds']} rounds in {record['wall_s']:.1f} s, update median "
                f"{record['update_s_median']:.4f} s, final mass {record['rows'][-1]['mass']:.3f}, "
                f"cov10 {record['rows'][-1]['cov10']:.3f}",
                flush=True,
            )

        jobs = [Job(f"{t.layout}/{t.method}/{t.protocol}/seed{t.seed}", run_job, (t, out, every)) for t in todo]
        run_grid(
            jobs,
            make_backend(args.ray, args.workers, inline=True),
            progress=False,
            desc=NAME,
            on_result=lambda _, record: report(record),
        )

        order = {(t.layout, t.method, t.protocol, t.seed): i for i, t in enumerate(tasks)}
        done.sort(key=lambda r: order[(r["layout"], r["method"], r["protocol"], r["seed"])])
        rows = quality_rows(done)
        print(table(rows))
        layouts = list(dict.fromkeys(t.layout for t in tasks))
        write_json(
            summary_path,
            {
                "benchmark": NAME,
                "command": "benchmarks/sampler_quality.py " + " ".join(argv or sys.argv[1:]),
                "settings": {
                    "rounds": tasks[0].rounds,
                    "batch": tasks[0].batch,
                    "draws": tasks[0].draws,
                    "seeds": sorted({t.seed for t in tasks}),
                    "j_t": J_T,
                    "delta": DELTA,
                    "levels": LEVELS,
                    "sampler_overrides": dict(tasks[0].overrides),
                },
                "layouts": {
                    name: {
                        **describe(LAYOUTS[name]),
                        "optimum_mass": {
                            m: optimum_mass(LAYOUTS[name], METHODS[m].objective)
                            for m in dict.fromkeys(t.method for t in tasks)
                        },
                    }
                    for name in layouts
                },
                "methods": {m: dataclasses.asdict(METHODS[m]) for m in dict.fromkeys(t.method for t in tasks)},
                "rows": rows,
            },
        )
        print(f"{NAME}: summary -> {summary_path}")
        if args.plot is not None:
            plot_quality(rows, args.plot)
            density = args.plot.with_name(args.plot.stem + "_density.png")
            drawn = plot_densities(done, density)
            print(
                f"{NAME}: figures -> {args.plot}"
                + (f", {density}" if drawn else " (no 2-D GoFlow run to draw densities of)")
            )
        return 0
    except KeyboardInterrupt:
        print(
            f"{NAME}: interrupted; {len(done)} of {len(tasks)} runs are saved in {out}; rerun the same command "
            "to resume",
            file=sys.stderr,
        )
        return 130
    except (GoflowError, ValueError, TypeError, OSError) as exc:
        print(f"{NAME}: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
