"""The simulated arm reality: its trajectory, its nominal log, each effect's signature in the log,
and its errors (sim2real/reality.py, sim2real/trajectory.py)."""

from __future__ import annotations

import numpy as np
import pytest

from assembly.panda_model import Q_HOME, Q_MAX, Q_MIN, REFLECTED_INERTIA, TAU_MAX, V_MAX
from goflow_common.errors import InputError, SimulationError
from sim2real.arm import ArmModel
from sim2real.log import validate_log
from sim2real.reality import KD, KP, RealityConfig, _Plant, make_arm_log, resolve_effects
from sim2real.trajectory import exciting_trajectory

DURATION = 2.0  # [s] of every simulated log here
QUIET = RealityConfig(duration=DURATION, noise=False)
INNER = slice(5, -5)  # samples away from the ends (forward difference, start-up)


@pytest.fixture(scope="module")
def model() -> ArmModel:
    return ArmModel("hand")


@pytest.fixture(scope="module")
def nominal():
    return make_arm_log({}, QUIET)


def _ddq(log) -> np.ndarray:
    """The forward difference of the noise-free dq: tau at t_k is the torque held over
    [t_k, t_k+1), which that difference sees."""
    ddq = np.empty_like(log.dq)
    ddq[:-1] = np.diff(log.dq, axis=0) / np.diff(log.time)[:, None]
    ddq[-1] = ddq[-2]
    return ddq


def residual(log, model: ArmModel) -> tuple[np.ndarray, np.ndarray]:
    """The link-side torque tau minus the nominal model's link torque (without the rotor's
    reflected inertia, which sits before the sensor), and ddq."""
    ddq = _ddq(log)
    terms = model.terms(log.q, log.dq, ddq)
    return log.tau - (terms.total - terms.rotor), ddq


def command_residual(log, model: ArmModel) -> tuple[np.ndarray, np.ndarray]:
    """The command tau_cmd minus the nominal model's total torque (rotor inertia included)."""
    ddq = _ddq(log)
    return log.tau_cmd - model.terms(log.q, log.dq, ddq).total, ddq


def slope(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Per-joint least-squares slope of y on x (no intercept) over the inner samples."""
    x, y = x[INNER], y[INNER]
    return (x * y).sum(axis=0) / (x * x).sum(axis=0)


# ---------------------------------------------------------------------------------------------- trajectory


@pytest.mark.parametrize("duration", [20.0, 4.0])
def test_trajectory_starts_and_ends_at_rest_inside_the_limits(duration: float) -> None:
    traj = exciting_trajectory(duration, seed=3)
    t = np.arange(0.0, duration + 1e-9, 1e-3)
    q, dq, ddq = traj(t)
    for k in (0, -1):
        np.testing.assert_allclose(q[k], Q_HOME, atol=1e-9)
        np.testing.assert_allclose(dq[k], 0.0, atol=1e-9)
        np.testing.assert_allclose(ddq[k], 0.0, atol=1e-9)
    assert np.all(q >= Q_MIN + 0.2 - 1e-5) and np.all(q <= Q_MAX - 0.2 + 1e-5)
    assert np.all(np.abs(dq).max(axis=0) <= 0.65 * V_MAX * (1 + 1e-5))  # peaks found on a grid


def test_default_trajectory_excites_every_joint() -> None:
    traj = exciting_trajectory(20.0, seed=0)
    assert traj.period == pytest.approx(10.0)  # 0.1 Hz, two periods in 20 s
    _, dq, _ = traj(np.arange(0.0, 20.0, 1e-3))
    reversals = (np.diff(np.sign(dq[1:-1]), axis=0) != 0).sum(axis=0)
    assert np.all(reversals >= 8)
    speed = np.abs(dq).max(axis=0) / V_MAX
    assert np.all(speed >= 0.25) and np.sum(speed > 0.6) >= 5  # a range of speeds, most joints near 65 %


def test_trajectory_rejects_a_frequency_that_does_not_fit() -> None:
    with pytest.raises(InputError, match="base_frequency"):
        exciting_trajectory(4.0, seed=0, base_frequency=0.3)


# ---------------------------------------------------------------------------------------------- nominal log


def test_nominal_log_matches_the_nominal_model(nominal, model: ArmModel) -> None:
    log = validate_log(nominal)
    n = int(round(DURATION * 1000)) + 1
    assert log.time.shape == (n,) and log.tau.shape == (n, 7) and log.tau_cmd.shape == (n, 7)
    assert np.all(log.phase == 0)
    meta = log.meta
    assert meta["robot"] == "panda" and meta["end_effector"] == "hand" and meta["torque_side"] == "link"
    assert meta["controller"] == {**meta["controller"], "law": "computed_torque_pd", "kp": list(KP), "kd": list(KD)}
    assert meta["truth"] == {} and meta["reality"]["duration"] == DURATION and meta["notes"] == []
    r, _ = residual(log, model)
    assert np.sqrt((r[INNER] ** 2).mean(axis=0)).max() < 0.01  # [N m]: the simulation is the model
    assert np.abs(log.q_cmd - log.q).max() < 2e-3  # [rad]: the controller tracks
    rc, ddq = command_residual(log, model)
    assert np.sqrt((rc[INNER] ** 2).mean(axis=0)).max() < 0.01  # the command drives the rotor too
    # the link-side sensor: the command less what accelerates the rotor
    np.testing.assert_allclose(log.tau[:-1], (log.tau_cmd - REFLECTED_INERTIA * ddq)[:-1], atol=1e-9)


def test_noise_levels_and_seeds() -> None:
    cfg = RealityConfig(duration=1.0)
    log = make_arm_log(None, cfg)
    quiet = make_arm_log(None, RealityConfig(duration=1.0, noise=False))
    assert (log.tau - quiet.tau).std() == pytest.approx(cfg.tau_noise, rel=0.5)  # sensor noise + its motion
    again = make_arm_log({}, cfg)
    np.testing.assert_array_equal(log.tau, again.tau)
    other = make_arm_log({}, RealityConfig(duration=1.0, seed=1))
    assert np.abs(other.q_cmd - log.q_cmd).max() > 1e-3


# ---------------------------------------------------------------------------------------------- dynamics effects


def test_coulomb_friction_is_in_the_torque_residual(model: ArmModel) -> None:
    fc = [0.8, 1.0, 0.5, 0.9, 0.3, 0.4, 0.2]
    log = make_arm_log({"coulomb": {"fc": fc, "v_smooth": 0.02}}, QUIET)
    r, _ = residual(log, model)
    np.testing.assert_allclose(slope(np.tanh(log.dq / 0.02), r), fc, rtol=0.02)
    assert log.meta["truth"] == {"coulomb": {"fc": fc, "v_smooth": 0.02}}


def test_stiff_coulomb_and_stribeck_friction_stay_right(model: ArmModel) -> None:
    # fc / v_smooth = 1000 N m s/rad against joint inertias ~0.2 kg m^2: the implicit step holds
    log = make_arm_log({"coulomb": {"fc": 2.0, "v_smooth": 0.002}, "stribeck": {"fs": 1.0, "vs": 0.05}}, QUIET)
    r, _ = residual(log, model)
    shape = np.stack([np.tanh(log.dq / 0.002), np.exp(-((log.dq / 0.05) ** 2)) * np.tanh(log.dq / 0.002)], axis=-1)
    for j in range(7):
        coef, *_ = np.linalg.lstsq(shape[INNER, j], r[INNER, j], rcond=None)
        np.testing.assert_allclose(coef, [2.0, 1.0], atol=0.1)


def test_viscous_and_rotor_inertia(model: ArmModel) -> None:
    dI = [0.2, -0.2, 0.1, 0.1, -0.1, 0.05, -0.15]
    log = make_arm_log({"viscous": {"fv": 0.5}, "rotor_inertia": {"dI": dI}}, QUIET)
    r, ddq = command_residual(log, model)  # the rotor is before the sensor: the command sees it
    x = np.stack([log.dq, ddq], axis=-1)
    for j in range(7):
        coef, *_ = np.linalg.lstsq(x[INNER, j], r[INNER, j], rcond=None)
        np.testing.assert_allclose(coef, [0.5, dI[j]], atol=0.01)


def test_rotor_inertia_below_zero_is_clipped_with_a_note() -> None:
    log = make_arm_log({"rotor_inertia": {"dI": [-0.7, 0, 0, 0, 0, 0, 0]}}, RealityConfig(duration=0.5, noise=False))
    assert REFLECTED_INERTIA[0] - 0.7 < 0
    assert any("clipped" in note and "[1]" in note for note in log.meta["notes"])


def test_payload_adds_a_point_mass_at_the_flange(model: ArmModel) -> None:
    dm, com = 1.0, np.array([0.02, -0.01, 0.1])
    log = make_arm_log({"payload": {"dm": dm, "com_x": com[0], "com_y": com[1], "com_z": com[2]}}, QUIET)
    r, ddq = residual(log, model)
    J, w, alpha, a = model.flange_kinematics(log.q, log.dq, ddq)
    force = dm * (a + np.cross(alpha, com) + np.cross(w, np.cross(w, com)))
    wrench = np.concatenate([np.cross(com, force), force], axis=1)
    predicted = np.einsum("tki,tk->ti", J, wrench)
    assert np.abs(predicted[INNER]).max() > 3.0  # [N m]: the payload matters
    assert np.sqrt(((r - predicted)[INNER] ** 2).mean(axis=0)).max() < 0.01


# ---------------------------------------------------------------------------------- sensing, actuation, controller


def test_torque_offset_shifts_the_residual(model: ArmModel) -> None:
    offset = [0.5, -1.0, 0.0, 0.0, 0.2, 0.0, -0.3]
    log = make_arm_log({"torque_offset": {"offset": offset}}, QUIET)
    r, _ = residual(log, model)
    np.testing.assert_allclose(r[INNER].mean(axis=0), offset, atol=0.01)


def test_torque_gain_scales_the_delivered_torque(model: ArmModel) -> None:
    k = [0.7, 1.3, 1.0, 1.0, 0.8, 1.2, 0.6]
    log = make_arm_log({"torque_gain": {"k": k}}, QUIET)
    r, ddq = residual(log, model)
    np.testing.assert_allclose(log.tau[:-1], (k * log.tau_cmd - REFLECTED_INERTIA * ddq)[:-1], atol=1e-9)
    # invisible in "tau": the sensor reads the delivered torque
    assert np.sqrt((r[INNER] ** 2).mean(axis=0)).max() < 0.01


def test_torque_saturation_clips_the_delivered_torque() -> None:
    log = make_arm_log({"torque_saturation": {"s": 0.3}}, QUIET)
    delivered = (log.tau + REFLECTED_INERTIA * _ddq(log))[:-1]
    np.testing.assert_allclose(delivered, np.clip(log.tau_cmd, -0.3 * TAU_MAX, 0.3 * TAU_MAX)[:-1], atol=1e-9)
    assert np.any(np.abs(log.tau_cmd) > 0.3 * TAU_MAX)
    assert any("saturated" in note for note in log.meta["notes"])


def test_actuation_delay_lags_the_delivered_torque() -> None:
    log = make_arm_log({"actuation_delay": {"delay": 0.01}}, QUIET)
    delivered = log.tau + REFLECTED_INERTIA * _ddq(log)  # the link-side sensor plus the rotor's share
    a, b = np.diff(log.tau_cmd[:-1], axis=0), np.diff(delivered[:-1], axis=0)
    for j in range(7):
        xc = [a[: len(a) - lag, j] @ b[lag:, j] for lag in range(40)]
        assert abs(int(np.argmax(xc)) - 10) <= 1  # samples of 1 ms


def test_controller_gain_changes_the_law_not_the_stated_gains() -> None:
    kp_scale = np.array([2.0, 0.5, 1.0, 1.0, 1.5, 1.0, 3.0])
    log = make_arm_log({"controller_gain": {"kp_scale": kp_scale.tolist(), "kd_scale": 0.5}}, QUIET)
    assert log.meta["controller"]["kp"] == list(KP) and log.meta["controller"]["kd"] == list(KD)
    q_ref, dq_ref, ddq_ref = exciting_trajectory(DURATION, seed=0)(log.time)
    e, de = log.q_cmd - log.q, log.dq_cmd - log.dq
    law = ArmModel("hand").terms(q_ref, dq_ref, ddq_ref).total + np.array(KP) * e + np.array(KD) * de
    extra = (kp_scale - 1.0) * np.array(KP) * e + (0.5 - 1.0) * np.array(KD) * de
    np.testing.assert_allclose(log.tau_cmd - law, extra, atol=1e-9)


def test_backlash_shows_and_vanishes_at_zero(nominal, model: ArmModel) -> None:
    log = make_arm_log({"backlash": {"b": 0.005}}, QUIET)
    r, _ = command_residual(log, model)
    assert np.sqrt((r[INNER] ** 2).mean()) > 0.1  # the motor crossing the dead band: J_m (ddtheta - ddq)
    r_link, _ = residual(log, model)
    assert np.sqrt((r_link[INNER] ** 2).mean()) < 0.1 * np.sqrt((r[INNER] ** 2).mean())  # link side: hidden
    assert np.abs(log.q_cmd - log.q).max() < 0.05
    zero = make_arm_log({"backlash": {"b": 0.0}}, QUIET)
    np.testing.assert_array_equal(zero.tau, nominal.tau)


def test_backlash_transmission_is_the_one_the_fit_models() -> None:
    effects = pytest.importorskip("sim2real.effects")
    from sim2real import reality

    for name in ("BACKLASH_MOTOR_FRACTION", "BACKLASH_STIFFNESS", "BACKLASH_DAMPING", "STRIBECK_SIGN_VELOCITY"):
        assert getattr(effects, name) == getattr(reality, name), name


def test_an_extra_torque_acts_on_the_joints(model: ArmModel) -> None:
    def ripple(q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        return -0.5 * np.sin(2 * np.pi * 6.0 * q)

    log = make_arm_log({}, QUIET, extra_torque=ripple)
    r, _ = residual(log, model)
    np.testing.assert_allclose(slope(np.sin(2 * np.pi * 6.0 * log.q), r), 0.5, atol=0.02)
    assert log.meta["extra_torque"].endswith("ripple") and log.meta["truth"] == {}
    with pytest.raises(InputError, match="extra_torque"):
        make_arm_log({}, RealityConfig(duration=0.2), extra_torque=lambda q, dq: np.zeros(3))


# ---------------------------------------------------------------------------------------------- errors


@pytest.mark.parametrize(
    "effects, words",
    [
        ({"gear_wobble": {}}, "gear_wobble"),
        ({"shaft_friction": {"mu": 0.3}}, "shaft_friction"),
        ({"coulomb": {"fc": 7.0}}, "coulomb.fc"),
        ({"coulomb": {"fc": [0.1, 0.2]}}, "coulomb.fc"),
        ({"coulomb": {"mu": 0.1}}, "'mu'"),
        ({"actuation_delay": {"delay": [0.01] * 7}}, "actuation_delay.delay"),
        ({"payload": {"dm": -1.5}}, "payload dm = -1.5"),
        ({"payload": {"dm": -1.4, "com_z": 0.25}}, "payload dm = -1.4"),
    ],
)
def test_bad_effects_raise_input_errors_naming_them(effects, words: str) -> None:
    with pytest.raises(InputError, match=words):
        make_arm_log(effects, RealityConfig(duration=0.2, noise=False))


def test_resolve_effects_fills_the_catalogue_defaults() -> None:
    assert resolve_effects({"coulomb": {"fc": 0.5}}) == {"coulomb": {"fc": [0.5] * 7, "v_smooth": 0.02}}
    assert resolve_effects({"payload": {"dm": 1.0}}) == {
        "payload": {"dm": 1.0, "com_x": 0.0, "com_y": 0.0, "com_z": 0.0}
    }


@pytest.mark.parametrize(
    "fields, words",
    [
        ({"time_step": 3e-4}, "time_step"),
        ({"kp": (1.0, 2.0)}, "kp"),
        ({"end_effector": "gripper"}, "end_effector"),
        ({"duration": -1.0}, "duration"),
        ({"tau_noise": -0.1}, "tau_noise"),
    ],
)
def test_bad_config_raises(fields: dict, words: str) -> None:
    with pytest.raises(InputError, match=words):
        RealityConfig(**fields)


def test_a_failed_step_raises_a_simulation_error(monkeypatch: pytest.MonkeyPatch) -> None:
    def diverge(self, state, tau_a, h):
        return state[0], state[1] + np.nan

    monkeypatch.setattr(_Plant, "step", diverge)
    with pytest.raises(SimulationError, match=r"t = 0\.0010 s.*coulomb"):
        make_arm_log({"coulomb": {"fc": 0.5}}, RealityConfig(duration=0.2))
    monkeypatch.setattr(_Plant, "step", lambda self, state, tau_a, h: None)
    with pytest.raises(SimulationError, match=r"failed at t = 0\.0000 s.*viscous"):
        make_arm_log({"viscous": {"fv": 0.5}}, RealityConfig(duration=0.2))
