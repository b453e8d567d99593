"""Where a cheap env's wrapper overhead goes: the same per-step work timed alone and between
`AdvanceTo` calls, and `AdvanceTo` timed with and without that work around it.

    .venv/bin/python benchmarks/step_interference.py [--env goflow/Quadrotor-v0] [--reps 21]

Prints one table (microseconds per control step, best of --reps episodes).
"""

from __future__ import annotations

import argparse
import time
import timeit

import gymnasium
import numpy as np

import assembly  # noqa: F401  (registers the ids)
import assembly.envs.drake_sim as drake_sim


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="goflow/Quadrotor-v0", choices=["goflow/Quadrotor-v0", "goflow/Cartpole-v0"])
    parser.add_argument("--reps", type=int, default=21)
    args = parser.parse_args()
    env = gymnasium.make(args.env).unwrapped
    xi = env.space.nominal()
    n = env.max_episode_steps
    actions = np.random.default_rng(0).uniform(-1.0, 1.0, size=(n, *env.action_space.shape))
    env_module = __import__(type(env).__module__, fromlist=["advance"])
    original = drake_sim.advance
    advance_time = [0.0]

    def timed_advance(simulator, t, owner):
        t0 = time.perf_counter()
        original(simulator, t, owner)
        advance_time[0] += time.perf_counter() - t0

    def patch(fn) -> None:  # the env's steps and bare_rollout both call `advance`
        env_module.advance = drake_sim.advance = fn

    def best(body) -> tuple[float, float]:
        """(us per step for body, us per step inside AdvanceTo), best of reps."""
        total, inside = np.inf, np.inf
        for _ in range(args.reps):
            env.reset(seed=0, options={"xi": xi})
            advance_time[0] = 0.0
            t0 = time.perf_counter()
            body()
            total = min(total, time.perf_counter() - t0)
            inside = min(inside, advance_time[0])
        return 1e6 * total / n, 1e6 * inside / n

    def bare() -> None:
        env.bare_rollout(xi, actions, initial_state=env.plant_state)

    def steps() -> None:
        for a in actions:
            env.step(a)

    try:
        patch(timed_advance)
        bare_total, bare_adv = best(bare)
        step_total, step_adv = best(steps)
        patch(lambda simulator, t, owner: None)  # the wrapper's own work, with no physics between
        env.reset(seed=0, options={"xi": xi})
        work = min(timeit.repeat(lambda: env.step(actions[0]), number=n - 1, repeat=1)) / (n - 1) * 1e6
    finally:
        patch(original)
    print(f"{args.env}: microseconds per control step (best of {args.reps} episodes of {n} steps)")
    print(f"{'':46} {'total':>8} {'in AdvanceTo':>13} {'outside':>8}")
    print(f"{'bare simulator loop':46} {bare_total:8.1f} {bare_adv:13.1f} {bare_total - bare_adv:8.1f}")
    print(f"{'env.step':46} {step_total:8.1f} {step_adv:13.1f} {step_total - step_adv:8.1f}")
    print(f"{'env.step with AdvanceTo removed (work alone)':46} {work:8.1f} {'-':>13} {work:8.1f}")
    print(f"wrapper overhead {100 * (step_total / bare_total - 1):.1f} %: AdvanceTo {step_adv - bare_adv:+.1f} us, "
          f"work outside it {step_total - step_adv - (bare_total - bare_adv):+.1f} us (alone: {work:.1f} us)")

if __name__ == "__main__":
    main()
