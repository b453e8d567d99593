"""goflow/Hopper-v0, Walker2d-v0, HalfCheetah-v0, Humanoid-v0: gymnasium's MuJoCo tasks on Drake
plants built from the same files, with the NFPDE paper's parameters as xi."""

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import assembly  # noqa: F401  (registers the ids)
from assembly.envs.mjcf import drake_coefficient, gymnasium_asset, read_mjcf
from goflow_common.errors import InputError

IDS = ["goflow/Hopper-v0", "goflow/Walker2d-v0", "goflow/HalfCheetah-v0", "goflow/Humanoid-v0"]
DIMS = {
    "goflow/Hopper-v0": (6, 11, 3),
    "goflow/Walker2d-v0": (7, 17, 6),
    "goflow/HalfCheetah-v0": (14, 17, 6),
    "goflow/Humanoid-v0": (30, 348, 17),
}


@pytest.fixture(scope="module", params=IDS)
def env(request):
    e = gymnasium.make(request.param).unwrapped
    yield e
    e.close()


def test_env_checker_passes(env):
    check_env(env, skip_render_check=True)


def test_dimensions_and_table_one_parameters(env):
    d, obs, act = DIMS[env.spec.id]
    assert env.space.dim == d
    assert env.observation_space.shape == (obs,) and env.action_space.shape == (act,)
    nominal = env.space.nominal()
    assert np.all(env.space.low < nominal) and np.all(nominal < env.space.high)
    masses = [n for n in env.space.names if n.endswith("_mass")]
    assert masses and all(u == "kg" for n, u in zip(env.space.names, env.space.units) if n in masses)


def test_info_contract_and_xi_in_the_plant(env):
    xi = env.space.nominal()
    xi[0] *= 1.5  # the first parameter is a mass in every task
    obs, info = env.reset(seed=3, options={"xi": xi})
    np.testing.assert_allclose(info["xi"], xi)
    assert info["critic_obs"].shape == (obs.size + env.space.dim,)
    body = env.model.bodies[0]
    assert body.get_mass(env._plant_context) == pytest.approx(xi[0])
    damping = [i for i, n in enumerate(env.space.names) if n.endswith("_damping")][0]
    joint = env._params[damping][2][0]
    assert joint.GetDamping(env._plant_context) == pytest.approx(xi[damping])


def test_same_seed_same_start_and_bad_xi_raise(env):
    a, _ = env.reset(seed=7)
    b, _ = env.reset(seed=7)
    np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="outside|shape"):
        env.reset(options={"xi": env.space.high * 1.01})
    with pytest.raises(ValueError, match="shape"):
        env.reset(options={"xi": np.ones(env.space.dim + 1)})
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        env.step(np.full(env.action_space.shape, np.nan))


def test_heavier_links_change_the_motion():
    env = gymnasium.make("goflow/Hopper-v0").unwrapped
    actions = np.random.default_rng(0).uniform(-1, 1, (12, 3))

    def run(xi):
        env.reset(seed=1, options={"xi": xi})
        for a in actions:
            obs, _, terminated, *_ = env.step(a)
            assert not terminated
        return obs

    light, heavy = env.space.nominal(), env.space.nominal()
    heavy[:4] *= 1.8
    assert np.abs(run(light) - run(heavy)).max() > 0.05
    np.testing.assert_allclose(run(light), run(light))  # deterministic


def test_friction_parameter_reaches_the_contact():
    env = gymnasium.make("goflow/HalfCheetah-v0").unwrapped
    i = env.space.names.index("floor_friction")
    xi = env.space.nominal()
    xi[i] = env.space.high[i]
    env.reset(seed=0, options={"xi": xi})
    query = env.model.scene_graph.get_query_output_port().Eval(env._sg_context)
    props = query.inspector().GetProximityProperties(env.model.geometry_ids["bfoot"])
    mu = props.GetProperty("material", "coulomb_friction").static_friction()
    assert mu == pytest.approx(drake_coefficient(xi[i]))


def test_healthy_termination_and_time_limit():
    hopper = gymnasium.make("goflow/Hopper-v0").unwrapped
    hopper.reset(seed=0)
    *_, terminated, truncated, _ = hopper.step(np.zeros(3))
    assert not terminated and not truncated
    qpos, qvel = hopper.mujoco_state()
    qpos[2] = 0.5  # torso pitched beyond +-0.2 rad: unhealthy
    hopper.set_mujoco_state(qpos, qvel)
    *_, terminated, truncated, info = hopper.step(np.zeros(3))
    assert terminated and not truncated and "episode_return" in info
    cheetah = gymnasium.make("goflow/HalfCheetah-v0", horizon=20).unwrapped
    cheetah.reset(seed=0)
    for _ in range(20):
        *_, terminated, truncated, info = cheetah.step(np.zeros(6))
    assert truncated and not terminated  # HalfCheetah never terminates; 20 steps is the limit


def test_parameter_subset_missing_file_and_unknown_names():
    env = gymnasium.make("goflow/Hopper-v0", params=["torso_mass", "leg_damping"]).unwrapped
    assert env.space.names == ("torso_mass", "leg_damping")
    env.reset(seed=0)
    with pytest.raises(InputError, match="unknown parameter.*'tail_mass'"):
        gymnasium.make("goflow/Hopper-v0", params=["tail_mass"])
    with pytest.raises(InputError, match="not found"):
        gymnasium.make("goflow/Hopper-v0", xml_file="/nonexistent/hopper.xml")
    with pytest.raises(InputError, match="nope.xml"):
        gymnasium_asset("nope.xml")
    with pytest.raises(InputError, match="frame_skip"):
        gymnasium.make("goflow/Hopper-v0", frame_skip=0)


def test_rebuilt_features_match_the_file():
    spec = read_mjcf(gymnasium_asset("half_cheetah.xml"))
    assert spec.total_mass == 14.0 and spec.timestep == 0.01
    assert spec.stiffness["bthigh"] == (240.0, 0.0)
    env = gymnasium.make("goflow/HalfCheetah-v0").unwrapped
    assert env.model.masses.sum() == pytest.approx(14.0)
    np.testing.assert_allclose(env.model.gear, [120, 90, 60, 120, 60, 30])
    walker = read_mjcf(gymnasium_asset("walker2d_v5.xml"))
    assert walker.geoms["foot_geom"]["conaffinity"] == 0  # robot geoms touch only the floor


@pytest.mark.parametrize("env_id", IDS)
def test_fidelity_against_mujoco_at_small_size(env_id):
    mujoco = pytest.importorskip("mujoco", reason="the `mujoco` extra is not installed")
    from assembly.envs.mujoco_reference import paired_rollout, reference_env

    ours = gymnasium.make(env_id).unwrapped
    ref = reference_env(env_id)
    m = ref.model
    np.testing.assert_allclose(ours.model.masses, m.body_mass[1:], rtol=1e-3)
    dofs = {n: i for i, n in enumerate(ours.model.spec.joints)}
    for name, (k, _) in ours.model.spec.stiffness.items():
        assert m.jnt_stiffness[dofs[name]] == pytest.approx(k)
    # Kinematics: at a random configuration every body sits where MuJoCo puts it (Drake's parser
    # alone composed a body's several joints wrongly).
    ref.reset(seed=2)
    ref.data.qpos[len(ref.data.qpos) - len(ours.model.joints) :] += np.random.default_rng(0).uniform(
        -0.3, 0.3, len(ours.model.joints)
    )
    mujoco.mj_forward(m, ref.data)
    plant, ctx = ours.model.plant, ours._plant_context
    plant.SetPositionsAndVelocities(ctx, ours.model.from_mujoco(ref.data.qpos, ref.data.qvel))
    for i, body in enumerate(ours.model.bodies):
        np.testing.assert_allclose(
            plant.EvalBodyPoseInWorld(ctx, body).translation(), ref.data.xpos[i + 1], atol=1e-9, err_msg=body.name()
        )
    if hasattr(ours, "com_quantities"):
        q = ours.com_quantities()
        np.testing.assert_allclose(q["cinert"], ref.data.cinert[1:], atol=1e-9)
        np.testing.assert_allclose(q["cvel"], ref.data.cvel[1:], atol=1e-9)
    # Lifted off the floor, zero action for 0.1 s: the multibody dynamics agree closely.
    ref.reset(seed=0)
    qpos, qvel = ref.data.qpos.copy(), ref.data.qvel.copy()
    qpos[2 if ours.model.free else 1] += 1.0
    ref.set_state(qpos, qvel)
    ours.reset(seed=0, options={"xi": ours.space.nominal()})
    ours.set_mujoco_state(qpos, qvel)
    zero = np.zeros(ours.action_space.shape)
    for _ in range(int(round(0.1 / ours.control_dt))):
        ref.step(zero)
        ours.step_physics(zero)
    assert np.abs(ours.mujoco_state()[0][1:] - ref.data.qpos[1:]).max() < 0.02
    # On the floor, with the same random actions, the first steps' rewards agree.
    actions = np.random.default_rng(0).uniform(ours.action_space.low, ours.action_space.high, (3, zero.size))
    rollout = paired_rollout(ours, ref, actions, seed=1)
    assert np.abs(rollout.reward_ours - rollout.reward_ref).max() < 0.5 + 0.05 * np.abs(rollout.reward_ref).max()
