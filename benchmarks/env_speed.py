"""Speed of every goflow environment: steps per second single and vectorized, and the wrapper's
overhead against advancing the bare Drake simulator through the same steps.

    .venv/bin/python benchmarks/env_speed.py [--steps 400] [--workers 2] [--json docs/results/env_speed.json]
    .venv/bin/python benchmarks/env_speed.py --batched [--copies 1 16 64 256] [--json docs/results/batched_speed.json]

Every env runs at its nominal xi (a NoDR sampler), so all columns do the same physics.
Columns: steps/s and real-time factor (simulated s per wall s) in one process; steps/s of an
AsyncVectorEnv with `--workers` processes (one env each); wrapper overhead = env.step time over
bare-simulator time for the same xi and actions, minus 1 (envs with a bare_rollout method);
MuJoCo steps/s = gymnasium's MuJoCo original of a locomotion env (Hopper-v5, ...) stepped with the
same actions in the same process, when the `mujoco` extra is installed.

With --batched, the table is for the ids with a batched vector env (assembly/envs/batched.py):
env steps/s of today's path (a SyncVectorEnv of 16 single envs) and of the batched env at each
--copies N, the ratio of each to today, the share of the batched step spent in Drake's
AdvanceTo at the largest N (the rest is Python: observations, rewards, bookkeeping), and, where a
MuJoCo original exists, its steps/s single and through `mujoco.rollout` with N states at once.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gymnasium
import numpy as np

import assembly  # noqa: F401  (registers the ids)
from assembly.samplers import NoDR
from goflow_common.files import check_output_file, write_json

ENVS = {
    "goflow/Toy2D-v0": {},
    "goflow/Cartpole-v0": {},
    "goflow/Quadrotor-v0": {},
    "goflow/Ant-v0": {},
    "goflow/Anymal-v0": {},
    "goflow/Hopper-v0": {},
    "goflow/Walker2d-v0": {},
    "goflow/HalfCheetah-v0": {},
    "goflow/Humanoid-v0": {},
    "goflow/GearInsertion-v0 fast": {"variant": "fast"},
    "goflow/GearInsertion-v0 panda": {"variant": "panda"},
}


def actions_for(name: str, space: gymnasium.spaces.Box, n: int, rng: np.random.Generator) -> np.ndarray:
    """The workload: uniform random actions, except for gear insertion, where the tool pushes
    down while wandering a little (the gear is on or in its shaft most of the episode, as when a
    policy inserts; uniform actions would mostly fly it around in free space)."""
    a = rng.uniform(space.low, space.high, size=(n, *space.shape))
    if name.startswith("goflow/GearInsertion"):
        a[:, :2] *= 0.3
        a[:, 2] = -1.0
    return a


def _env_id(name: str) -> str:
    return name.split(" ")[0]


def make_nominal(name: str, kwargs: dict) -> gymnasium.Env:
    """The env with a NoDR sampler: every episode at the nominal xi, so that single-process,
    vectorized and bare runs do the same physics."""
    env = gymnasium.make(_env_id(name), **kwargs)
    env.unwrapped.sampler = NoDR(env.unwrapped.space)
    return env


def single(name: str, kwargs: dict, steps: int, seed: int) -> tuple[float, float]:
    """(steps per second, real-time factor) of env.step in this process, random actions."""
    env = make_nominal(name, kwargs).unwrapped
    wall = step_seconds(env, name, steps, seed)
    return steps / wall, steps * env.control_dt / wall


def step_seconds(env: gymnasium.Env, name: str, steps: int, seed: int) -> float:
    """Wall seconds spent in `steps` calls of env.step (resets on episode ends not counted)."""
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    wall = 0.0
    for action in actions_for(name, env.action_space, steps, rng):
        t0 = time.perf_counter()
        _, _, terminated, truncated, _ = env.step(action)
        wall += time.perf_counter() - t0
        if terminated or truncated:
            env.reset(seed=int(rng.integers(1 << 31)))
    return wall


def mujoco_speed(name: str, steps: int, seed: int) -> float | None:
    """Steps per second of gymnasium's MuJoCo original of `name` (None: no original, or no
    `mujoco` package), the same action workload as `single`."""
    from assembly.envs.mujoco_reference import ORIGINALS, reference_env
    from goflow_common.errors import InputError

    if _env_id(name) not in ORIGINALS:
        return None
    try:
        env = reference_env(_env_id(name))
    except InputError:
        return None
    return steps / step_seconds(env, name, steps, seed)


def vectorized(name: str, kwargs: dict, steps: int, workers: int, seed: int) -> float:
    """Steps per second (summed over envs) of an AsyncVectorEnv with `workers` processes."""
    vec = gymnasium.vector.AsyncVectorEnv([lambda: make_nominal(name, kwargs) for _ in range(workers)])
    vec.reset(seed=seed)
    n = max(steps // workers, 1)
    rng = np.random.default_rng(seed)
    actions = np.stack([actions_for(name, vec.single_action_space, n, rng) for _ in range(workers)], 1)
    t0 = time.perf_counter()
    for a in actions:
        vec.step(a)
    wall = time.perf_counter() - t0
    vec.close()
    return n * workers / wall


def overhead(name: str, kwargs: dict, steps: int, seed: int) -> float | None:
    """env.step time / bare_rollout time - 1, over the same xi and actions (None if no bare)."""
    env = make_nominal(name, kwargs).unwrapped
    if not hasattr(env, "bare_rollout"):
        return None
    rng = np.random.default_rng(seed)
    n = min(steps, env.max_episode_steps or steps)
    actions = actions_for(name, env.action_space, n, rng)
    xi = env.space.nominal()
    best_env, best_bare = np.inf, np.inf
    for _ in range(3):  # best of three: the machine is shared and noisy
        env.reset(seed=seed, options={"xi": xi})
        t0 = time.perf_counter()
        for a in actions:
            env.step(a)
        best_env = min(best_env, time.perf_counter() - t0)
        t0 = time.perf_counter()
        env.bare_rollout(xi, actions)
        best_bare = min(best_bare, time.perf_counter() - t0)
    return best_env / best_bare - 1.0


def sync_speed(env_id: str, kwargs: dict, n: int, steps: int, seed: int) -> float:
    """Env steps/s (summed over envs) of a SyncVectorEnv of n single envs at the nominal xi."""
    vec = gymnasium.vector.SyncVectorEnv(
        [lambda: make_nominal(env_id, kwargs) for _ in range(n)],
        autoreset_mode=gymnasium.vector.AutoresetMode.SAME_STEP,
    )
    return _vector_speed(vec, env_id, steps, seed)


def _vector_speed(vec, env_id: str, steps: int, seed: int) -> float:
    vec.reset(seed=seed)
    rng = np.random.default_rng(seed)
    rounds = max(steps // vec.num_envs, 20)
    actions = np.stack([actions_for(env_id, vec.single_action_space, vec.num_envs, rng) for _ in range(rounds)])
    t0 = time.perf_counter()
    for a in actions:
        vec.step(a)
    wall = time.perf_counter() - t0
    vec.close()
    return rounds * vec.num_envs / wall


def batched_speed(env_id: str, kwargs: dict, n: int, steps: int, seed: int) -> tuple[float, float]:
    """(env steps/s, share of the step's wall time inside Simulator.AdvanceTo) of the batched env
    with n copies at the nominal xi."""
    import importlib

    vec = gymnasium.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", **kwargs)
    vec.set_attr("sampler", NoDR(vec.space))
    import assembly.envs.drake_sim as drake_sim

    modules = [m for m in (drake_sim, importlib.import_module(type(vec).__module__)) if hasattr(m, "advance")]
    inner, spent = drake_sim.advance, [0.0]

    def timed(*args):
        t0 = time.perf_counter()
        try:
            return inner(*args)
        finally:
            spent[0] += time.perf_counter() - t0

    for module in modules:
        module.advance = timed
    try:
        t0 = time.perf_counter()
        rate = _vector_speed(vec, env_id, steps, seed)
        wall = time.perf_counter() - t0
    finally:
        for module in modules:
            module.advance = inner
    return rate, spent[0] / wall


def mujoco_rollout_speed(env_id: str, n: int, steps: int, seed: int) -> float | None:
    """Env steps/s of gymnasium's MuJoCo original of env_id through `mujoco.rollout` (n initial
    states, random controls, one thread); None without an original or the `mujoco` package."""
    from assembly.envs.mujoco_reference import ORIGINALS, reference_env
    from goflow_common.errors import InputError

    if env_id not in ORIGINALS:
        return None
    try:
        env = reference_env(env_id).unwrapped
        import mujoco
        from mujoco import rollout
    except (InputError, ImportError):
        return None
    model, data = env.model, env.data
    kind = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.empty(mujoco.mj_stateSize(model, kind))
    mujoco.mj_getState(model, data, state, kind)
    rounds = max(steps // n, 20)
    rng = np.random.default_rng(seed)
    control = rng.uniform(-1.0, 1.0, size=(n, rounds * env.frame_skip, model.nu))
    t0 = time.perf_counter()
    rollout.rollout(model, data, np.tile(state, (n, 1)), control)
    return n * rounds / (time.perf_counter() - t0)


def batched_table(copies: list[int], steps: int, seed: int, only: list[str] | None) -> list[dict]:
    """Print and return the --batched table (see the module docstring)."""
    from assembly.envs import VECTOR_ENVS

    header = (
        f"{'env':<26} {'sync x16':>9} "
        + " ".join(f"{f'N={n}':>8} {'x':>5}" for n in copies)
        + f" {'AdvanceTo':>9} {'MuJoCo':>8} {f'rollout N={copies[-1]}':>14}"
    )
    print(header)
    print("-" * len(header))
    rows = []
    for env_id in VECTOR_ENVS:
        name = next((k for k in ENVS if _env_id(k) == env_id), env_id)
        if only and name not in only and env_id not in only:
            continue
        kwargs = ENVS.get(name, {})
        today = sync_speed(env_id, kwargs, 16, steps, seed)
        row = {"env": env_id, "sync16_steps_per_s": today, "batched": {}}
        cells = []
        for n in copies:
            rate, share = batched_speed(env_id, kwargs, n, max(steps, 4 * n), seed)
            row["batched"][str(n)] = {"steps_per_s": rate, "ratio_to_sync16": rate / today, "advance_share": share}
            cells.append(f"{rate:>8.0f} {rate / today:>5.1f}")
        mj = mujoco_speed(name, steps, seed)
        mj_roll = mujoco_rollout_speed(env_id, copies[-1], max(steps, 4 * copies[-1]), seed)
        row.update(mujoco_steps_per_s=mj, mujoco_rollout_steps_per_s=mj_roll)
        share = row["batched"][str(copies[-1])]["advance_share"]
        print(
            f"{env_id:<26} {today:>9.0f} " + " ".join(cells) + f" {100 * share:>8.0f}%"
            f" {'n/a' if mj is None else f'{mj:.0f}':>8} {'n/a' if mj_roll is None else f'{mj_roll:.0f}':>14}",
            flush=True,
        )
        rows.append(row)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--only", nargs="*", help="names from ENVS to run")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--batched", action="store_true", help="the batched vector envs' table instead")
    parser.add_argument(
        "--copies", type=int, nargs="+", default=[1, 16, 64, 256], help="copies N of the batched envs (with --batched)"
    )
    args = parser.parse_args()
    if args.json:
        check_output_file(args.json)
    if args.batched:
        if any(n < 1 for n in args.copies):
            parser.error(f"--copies {args.copies}: expected whole numbers >= 1")
        rows = batched_table(args.copies, args.steps, args.seed, args.only)
        if args.json:
            write_json(
                args.json,
                {
                    "command": "benchmarks/env_speed.py --batched",
                    "copies": args.copies,
                    "steps": args.steps,
                    "rows": rows,
                },
            )
        return
    rows = []
    header = (
        f"{'env':<32} {'steps/s':>9} {'RTF':>7} {f'steps/s x{args.workers}':>12} {'overhead':>9} {'MuJoCo steps/s':>15}"
    )
    print(header)
    print("-" * len(header))
    for name, kwargs in ENVS.items():
        if args.only and name not in args.only:
            continue
        steps = args.steps if "panda" not in name else max(args.steps // 4, 25)
        try:
            sps, rtf = single(name, kwargs, steps, args.seed)
        except (ImportError, ModuleNotFoundError) as exc:
            print(f"{name:<32} not available: {exc}")
            continue
        vps = vectorized(name, kwargs, steps, args.workers, args.seed)
        ovh = overhead(name, kwargs, steps, args.seed)
        mj = mujoco_speed(name, steps, args.seed)
        rows.append(
            {
                "env": name,
                "steps_per_s": sps,
                "real_time_factor": rtf,
                "vector_workers": args.workers,
                "vector_steps_per_s": vps,
                "wrapper_overhead": ovh,
                "mujoco_steps_per_s": mj,
            }
        )
        ovh_text = "n/a" if ovh is None else f"{100 * ovh:.1f}%"
        mj_text = "n/a" if mj is None else f"{mj:.1f}"
        print(f"{name:<32} {sps:>9.1f} {rtf:>7.1f} {vps:>12.1f} {ovh_text:>9} {mj_text:>15}", flush=True)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        write_json(args.json, {"rows": rows})


if __name__ == "__main__":
    main()
