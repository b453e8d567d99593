"""Step-from-state simulators: they reproduce their environments' steps, batch over xi, split
across processes, and refuse bad input."""

from __future__ import annotations

import numpy as np
import pytest

from assembly.transition_sim import ParallelTransitionSim, make_transition_sim


def test_cartpole_step_matches_the_env():
    from assembly.envs.cartpole import CartpoleEnv

    env = CartpoleEnv()
    xi = np.array([3.0, 7.0, 0.4])
    env.reset(seed=1, options={"xi": xi})
    s0 = env.plant_state
    env.step(np.array([0.6], dtype=np.float32))
    sim = make_transition_sim("goflow/Cartpole-v0")
    nxt = sim.step(s0[None], [[0.6]], xi[None])[0]
    np.testing.assert_allclose(nxt, env.plant_state, atol=1e-9)
    # batched over xi: heavier pole, different next state; rows independent of their order
    batch = sim.step(np.tile(s0, (3, 1)), [[0.6]] * 3, [[3.0, 7.0, 0.4], [15.0, 7.0, 0.4], [3.0, 7.0, 0.4]])
    np.testing.assert_allclose(batch[0], nxt, atol=1e-9)
    np.testing.assert_allclose(batch[2], nxt, atol=1e-9)
    assert np.abs(batch[1] - nxt).max() > 1e-4


def test_ant_step_matches_the_env_at_nominal_damping():
    from assembly.envs.ant import AntEnv

    env = AntEnv()
    env.reset(seed=2, options={"xi": [4.0]})
    s0 = env.state()
    a = np.linspace(-1, 1, 8).astype(np.float32).astype(np.float64)  # what the env receives
    env.step(a.astype(np.float32))
    sim = make_transition_sim("goflow/Ant-v0")
    nxt = sim.step(s0[None], a[None], [[4.0, 0.1]])[0]
    np.testing.assert_allclose(nxt, env.state(), atol=1e-9)
    damped = sim.step(s0[None], a[None], [[4.0, 2.0]])[0]
    assert np.abs(damped - nxt).max() > 1e-4
    assert sim.observe(s0).shape == env.observation_space.shape


def test_panda_arm_parameters_change_the_motion():
    sim = make_transition_sim("goflow/PandaArm-v0")
    rng = np.random.default_rng(0)
    s0 = sim.initial_state(sim.space.nominal(), rng)
    s0[7:] = 0.5  # moving joints: damping and friction act
    a = np.full((1, 7), 0.3)
    base = sim.step(s0[None], a, sim.space.nominal()[None])[0]
    assert np.all(np.isfinite(base)) and base.shape == (14,)
    for k in range(sim.space.dim):
        xi = sim.space.nominal().copy()
        xi[k] = sim.space.high[k]
        moved = sim.step(s0[None], a, xi[None])[0]
        assert np.abs(moved - base).max() > 1e-6, f"{sim.space.names[k]} has no effect"


def test_bad_batches_are_refused_and_parallel_matches_serial():
    sim = make_transition_sim("goflow/PointMass-v0")
    with pytest.raises(ValueError, match=r"xi has shape \(2, 3\), expected \(2, 2\)"):
        sim.step(np.zeros((2, 2)), np.zeros((2, 1)), np.ones((2, 3)))
    with pytest.raises(ValueError, match="parameter 'mass' = 9 kg is outside its bounds"):
        sim.step(np.zeros((1, 2)), np.zeros((1, 1)), [[9.0, 1.0]])
    with pytest.raises(ValueError, match="no step-from-state simulator for env 'x'"):
        make_transition_sim("x")
    rng = np.random.default_rng(0)
    s, a = rng.normal(size=(40, 2)), rng.uniform(-1, 1, (40, 1))
    xi = sim.space.denormalize(rng.uniform(size=(40, 2)))
    par = ParallelTransitionSim("goflow/PointMass-v0", workers=2)
    try:
        np.testing.assert_array_equal(par.step(s, a, xi), sim.step(s, a, xi))
    finally:
        par.close()
