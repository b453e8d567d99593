"""How much of the Cartpole box can be balanced at all: the success rate on the uniform box of
controllers that know each episode's parameters xi, a ceiling-side reference for the learned policies.

    .venv/bin/python -m benchmarks.cartpole_oracle [--episodes 1000] [--seed 0] [--json PATH]

Each episode draws xi uniformly on the box and the start as `goflow/Cartpole-v0` does (pole angle
uniform in +-45 deg), exactly like a validation episode, and is run by every controller of a
family; it counts as a success if any of them reaches J_T. The family: LQR on the cart-pole
linearized about upright with this xi's masses (the pole's inertia as the env builds it, the
slider's viscous damping), saturated at the 100 N actuator, for three control weights, with and
without Coulomb friction compensation (mu (m_pole + m_cart) g added in the direction of the LQR
force). Where that friction bound reaches the actuator limit the cart cannot be moved and the episode
is counted a failure without simulating it.

This is a lower bound on what any policy could reach (a better controller might save more), and the
learned policies see only the observation, not xi.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import scipy.linalg

from assembly.envs.cartpole import CARTPOLE_SPACE, CartpoleEnv
from assembly.samplers import FullDR
from goflow_common.files import write_json

GRAVITY = 9.81  # [m/s^2]
CONTROL_WEIGHTS = (1e-4, 1e-3, 1e-2)  # R [1/N^2] against Q = diag(1, 100, 1, 1) on (x, theta, xdot, thetadot)


def lqr_gain(env: CartpoleEnv, pole_mass: float, cart_mass: float, control_weight: float) -> np.ndarray:
    """State-feedback gain K (force = -K s, s = (x, theta, xdot, thetadot)) of the linearized cart-pole."""
    cfg = env.config
    l = cfg.pole_com
    # the env keeps the pole's unit inertia (its body is built at 1 kg, origin at the pivot) and
    # scales it by the mass: the pitch moment about the pivot [kg m^2], read from the env's model
    inertia = pole_mass * env._pole.default_rotational_inertia().get_moments()[1]
    mass_matrix_inv = np.linalg.inv(np.array([[pole_mass + cart_mass, pole_mass * l], [pole_mass * l, inertia]]))
    a = np.zeros((4, 4))
    a[0, 2] = a[1, 3] = 1.0
    a[2:, :] = mass_matrix_inv @ np.array(
        [[0.0, 0.0, -cfg.slider_damping, 0.0], [0.0, pole_mass * GRAVITY * l, 0.0, 0.0]]
    )
    b = np.zeros((4, 1))
    b[2:, 0] = mass_matrix_inv @ np.array([1.0, 0.0])
    q, r = np.diag([1.0, 100.0, 1.0, 1.0]), np.array([[control_weight]])
    p = scipy.linalg.solve_continuous_are(a, b, q, r)
    return np.linalg.solve(r, b.T @ p)[0]


def run_episode(env: CartpoleEnv, xi: np.ndarray, seed: int, control_weight: float, compensate: bool) -> float:
    """Undiscounted return of one episode under the saturated LQR for this xi."""
    gain = lqr_gain(env, xi[0], xi[1], control_weight)
    friction = xi[2] * (xi[0] + xi[1]) * GRAVITY if compensate else 0.0
    obs, _ = env.reset(seed=seed, options={"xi": xi})
    total, done = 0.0, False
    while not done:
        x, xdot, cos_t, sin_t, thetadot = (float(v) for v in obs)
        force = -float(gain @ np.array([x, math.atan2(sin_t, cos_t), xdot, thetadot]))
        force += friction * math.tanh(force / 5.0)
        action = np.array([np.clip(force / env.config.max_force, -1.0, 1.0)], dtype=np.float32)
        obs, reward, terminated, truncated, _ = env.step(action)
        total += float(reward)
        done = terminated or truncated
    return total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    if args.episodes < 1:
        raise SystemExit(f"--episodes must be >= 1, got {args.episodes}")
    env = CartpoleEnv()
    rng = np.random.default_rng(args.seed)
    xis = FullDR(CARTPOLE_SPACE).sample(args.episodes, rng)
    friction_force = xis[:, 2] * (xis[:, 0] + xis[:, 1]) * GRAVITY
    immovable = friction_force >= env.config.max_force
    controllers = [(w, c) for w in CONTROL_WEIGHTS for c in (False, True)]
    returns = np.full((args.episodes, len(controllers)), -np.inf)
    for i in map(int, np.flatnonzero(~immovable)):
        for j, (weight, compensate) in enumerate(controllers):
            returns[i, j] = run_episode(env, xis[i], args.seed * 1_000_003 + i, weight, compensate)
    threshold = env.config.success_threshold
    success = (returns >= threshold).any(axis=1)
    n = args.episodes
    rows = [("any controller", success)] + [
        (f"R = {w:g}, {'with' if c else 'without'} friction compensation", returns[:, j] >= threshold)
        for j, (w, c) in enumerate(controllers)
    ]
    print(
        f"goflow/Cartpole-v0, {n} uniform episodes (seed {args.seed}); cart immovable "
        f"(mu (m_pole + m_cart) g >= {env.config.max_force:g} N) on {immovable.mean():.3f} of the box"
    )
    print(f"{'controller':52} {'success on the box':>20}")
    for name, ok in rows:
        print(f"{name:52} {ok.mean():>11.3f} +- {ok.std(ddof=1) / math.sqrt(n):.3f}")
    bands = [(0.0, 20.0), (20.0, 50.0), (50.0, 100.0), (100.0, math.inf)]
    print("by friction bound mu (m_pole + m_cart) g [N]:")
    by_band = []
    for lo, hi in bands:
        m = (friction_force >= lo) & (friction_force < hi)
        by_band.append(
            {
                "low_N": lo,
                "high_N": hi,
                "share_of_box": float(m.mean()),
                "success": float(success[m].mean()) if m.any() else None,
            }
        )
        print(
            f"  [{lo:g}, {hi:g}): {m.mean():.3f} of the box, success {success[m].mean() if m.any() else float('nan'):.3f}"
        )
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        write_json(
            args.json,
            {
                "env": "goflow/Cartpole-v0",
                "episodes": n,
                "seed": args.seed,
                "success_threshold": threshold,
                "success_any": float(success.mean()),
                "success_any_se": float(success.std(ddof=1) / math.sqrt(n)),
                "immovable_share": float(immovable.mean()),
                "controllers": {name: float(ok.mean()) for name, ok in rows[1:]},
                "by_friction_bound": by_band,
            },
        )


if __name__ == "__main__":
    main()
