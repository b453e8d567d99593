"""Transition simulators (assembly/transition/): they reproduce their environments' steps, batch
over xi without changing any row, turn a failed row into NaN, split across processes, and refuse
bad input."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from assembly.params import Param, ParamSpace
from assembly.transition import (
    TRANSITION_SIMS,
    BatchTransitionSim,
    ParallelTransitionSim,
    TransitionSim,
    make_transition_sim,
    register_transition_sim,
    xi_groups,
)
from goflow_common.errors import SimulationError, UnknownOptionError

IDS = sorted(TRANSITION_SIMS)
DRAKE_IDS = [i for i in IDS if i != "goflow/PointMass-v0"]


@pytest.fixture(scope="module")
def sims():
    """One simulator per registered id, built on first use."""
    cache = {}

    def get(env_id):
        if env_id not in cache:
            cache[env_id] = make_transition_sim(env_id)
        return cache[env_id]

    return get


def _batch(sim, n, rng):
    """n rows from the sim's own initial states (speeds perturbed), random actions, random xi."""
    xi = sim.space.denormalize(rng.uniform(size=(n, sim.space.dim)))
    states = np.stack([sim.initial_state(x, rng) for x in xi])
    states = states + 0.05 * rng.normal(size=states.shape)
    actions = np.stack([sim.random_action(rng) for _ in range(n)])
    return states, actions, xi


# -- the registry ---------------------------------------------------------------------------------


def test_registry_is_data_and_every_id_keeps_the_contract(sims):
    assert all(isinstance(v, str) and v.count(":") == 1 for v in TRANSITION_SIMS.values())
    for env_id in IDS:
        sim = sims(env_id)
        assert isinstance(sim, TransitionSim) and sim.env_id == env_id
        assert sim.random_action(np.random.default_rng(0)).shape == (sim.action_dim,)
        s0 = sim.initial_state(sim.space.nominal(), np.random.default_rng(0))
        assert s0.shape == (sim.state_dim,) and sim.observe(s0).dtype == np.float32
    unknown = r"no step-from-state simulator for env 'x'; known: \[.*PandaArm"
    with pytest.raises(UnknownOptionError, match=unknown):
        make_transition_sim("x")
    with pytest.raises(ValueError, match="already registered"):
        register_transition_sim("goflow/PointMass-v0", TRANSITION_SIMS["goflow/PointMass-v0"])
    with pytest.raises(ValueError, match="expected 'module:Class'"):
        register_transition_sim("goflow/New-v0", "assembly.transition.point_mass")


def test_importing_the_package_imports_no_drake():
    code = "import sys, assembly.transition; assert 'pydrake' not in sys.modules, 'pydrake'"
    subprocess.run([sys.executable, "-c", code], check=True)


# -- the batch loop -------------------------------------------------------------------------------


def test_xi_groups_cover_every_row_once_with_equal_xi():
    xi = np.array([[2.0, 1.0], [1.0, 3.0], [2.0, 1.0], [1.0, 2.0], [1.0, 3.0]])
    groups = xi_groups(xi)
    assert sorted(np.concatenate(groups).tolist()) == list(range(5))
    assert [sorted(g.tolist()) for g in groups] == [[3], [1, 4], [0, 2]]
    assert xi_groups(np.zeros((0, 2))) == []


@pytest.mark.parametrize("env_id", IDS)
def test_grouping_does_not_change_any_row(sims, env_id):
    sim = sims(env_id)
    rng = np.random.default_rng(3)
    states, actions, xi = _batch(sim, 9, rng)
    xi[[2, 5, 7]] = xi[0]  # repeated parameters (distinct states and actions)
    xi[8] = xi[4]
    order = rng.permutation(9)
    states, actions, xi = states[order], actions[order], xi[order]
    batch = sim.step(states, actions, xi)
    assert np.all(np.isfinite(batch))
    for i in range(9):
        alone = sim.step(states[i : i + 1], actions[i : i + 1], xi[i : i + 1])[0]
        np.testing.assert_array_equal(batch[i], alone, err_msg=f"{env_id} row {i}")


@pytest.mark.parametrize("env_id", DRAKE_IDS)
def test_a_failing_row_is_nan_and_the_others_are_finite(sims, env_id):
    sim = sims(env_id)
    rng = np.random.default_rng(4)
    states, actions, xi = _batch(sim, 4, rng)
    nq = sim._plant.num_positions()
    states[1, nq:] = 1e150  # absurd speeds: Drake fails or diverges
    out = sim.step(states, actions, xi)
    assert np.all(np.isnan(out[1]))
    assert np.all(np.isfinite(np.delete(out, 1, axis=0)))


class _Toy(BatchTransitionSim):
    """x' = x + a for xi = (k,); k > 0.9 raises, k in (0.8, 0.9] gives inf (failure paths)."""

    env_id, state_dim, action_dim, control_dt = "toy", 1, 1, 1.0
    space = ParamSpace((Param("k", 0.0, 1.0, "1"),))

    def __init__(self):
        self.applied = []

    def _apply_xi(self, xi):
        self.applied.append(float(xi[0]))

    def _set_state(self, state):
        self._x = float(state[0])

    def _apply_action(self, state, action):
        self._a = float(action[0])

    def _advance(self):
        if self.applied[-1] > 0.9:
            raise SimulationError("toy: diverged")
        self._x = np.inf if self.applied[-1] > 0.8 else self._x + self._a

    def _read_state(self):
        return np.array([self._x])


def test_the_loop_applies_xi_once_per_group_and_returns_nan_rows_on_failure():
    sim = _Toy()
    xi = [[0.5], [0.95], [0.5], [0.85], [0.1]]
    out = sim.step([[1.0], [2.0], [3.0], [4.0], [5.0]], [[1.0]] * 5, xi)
    np.testing.assert_array_equal(out[:, 0], [2.0, np.nan, 4.0, np.nan, 6.0])
    assert sim.applied == [0.1, 0.5, 0.85, 0.95]


# -- the models -----------------------------------------------------------------------------------


def test_cartpole_step_matches_the_env(sims):
    from assembly.envs.cartpole import CartpoleEnv

    env = CartpoleEnv()
    xi = np.array([3.0, 7.0, 0.4])
    env.reset(seed=1, options={"xi": xi})
    s0 = env.plant_state
    env.step(np.array([0.6], dtype=np.float32))
    sim = sims("goflow/Cartpole-v0")
    nxt = sim.step(s0[None], [[0.6]], xi[None])[0]
    np.testing.assert_allclose(nxt, env.plant_state, atol=1e-9)
    # batched over xi: heavier pole, different next state; rows independent of their order
    xis = [[3.0, 7.0, 0.4], [15.0, 7.0, 0.4], [3.0, 7.0, 0.4]]
    batch = sim.step(np.tile(s0, (3, 1)), [[0.6]] * 3, xis)
    np.testing.assert_allclose(batch[0], nxt, atol=1e-9)
    np.testing.assert_allclose(batch[2], nxt, atol=1e-9)
    assert np.abs(batch[1] - nxt).max() > 1e-4


def test_ant_step_matches_the_env_at_nominal_damping(sims):
    from assembly.envs.ant import AntEnv

    env = AntEnv()
    env.reset(seed=2, options={"xi": [4.0]})
    s0 = env.state()
    a = np.linspace(-1, 1, 8).astype(np.float32).astype(np.float64)  # what the env receives
    env.step(a.astype(np.float32))
    sim = sims("goflow/Ant-v0")
    nxt = sim.step(s0[None], a[None], [[4.0, 0.1]])[0]
    np.testing.assert_allclose(nxt, env.state(), atol=1e-9)
    damped = sim.step(s0[None], a[None], [[4.0, 2.0]])[0]
    assert np.abs(damped - nxt).max() > 1e-4
    assert sim.observe(s0).shape == env.observation_space.shape


LOCOMOTION = {
    "goflow/Hopper-v0": "HopperEnv",
    "goflow/Walker2d-v0": "Walker2dEnv",
    "goflow/HalfCheetah-v0": "HalfCheetahEnv",
    "goflow/Humanoid-v0": "HumanoidEnv",
}


@pytest.mark.parametrize("env_id", sorted(LOCOMOTION))
def test_locomotion_step_matches_the_env_and_every_parameter_acts(sims, env_id):
    from assembly.envs import locomotion

    sim = sims(env_id)
    env = getattr(locomotion, LOCOMOTION[env_id])(terminate_when_unhealthy=False)
    rng = np.random.default_rng(5)
    xi = sim.space.denormalize(rng.uniform(0.2, 0.8, size=sim.space.dim))
    env.reset(seed=2, options={"xi": xi})
    for _ in range(30):  # into contact, joints off their limits (the Humanoid's knees start on them)
        env.step(sim.ctrl(rng.uniform(-1, 1, sim.action_dim)))
    s0, a = env.plant_state, rng.uniform(-1, 1, sim.action_dim)
    obs = env.step(sim.ctrl(a))[0]
    nxt = sim.step(s0[None], a[None], xi[None])[0]
    np.testing.assert_array_equal(nxt, env.plant_state)
    assert sim.observe(nxt).shape == obs.shape == env.observation_space.shape
    for k, name in enumerate(sim.space.names):
        moved = xi.copy()
        moved[k] = sim.space.high[k]
        assert np.abs(sim.step(s0[None], a[None], moved[None])[0] - nxt).max() > 1e-8, f"{name} has no effect"
    np.testing.assert_allclose(sim.ctrl([-1.0] * sim.action_dim), env.action_space.low, rtol=1e-6)
    np.testing.assert_allclose(sim.ctrl([2.0] * sim.action_dim), env.action_space.high, rtol=1e-6)


def test_panda_arm_parameters_change_the_motion(sims):
    sim = sims("goflow/PandaArm-v0")
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


# -- input checks and processes -------------------------------------------------------------------


def test_bad_batches_are_refused_and_parallel_matches_serial(sims):
    sim = sims("goflow/PointMass-v0")
    with pytest.raises(ValueError, match=r"xi has shape \(2, 3\), expected \(2, 2\)"):
        sim.step(np.zeros((2, 2)), np.zeros((2, 1)), np.ones((2, 3)))
    with pytest.raises(ValueError, match="parameter 'mass' = 9 kg is outside its bounds"):
        sim.step(np.zeros((1, 2)), np.zeros((1, 1)), [[9.0, 1.0]])
    with pytest.raises(ValueError, match="states must be finite"):
        sim.step([[np.nan, 0.0]], np.zeros((1, 1)), [[1.0, 1.0]])
    rng = np.random.default_rng(0)
    s, a = rng.normal(size=(40, 2)), rng.uniform(-1, 1, (40, 1))
    xi = sim.space.denormalize(rng.uniform(size=(40, 2)))
    par = ParallelTransitionSim("goflow/PointMass-v0", workers=2)
    try:
        np.testing.assert_array_equal(par.step(s, a, xi), sim.step(s, a, xi))
    finally:
        par.close()


def test_quadrotor_step_matches_the_env_and_the_mass_acts(sims):
    from assembly.envs.quadrotor import QuadrotorEnv

    sim, env, rng = sims("goflow/Quadrotor-v0"), QuadrotorEnv(), np.random.default_rng(6)
    xi = np.array([0.6])
    env.reset(seed=1, options={"xi": xi})
    for _ in range(20):  # off the ground, turning
        env.step(rng.uniform(-1, 1, 4).astype(np.float32))
    s0, a = np.concatenate([env.plant_state, env.goal]), rng.uniform(-1, 1, 4).astype(np.float32)
    obs = env.step(a)[0]
    nxt = sim.step(s0[None], a[None].astype(np.float64), xi[None])[0]
    np.testing.assert_allclose(nxt[:13], env.plant_state, atol=1e-9)
    np.testing.assert_array_equal(nxt[13:], env.goal)  # the goal rides along
    np.testing.assert_allclose(sim.observe(nxt), obs, atol=1e-6)
    assert np.abs(sim.step(s0[None], a[None], [[5.0]])[0] - nxt).max() > 1e-4
    spinning = s0.copy()
    spinning[7:10] = 1e4  # beyond max_angular_rate: the env's episode would end there
    assert np.all(np.isnan(sim.step(spinning[None], a[None], xi[None])[0]))


def test_anymal_step_matches_the_env_and_every_parameter_acts(sims):
    from assembly.envs.anymal import AnymalEnv

    sim, env, rng = sims("goflow/Anymal-v0"), AnymalEnv(), np.random.default_rng(7)
    xi = np.array([30.0, 0.05, 0.02, 0.03, 0.08])
    env.reset(seed=1, options={"xi": xi})
    for _ in range(20):  # feet loaded, hips moving: the friction of a step depends on the last loads
        env.step(rng.uniform(-1, 1, 12).astype(np.float32))
    s0 = np.concatenate([env.state(), env._haa_load, env._action])
    a = rng.uniform(-1, 1, 12).astype(np.float32).astype(np.float64)
    obs = env.step(a.astype(np.float32))[0]
    nxt = sim.step(s0[None], a[None], xi[None])[0]
    np.testing.assert_allclose(nxt[:37], env.state(), atol=1e-9)
    np.testing.assert_allclose(nxt[37:41], env._haa_load, atol=1e-9)
    np.testing.assert_array_equal(nxt[41:], a)
    np.testing.assert_allclose(sim.observe(nxt), obs, atol=1e-6)
    for k, name in enumerate(sim.space.names):
        moved = xi.copy()
        moved[k] = sim.space.high[k]
        assert np.abs(sim.step(s0[None], a[None], moved[None])[0][:37] - nxt[:37]).max() > 1e-8, f"{name} has no effect"


def test_gear_insertion_step_matches_the_env_and_every_parameter_acts(sims):
    from assembly.envs.gear_insertion import GearInsertionEnv
    from assembly.transition.gear_insertion import GearInsertionTransitionSim
    from goflow_common.errors import InputError

    sim, env, rng = sims("goflow/GearInsertion-v0"), GearInsertionEnv(), np.random.default_rng(8)
    xi = np.array([0.001, -0.002, 0.1])
    env.reset(seed=1, options={"xi": xi})
    plant = env.sim.model.plant
    plant_context = plant.GetMyContextFromRoot(env.sim.context)

    def push():  # down onto the shaft, wandering sideways: the gear in contact, its history full
        return np.r_[rng.uniform(-1, 1, 2), -1.0, rng.uniform(-1, 1)].astype(np.float32)

    for _ in range(30):
        env.step(push())
    assert env.insertion_error()[0] < 0.005  # on the shaft, where the grasp error acts through contact
    s0, a = np.concatenate([plant.GetPositionsAndVelocities(plant_context), env._history.poses[1:].ravel()]), push()
    obs = env.step(a)[0]
    nxt = sim.step(s0[None], a[None].astype(np.float64), xi[None])[0]
    assert nxt.shape == (44,) and sim.state_dim == 44
    np.testing.assert_allclose(nxt[:8], plant.GetPositionsAndVelocities(plant_context), atol=1e-12)
    np.testing.assert_array_equal(nxt[8:], env._history.poses[1:].ravel())  # the history rides along
    np.testing.assert_array_equal(sim.observe(nxt), obs)
    first = sim.initial_state(xi, np.random.default_rng(0))
    np.testing.assert_array_equal(sim.observe(first), env.reset(options={"xi": xi})[0])
    for k, name in enumerate(sim.space.names):
        moved = xi.copy()
        moved[k] = sim.space.high[k]
        assert np.abs(sim.step(s0[None], a[None], moved[None])[0][:8] - nxt[:8]).max() > 1e-8, f"{name} has no effect"
    jump = s0.copy()
    jump[8:12] += 0.5  # the last pose 0.5 m away: a velocity beyond the observation's bounds ends the env's episode
    assert np.all(np.isnan(sim.step(jump[None], a[None], xi[None])[0]))
    with pytest.raises(InputError, match="variant 'panda'; expected 'fast'"):
        GearInsertionTransitionSim(variant="panda")
