"""Discrete solver per batched env, chosen by measurement (issue 63, item 2): plant time step and
SAP/TAMSI contact approximation, speed against fidelity.

    .venv/bin/python -m benchmarks.solver_choice [--envs cartpole quadrotor ant anymal gear]
        [--num-envs 16 64] [--steps 960] [--repeats 3] [--episodes 16] [--obs-steps 10] [--json FILE]

Candidates per env: its configurable plant time step at 0.5x, 1x (today's default) and 2x (where
the control period is still a whole number of steps; the gear's 0.04 s step is its control period,
so it has no 2x), each with the default approximation ("lagged"), and every other discrete contact
approximation ("sap", "similar", "tamsi"; the Anymal's PD actuators refuse "tamsi") at 1x and 2x.
Cartpole, Quadrotor and the gear do not expose the approximation in their config; here it is set on
the plant after the env's own model code (measured only).

(a) Speed: batched env steps/s (`benchmarks.env_speed`'s workload: nominal xi, uniform random
actions; the gear pushes down while wandering) at each --num-envs N, candidates interleaved and
repeated --repeats times, the median taken; "x" = ratio to today's default in the same run.

(b) Fidelity, against the reference = the finest time step (0.5x) with the default approximation:
--episodes copies of one batched env (N = --episodes), reset with seed 0 (copy i: seed i, its xi
drawn by the default FullDR sampler) and stepped with the same random actions (seeded) in every
candidate, until every copy has ended its first episode. Metrics: `obs dev` = mean over copies,
the first --obs-steps steps and the observation entries of |obs - obs_ref| / (the reference's
std of that entry over those steps and copies); episode return and length, mean +- se over the
copies' first episodes; `fail` = copies whose physics failed (sim_error; a vector step that fails as
a whole counts every open copy, and a speed run that fails fails the `speed_runs` check); for the gear, the success
outcome's agreement with the reference. `stress`: the same run with xi at the corners of the box
(cycled over the copies) and bang-bang actions (the random actions' signs): its failed copies, and
its mean return against the reference's stressed one over the copies that failed in neither
(reported, not a check: bang-bang flight and falls are chaotic): the uniform random
actions at drawn xi rarely reach what broke TAMSI before (cartpole.py, quadrotor.py comments).

Pass (all of): |mean return - ref| <= 5 % of |ref mean return|; |mean length - ref| <= 5 % of the ref
mean length; obs dev <= 0.10; no more failed copies than the reference, in either run; gear: success agreement
>= 95 %. The MuJoCo check of docs/envs.md (benchmarks/mujoco_fidelity.py, within 10 %) covers the
locomotion envs with a MuJoCo original (Hopper, Walker2d, HalfCheetah, Humanoid), none of these
five, so it is not part of this table. Choice: the fastest passing candidate at the first N; it
replaces the default only if it is at least 1.1x faster (below that the noise of the shared
machine decides). The gear's default is not changed unless bit-identical (policies in
learning/skill_files/ were trained on it): its row is a measurement only.
"""

from __future__ import annotations

import argparse
import contextlib
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np

import assembly  # noqa: F401  (registers the ids)
from assembly.samplers import NoDR
from benchmarks.env_speed import actions_for
from goflow_common.errors import SimulationError
from goflow_common.files import check_output_file, write_json

APPROXIMATIONS = ("lagged", "sap", "similar", "tamsi")
DEFAULT_APPROXIMATION = "lagged"

# Stated thresholds (module docstring).
RETURN_TOLERANCE = 0.05
LENGTH_TOLERANCE = 0.05
OBS_DEV_TOLERANCE = 0.10
SUCCESS_AGREEMENT = 0.95
SWITCH_SPEEDUP = 1.1


@dataclass(frozen=True)
class EnvSpec:
    """How to vary one env's solver: its id, fixed kwargs, the time-step config field and its
    default, the control period, where the approximation goes, and the approximations it takes."""

    name: str
    env_id: str
    kwargs: dict[str, Any]
    dt_field: str
    dt_default: float
    control_dt: float
    approx_field: str | None  # a config field, or None: set on the plant (patch_target)
    patch_target: tuple[str, str] | None = None  # (module, function building the plant or a copy)
    approximations: tuple[str, ...] = APPROXIMATIONS
    shipped: bool = False  # trained policies depend on the default: measure, never change


def _specs() -> dict[str, EnvSpec]:
    from assembly.envs.ant import AntConfig
    from assembly.envs.anymal import AnymalConfig
    from assembly.envs.cartpole import CartpoleConfig
    from assembly.envs.gear_insertion import GearInsertionConfig
    from assembly.envs.quadrotor import QuadrotorConfig

    cp, qr, an, am, gr = CartpoleConfig(), QuadrotorConfig(), AntConfig(), AnymalConfig(), GearInsertionConfig()
    return {
        "cartpole": EnvSpec(
            "cartpole", "goflow/Cartpole-v0", {}, "sim_dt", cp.sim_dt, cp.control_dt, None,
            ("assembly.envs.cartpole_vector", "add_cartpole"),
        ),
        "quadrotor": EnvSpec(
            "quadrotor", "goflow/Quadrotor-v0", {}, "sim_dt", qr.sim_dt, qr.control_dt, None,
            ("assembly.envs.quadrotor_vector", "add_quadrotor"),
        ),
        "ant": EnvSpec("ant", "goflow/Ant-v0", {}, "time_step", an.time_step, an.control_dt, "contact_approximation"),
        "anymal": EnvSpec(
            "anymal", "goflow/Anymal-v0", {}, "time_step", am.time_step, am.control_dt, "contact_approximation",
            approximations=("lagged", "sap", "similar"),
        ),
        "gear": EnvSpec(
            "gear", "goflow/GearInsertion-v0", {"variant": "fast"}, "fast_time_step", gr.fast_time_step,
            gr.control_dt, None, ("assembly.envs.gear_insertion_vector", "fast_plant_config"), shipped=True,
        ),
    }  # fmt: skip


@dataclass(frozen=True)
class Candidate:
    scale: float  # time step / the default's
    approximation: str

    @property
    def label(self) -> str:
        return f"dt x{self.scale:g} {self.approximation}"


def candidates(spec: EnvSpec) -> list[Candidate]:
    """0.5x, 1x, 2x with the default approximation; the others at 1x and 2x (2x only where the
    control period is a whole number of steps)."""

    def fits(scale: float) -> bool:
        ratio = spec.control_dt / (spec.dt_default * scale)
        return abs(ratio - round(ratio)) < 1e-9 and round(ratio) >= 1

    scales = [s for s in (0.5, 1.0, 2.0) if fits(s)]
    out = [Candidate(s, DEFAULT_APPROXIMATION) for s in scales]
    out += [Candidate(s, a) for a in spec.approximations if a != DEFAULT_APPROXIMATION for s in scales if s >= 1]
    return out


@contextlib.contextmanager
def approximation(spec: EnvSpec, approx: str) -> Iterator[dict[str, Any]]:
    """The env kwargs that select `approx`; for envs without a config field, the plant-building
    function is wrapped meanwhile so that the approximation is set on the plant after it."""
    if spec.approx_field is not None:
        yield {spec.approx_field: approx}
        return
    if approx == DEFAULT_APPROXIMATION or spec.patch_target is None:
        yield {}
        return
    import importlib

    from pydrake.multibody.plant import DiscreteContactApproximation

    module = importlib.import_module(spec.patch_target[0])
    inner = getattr(module, spec.patch_target[1])
    value = {
        "lagged": DiscreteContactApproximation.kLagged,
        "sap": DiscreteContactApproximation.kSap,
        "similar": DiscreteContactApproximation.kSimilar,
        "tamsi": DiscreteContactApproximation.kTamsi,
    }[approx]

    if spec.patch_target[1] == "fast_plant_config":  # returns a MultibodyPlantConfig

        def wrapped(*args, **kwargs):
            config = inner(*args, **kwargs)
            config.discrete_contact_approximation = approx
            return config
    else:  # add_<robot>(plant, ...): set on the plant after the robot is added

        def wrapped(plant, *args, **kwargs):
            out = inner(plant, *args, **kwargs)
            plant.set_discrete_contact_approximation(value)
            return out

    setattr(module, spec.patch_target[1], wrapped)
    try:
        yield {}
    finally:
        setattr(module, spec.patch_target[1], inner)


def make_vec(spec: EnvSpec, cand: Candidate, n: int):
    with approximation(spec, cand.approximation) as extra:
        kwargs = {**spec.kwargs, spec.dt_field: spec.dt_default * cand.scale, **extra}
        return gymnasium.make_vec(spec.env_id, num_envs=n, vectorization_mode="vector_entry_point", **kwargs)


def speed(spec: EnvSpec, cand: Candidate, n: int, steps: int, seed: int = 0) -> float:
    """Env steps/s of the batched env (nominal xi, env_speed's workload), build time excluded;
    NaN where a vector step failed as a whole (the batched env's SimulationError: no copy fails
    alone, or the batch fails again with the failed copies held)."""
    vec = make_vec(spec, cand, n)
    vec.set_attr("sampler", NoDR(vec.space))
    vec.reset(seed=seed)
    rng = np.random.default_rng(seed)
    rounds = max(steps // n, 10)
    actions = np.stack([actions_for(spec.env_id, vec.single_action_space, n, rng) for _ in range(rounds)])
    t0 = time.perf_counter()
    try:
        for a in actions:
            vec.step(a)
    except SimulationError as exc:
        print(f"# {spec.name} {cand.label} N={n}: speed run failed: {str(exc).splitlines()[0][:160]}", flush=True)
        return float("nan")
    finally:
        vec.close()
    return rounds * n / (time.perf_counter() - t0)


@dataclass
class Rollout:
    obs: np.ndarray  # (copies, K, obs dim): first K observations after reset
    returns: np.ndarray  # (copies,) first episode's return
    lengths: np.ndarray  # (copies,)
    success: np.ndarray  # (copies,) bool
    failed_mask: np.ndarray  # (copies,) bool: the first episode ended in a physics failure

    @property
    def failed(self) -> int:
        return int(self.failed_mask.sum())


def corners(space, n: int) -> np.ndarray:
    """n rows cycling through the corners of the parameter box (xi where the physics is hardest)."""
    d = space.dim
    bits = (np.arange(n)[:, None] >> np.arange(d)) & 1
    return np.where(bits == 1, space.high, space.low)


def rollout(
    spec: EnvSpec, cand: Candidate, copies: int, obs_steps: int, seed: int = 0, stress: bool = False
) -> Rollout:
    """Every copy's first episode under seeded random actions (the same in every candidate);
    `stress`: xi at the box corners and bang-bang actions (the signs of the random ones)."""
    vec = make_vec(spec, cand, copies)
    space = vec.space
    options = {"xi": corners(space, copies)} if stress else None
    obs, _ = vec.reset(seed=seed, options=options)
    rng = np.random.default_rng(seed + 12345)
    traj = np.full((copies, obs_steps, obs.shape[1]), np.nan)
    returns, lengths = np.full(copies, np.nan), np.zeros(copies, dtype=int)
    success, failed = np.zeros(copies, dtype=bool), np.zeros(copies, dtype=bool)
    open_ = np.ones(copies, dtype=bool)
    t = 0
    while open_.any():
        a = actions_for(spec.env_id, vec.single_action_space, copies, rng)
        if stress:
            a = np.where(a >= 0.0, 1.0, -1.0)
        try:
            obs, _, terminated, truncated, info = vec.step(a)
        except SimulationError as exc:  # the batch failed as a whole: every open copy counts as failed
            print(
                f"# {spec.name} {cand.label}: rollout failed at step {t}: {str(exc).splitlines()[0][:160]}", flush=True
            )
            failed[open_], lengths[open_] = True, t + 1
            break
        done = terminated | truncated
        seen = obs.copy()
        for i in np.flatnonzero(done):
            seen[i] = info["final_obs"][i]
        if t < obs_steps:
            traj[open_, t] = seen[open_]
        for i in np.flatnonzero(done & open_):
            fi = info["final_info"]
            returns[i], lengths[i], success[i] = fi["episode_return"][i], t + 1, bool(fi["success"][i])
            failed[i] = "sim_error" in fi and fi["_sim_error"][i]
            open_[i] = False
        t += 1
    vec.close()
    return Rollout(traj, returns, lengths, success, failed)


def fidelity(r: Rollout, ref: Rollout) -> tuple[dict[str, Any], dict[str, bool]]:
    """The metrics of `r` against the reference, and pass/fail against the stated thresholds."""
    scale = np.nanstd(ref.obs, axis=(0, 1))
    varies = scale > 1e-6  # entries constant in the reference are left out
    dev = np.abs(r.obs - ref.obs)[..., varies] / scale[varies]
    obs_dev = float(np.nanmean(dev)) if np.isfinite(dev).any() else float("nan")

    def mean_se(x):
        x = np.asarray(x, float)
        return float(x.mean()), float(x.std(ddof=1) / np.sqrt(len(x))) if len(x) > 1 else 0.0

    ret, ret_se = mean_se(r.returns)
    ret_ref, _ = mean_se(ref.returns)
    ln, ln_se = mean_se(r.lengths)
    ln_ref, _ = mean_se(ref.lengths)
    agreement = float(np.mean(r.success == ref.success))
    checks = {
        "return": abs(ret - ret_ref) <= RETURN_TOLERANCE * abs(ret_ref),
        "length": abs(ln - ln_ref) <= LENGTH_TOLERANCE * ln_ref,
        "obs_dev": obs_dev <= OBS_DEV_TOLERANCE,
        "failures": r.failed <= ref.failed,
    }
    out = {
        "obs_dev": obs_dev,
        "return_mean": ret,
        "return_se": ret_se,
        "return_rel_diff": (ret - ret_ref) / abs(ret_ref) if ret_ref else float("nan"),
        "length_mean": ln,
        "length_se": ln_se,
        "failed": r.failed,
        "success_rate": float(r.success.mean()),
        "success_agreement": agreement,
    }
    return out, checks


def run_env(spec: EnvSpec, args: argparse.Namespace) -> list[dict[str, Any]]:
    cands = candidates(spec)
    default = Candidate(1.0, DEFAULT_APPROXIMATION)
    rates: dict[tuple[Candidate, int], list[float]] = {(c, n): [] for c in cands for n in args.num_envs}
    t0 = time.perf_counter()
    for _ in range(args.repeats):  # interleaved: each repeat visits every candidate once
        for c in cands:
            for n in args.num_envs:
                rates[(c, n)].append(speed(spec, c, n, args.steps))
    t_speed = time.perf_counter() - t0
    t0 = time.perf_counter()
    rolls = {c: rollout(spec, c, args.episodes, args.obs_steps) for c in cands}
    stressed = {c: rollout(spec, c, args.episodes, 1, stress=True) for c in cands}
    t_fid = time.perf_counter() - t0
    ref_cand = Candidate(min(c.scale for c in cands), DEFAULT_APPROXIMATION)
    ref, ref_stress = rolls[ref_cand], stressed[ref_cand]
    rows = []
    for c in cands:
        med = {n: float(np.median(rates[(c, n)])) for n in args.num_envs}
        base = {n: float(np.median(rates[(default, n)])) for n in args.num_envs}
        metrics, checks = fidelity(rolls[c], ref)
        metrics["stress_failed"] = stressed[c].failed
        both = ~(stressed[c].failed_mask | ref_stress.failed_mask)  # copies that failed in neither
        metrics["stress_return_rel_diff"] = (
            float(
                (stressed[c].returns[both].mean() - ref_stress.returns[both].mean())
                / abs(ref_stress.returns[both].mean())
            )
            if both.any()
            else float("nan")
        )
        checks["stress_failures"] = stressed[c].failed <= ref_stress.failed
        checks["speed_runs"] = all(np.isfinite(rates[(c, n)]).all() for n in args.num_envs)
        if spec.name == "gear":
            checks["success_agreement"] = metrics["success_agreement"] >= SUCCESS_AGREEMENT
        rows.append(
            {
                "env": spec.name,
                "candidate": c.label,
                "time_step": spec.dt_default * c.scale,
                "approximation": c.approximation,
                "default": c == default,
                "steps_per_s": {str(n): med[n] for n in args.num_envs},
                "ratio_to_default": {str(n): med[n] / base[n] for n in args.num_envs},
                **metrics,
                "checks": checks,
                "pass": all(checks.values()),
            }
        )
    print(f"# {spec.name}: speed {t_speed:.0f} s, fidelity {t_fid:.0f} s", flush=True)
    return rows


def choose(rows: list[dict[str, Any]], n: str, shipped: bool) -> dict[str, Any]:
    default = next(r for r in rows if r["default"])
    passing = [r for r in rows if r["pass"]]
    best = max(passing, key=lambda r: r["steps_per_s"][n]) if passing else default
    switch = best is not default and best["ratio_to_default"][n] >= SWITCH_SPEEDUP and not shipped
    chosen = best if switch else default
    return {
        "env": default["env"],
        "fastest_passing": best["candidate"],
        "its_ratio": best["ratio_to_default"][n],
        "chosen": chosen["candidate"],
        "changed": switch,
        "note": "measurement only (trained policies ship on this default)" if shipped else "",
    }


def print_table(rows: list[dict[str, Any]], sizes: list[int]) -> None:
    head = (
        f"{'env':<10} {'candidate':<20} "
        + " ".join(f"{f'N={n}':>7} {'x':>5}" for n in sizes)
        + f" {'obs dev':>8} {'return (mean +- se)':>20} {'dR':>7} {'length':>13} {'fail':>4} {'stress':>11} {'succ agr':>8} {'pass':>5}"
    )
    print(head)
    print("-" * len(head))
    for r in rows:
        cells = " ".join(f"{r['steps_per_s'][str(n)]:>7.0f} {r['ratio_to_default'][str(n)]:>5.2f}" for n in sizes)
        mark = "*" if r["default"] else " "
        print(
            f"{r['env']:<10} {r['candidate'] + mark:<20} {cells} {r['obs_dev']:>8.3f} "
            f"{r['return_mean']:>11.2f} +- {r['return_se']:<5.2f} {100 * r['return_rel_diff']:>6.1f}% "
            f"{r['length_mean']:>6.1f} +- {r['length_se']:<4.1f} {r['failed']:>4d} {r['stress_failed']:>3d} {100 * r['stress_return_rel_diff']:>6.1f}% {r['success_agreement']:>8.2f} "
            f"{'pass' if r['pass'] else 'FAIL':>5}"
            + ("" if r["pass"] else "  (" + ", ".join(k for k, v in r["checks"].items() if not v) + ")")
        )


def main() -> None:
    specs = _specs()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=list(specs), choices=list(specs))
    parser.add_argument("--num-envs", type=int, nargs="+", default=[16, 64], help="copies N of the speed runs")
    parser.add_argument("--steps", type=int, default=960, help="env steps per speed measurement")
    parser.add_argument("--repeats", type=int, default=3, help="interleaved speed repeats (median)")
    parser.add_argument("--episodes", type=int, default=16, help="copies (first episodes) of the fidelity runs")
    parser.add_argument("--obs-steps", type=int, default=10, help="K: steps of the observation deviation")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    if any(n < 1 for n in args.num_envs) or min(args.steps, args.repeats, args.episodes, args.obs_steps) < 1:
        parser.error("sizes must be whole numbers >= 1")
    if args.json:
        check_output_file(args.json)
    rows, choices = [], []
    for name in args.envs:
        env_rows = run_env(specs[name], args)
        rows += env_rows
        choices.append(choose(env_rows, str(args.num_envs[0]), specs[name].shipped))
    print("* today's default; reference: dt x0.5 lagged; x = steps/s over the default's, same run")
    print_table(rows, args.num_envs)
    for c in choices:
        print(
            f"{c['env']}: fastest passing {c['fastest_passing']} ({c['its_ratio']:.2f}x); "
            f"chosen {c['chosen']}{' (changed)' if c['changed'] else ''} {c['note']}"
        )
    if args.json:
        write_json(
            args.json,
            {
                "command": "python -m benchmarks.solver_choice",
                "args": {k: v for k, v in vars(args).items() if k != "json"},
                "thresholds": {
                    "return_rel": RETURN_TOLERANCE,
                    "length_rel": LENGTH_TOLERANCE,
                    "obs_dev": OBS_DEV_TOLERANCE,
                    "success_agreement": SUCCESS_AGREEMENT,
                    "switch_speedup": SWITCH_SPEEDUP,
                },
                "rows": rows,
                "choices": choices,
            },
        )


if __name__ == "__main__":
    main()
