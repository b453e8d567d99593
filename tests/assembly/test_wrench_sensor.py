"""The insertion skill's force sensing (assembly.wrench_sensor): the estimate's noise and bias have
the stated size as they reach the tool, a gear pressed onto its shaft reads the push in both
variants, env and law agree on the history, and bad sensor settings are named."""

import numpy as np
import pytest

from assembly.envs.gear_insertion import GearInsertionEnv
from assembly.insertion_law import InsertionLaw, PoseHistory
from assembly.panda_ik import panda_jacobian_at
from assembly.wrench_sensor import (
    IDEAL_WRENCH,
    PANDA_WRENCH,
    WrenchSensor,
    WrenchSensorModel,
    joint_torque_of,
    observed_wrench,
)
from assembly.envs.gear_insertion import seated_and_start, tool_down_pose, GearInsertionConfig
from assembly.station import build_station
from goflow_common.errors import InputError

PUSH = np.array([0.0, 0.0, -1.0, 0.0])  # straight down: the impedance presses K_z x 2 cm = 6 N


@pytest.fixture(scope="module")
def J():
    env = GearInsertionEnv(gear="medium", variant="fast")
    _, start = seated_and_start(env.config, env.sim.X_WS)
    env.close()
    return panda_jacobian_at(tool_down_pose(start[:3], start[3]))


def test_the_noise_reaches_the_tool_as_pinv_JT_maps_the_joint_noise_and_the_bias_holds_per_episode(J):
    sensor, rng = WrenchSensor(PANDA_WRENCH, control_dt=0.04), np.random.default_rng(0)
    sensor.reset(rng)
    samples = np.array([sensor.measure(np.zeros(7), J, rng) for _ in range(4000)])
    P = np.linalg.pinv(J.T)
    sigma = PANDA_WRENCH.noise_std_at(0.04)
    expected_std = observed_wrench(np.sqrt(np.diag(P @ np.diag(sigma**2) @ P.T)))
    np.testing.assert_allclose(samples.std(axis=0), expected_std, rtol=0.06)
    mean_error = samples.mean(axis=0) - observed_wrench(P @ sensor.bias)
    assert np.all(np.abs(mean_error) < 4 * expected_std / np.sqrt(len(samples))), mean_error
    # at the policy's 25 Hz the noise is the real log's 7.6 Hz floor widened to the 12.5 Hz band
    np.testing.assert_allclose(sigma / np.asarray(PANDA_WRENCH.noise_std), np.sqrt(12.5 / 7.6))
    bias = sensor.bias.copy()
    sensor.reset(rng)
    assert not np.allclose(bias, sensor.bias)
    # a true wrench comes through unchanged by an ideal sensor, through the arm's joints and back
    ideal = WrenchSensor(IDEAL_WRENCH, 0.04)
    f = np.array([1.0, -2.0, 6.0, 0.3])
    np.testing.assert_allclose(ideal.measure(joint_torque_of(J, f), J, rng), f, atol=1e-9)


@pytest.mark.parametrize("variant, tolerance", [("fast", 0.05), ("panda", 0.15)])
def test_a_gear_pressed_onto_its_shaft_reads_the_push(variant, tolerance):
    env = GearInsertionEnv(gear="medium", variant=variant, sensing="wrench", wrench_sensor="ideal")
    obs, _ = env.reset(seed=0, options={"xi": np.zeros(3)})
    np.testing.assert_allclose(obs[8:12], 0.0, atol=0.02)  # in the air: nothing but what the gear's contact
    for _ in range(30):
        obs, _, _, _, info = env.step(PUSH)
    assert info["seated"]
    fz = 10.0 * obs[10]  # the newest row's Fz, scaled back to N
    assert fz == pytest.approx(0.02 * 300.0, rel=tolerance), fz
    np.testing.assert_allclose(10.0 * obs[8:10], 0.0, atol=1.0)
    env.close()


def test_env_and_law_agree_on_a_history_with_the_wrench():
    env = GearInsertionEnv(gear="small", variant="fast", sensing="wrench", wrench_sensor="ideal")
    obs, _ = env.reset(seed=1, options={"xi": np.array([0.001, 0.0, 0.0])})
    outside = PoseHistory(env.law)
    outside.reset(env.tool_pose(), env.wrench())
    for _ in range(20):
        np.testing.assert_array_equal(obs, outside.observation())
        obs, *_ = env.step(PUSH)
        outside.push(env.tool_pose(), env.wrench())
    assert obs.shape == (120,) and env.observation_space.shape == (120,)
    env.close()


def test_the_station_exports_what_the_estimate_is_made_of():
    station = build_station()
    context = station.diagram.CreateDefaultContext()
    np.testing.assert_array_equal(station.diagram.GetOutputPort("tau_contact").Eval(context), np.zeros(7))
    J = station.diagram.GetOutputPort("tool_jacobian").Eval(context).reshape(6, 7)
    assert np.linalg.matrix_rank(J) == 6


def test_bad_sensor_settings_are_named():
    with pytest.raises(InputError, match="noise_std"):
        WrenchSensorModel("x", noise_std=(-0.1,) * 7)
    with pytest.raises(InputError, match="bias_std"):
        WrenchSensorModel("x", bias_std=(0.1,) * 6)
    with pytest.raises(InputError, match="noise_band"):
        WrenchSensorModel("x", noise_band=0.0)
    with pytest.raises(InputError, match="sensing"):
        GearInsertionConfig(sensing="force")
    with pytest.raises(InputError, match="wrench_sensor"):
        GearInsertionConfig(sensing="wrench", wrench_sensor="ati")
    law = InsertionLaw((0.5, 0.0, 0.1, 0.0), (1, 1, 1, 1), (1, 1, 1, 1), 10, 0.04, "wrench")
    with pytest.raises(InputError, match="needs the wrench"):
        PoseHistory(law).reset(law.seated)
    with pytest.raises(InputError, match="pose-only"):
        PoseHistory(InsertionLaw(law.seated, (1, 1, 1, 1), (1, 1, 1, 1), 10, 0.04)).reset(law.seated, np.zeros(4))
    with pytest.raises(ValueError, match="J"):
        WrenchSensor(IDEAL_WRENCH, 0.04).measure(np.zeros(7), np.zeros((6, 6)), np.random.default_rng(0))
