"""The catalogue's effects for torque-only logs (q, dq, tau): regressor, base parameters, recoveries."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from assembly.panda_model import Q_MAX, Q_MIN
from sim2real.arm import ArmModel
from sim2real.effects import Candidate, candidates, untestable
from sim2real.inertia import base_parameters, link_regressor
from sim2real.reality import RealityConfig, make_arm_log
from sim2real.replay import Replay, replay

CONFIG = RealityConfig(duration=4.0, end_effector="none")


def _torque_only(effects: dict) -> Replay:
    log = make_arm_log(effects, CONFIG)
    return replay(dataclasses.replace(log, tau_cmd=None, q_cmd=None, dq_cmd=None))


def _fit(rep: Replay, cand: Candidate) -> tuple[np.ndarray, float]:
    """Direct least squares of the candidate to the "tau" residual on the valid samples: (coef, sse)."""
    m = rep.valid
    y = rep.residual["tau"][m] - (cand.offset["tau"][m] if "tau" in cand.offset else 0.0)
    if not cand.n_coef:
        return np.zeros(0), float(np.sum(y**2))
    X = cand.features["tau"][m].reshape(-1, cand.n_coef)
    coef, *_ = np.linalg.lstsq(X, y.ravel(), rcond=None)
    return coef, float(np.sum((y.ravel() - X @ coef) ** 2))


def test_the_regressor_reproduces_drakes_inverse_dynamics():
    rng = np.random.default_rng(1)
    q = rng.uniform(Q_MIN, Q_MAX, (40, 7))
    dq, ddq = rng.normal(size=(40, 7)), 3.0 * rng.normal(size=(40, 7))
    reg = link_regressor("none")
    rigid = ArmModel("none").terms(q, dq, ddq).rigid
    np.testing.assert_allclose(reg(q, dq, ddq) @ reg.nominal, rigid, atol=1e-9)


def test_the_base_parameters_of_a_fixed_base_7r_arm():
    """44 by the QR's numerical rank (a gap of 1e15 in |R_ii|); the literature reports about 43
    for the Panda without friction (Gaz et al. 2019). Link 1 keeps only Izz1-grouped terms."""
    bp = base_parameters("none")
    assert bp.count == 44
    assert bp.groups[0].startswith("Izz1")
    assert not any(g.split()[0] in ("m1", "mx1", "my1", "mz1", "Ixx1", "Iyy1") for g in bp.groups)
    reg = link_regressor("none")
    rng = np.random.default_rng(2)
    q = rng.uniform(Q_MIN, Q_MAX, (30, 7))
    Y = reg(q, rng.normal(size=(30, 7)), rng.normal(size=(30, 7)))
    pi = rng.normal(size=70)  # any parameters: the base regressor times the base parameters is Y pi
    np.testing.assert_allclose(Y[..., list(bp.independent)] @ bp.nominal(pi), Y @ pi, atol=1e-9)


def _link_parameters(mass_scale, shift, inertia_scale) -> np.ndarray:
    """The standard parameters (70,) of the links as the simulated reality changes them."""
    pi = link_regressor("none").nominal.copy().reshape(7, 10)
    out = np.zeros_like(pi)
    for k, p in enumerate(pi):
        m, c = p[0], p[1:4] / p[0]
        I_o = np.array([[p[4], p[7], p[8]], [p[7], p[5], p[9]], [p[8], p[9], p[6]]])
        I_c = I_o - m * (c @ c * np.eye(3) - np.outer(c, c))
        m2, c2 = m * mass_scale[k], c + np.array([0, 0, shift[k]])
        I2 = I_c * mass_scale[k] * inertia_scale[k] + m2 * (c2 @ c2 * np.eye(3) - np.outer(c2, c2))
        out[k] = [m2, *(m2 * c2), I2[0, 0], I2[1, 1], I2[2, 2], I2[0, 1], I2[0, 2], I2[1, 2]]
    return out.ravel()


def test_link_inertia_is_recovered_through_the_base_parameters():
    """Link 4 30 % heavier, link 5's centre of mass 2 cm along z, link 6's inertia 40 % larger: the
    fitted base corrections predict the true ones' torque within 5 %, and the base parameters
    that move most are found within 10 % of their largest change."""
    setting = {
        "mass_scale": [1, 1, 1, 1.3, 1, 1, 1],
        "com_shift": [0, 0, 0, 0, 0.02, 0, 0],
        "inertia_scale": [1, 1, 1, 1, 1, 1.4, 1],
    }
    rep = _torque_only({"link_inertia": setting})
    (cand,) = candidates(rep, ["link_inertia"])["link_inertia"]
    coef, sse = _fit(rep, cand)
    bp = base_parameters("none")
    nominal = link_regressor("none").nominal
    truth = bp.nominal(
        _link_parameters(setting["mass_scale"], setting["com_shift"], setting["inertia_scale"]) - nominal
    )
    assert (np.abs(truth) <= cand.bounds[:, 1]).all()  # the truth is within the fit's bounds
    X = cand.features["tau"][rep.valid]
    true_torque, fit_torque = X @ truth, X @ coef
    assert np.sqrt(np.mean((fit_torque - true_torque) ** 2)) < 0.05 * np.sqrt(np.mean(true_torque**2))
    big = np.abs(truth) > 0.2 * np.abs(truth).max()
    np.testing.assert_allclose(coef[big], truth[big], atol=0.1 * np.abs(truth).max())
    assert cand.to_params(coef)["base"] == pytest.approx(list(coef))


def test_torque_scale_is_recovered():
    k = [1.1, 0.9, 1.05, 1.1, 0.95, 1.15, 0.9]
    rep = _torque_only({"torque_scale": {"k": k}})
    (cand,) = candidates(rep, ["torque_scale"])["torque_scale"]
    coef, _ = _fit(rep, cand)
    np.testing.assert_allclose(cand.to_params(coef)["k"], k, atol=0.005)


def test_joint_inertia_is_recovered():
    dJ = [0.2, 0.3, 0.1, 0.2, 0.05, 0.05, 0.02]
    rep = _torque_only({"joint_inertia": {"dJ": dJ}})
    (cand,) = candidates(rep, ["joint_inertia"])["joint_inertia"]
    coef, _ = _fit(rep, cand)
    np.testing.assert_allclose(cand.to_params(coef)["dJ"], dJ, atol=0.005)


def test_torque_delay_is_recovered():
    """8 ms: the grid's nearest member, then a golden-section search within its bracket, to 0.5 ms."""
    rep = _torque_only({"torque_delay": {"d": 0.008}})
    cands = candidates(rep, ["torque_delay"])["torque_delay"]
    best = min(cands, key=lambda c: _fit(rep, c)[1])
    lo, hi = best.family.bracket(best.setting["d"])
    g = (np.sqrt(5) - 1) / 2
    for _ in range(20):
        a, b = hi - g * (hi - lo), lo + g * (hi - lo)
        if _fit(rep, best.family.at(a))[1] < _fit(rep, best.family.at(b))[1]:
            hi = b
        else:
            lo = a
    assert 0.5 * (lo + hi) == pytest.approx(0.008, abs=5e-4)


def test_backlash_motor_logs_the_motor_side_and_is_fitted_only_there():
    log = make_arm_log({"backlash_motor": {"b": 0.01}}, CONFIG)
    assert log.meta["position_side"] == "motor"
    link = make_arm_log({"backlash": {"b": 0.01}}, CONFIG)
    assert link.meta["position_side"] == "link"
    assert np.abs(log.q - link.q).max() > 1e-3  # the motor's position, not the link's
    rep = replay(dataclasses.replace(log, tau_cmd=None, q_cmd=None, dq_cmd=None))
    assert "backlash_motor" in candidates(rep)
    rep_link = replay(dataclasses.replace(link, tau_cmd=None, q_cmd=None, dq_cmd=None))
    assert "backlash_motor" not in candidates(rep_link)


@pytest.mark.parametrize("noise", [True, False])
def test_backlash_motor_is_recovered(noise):
    """b = 10 mrad behind a motor-side encoder: the family's best member by a direct least-squares
    fit to the "tau" residual lies within 30 % of it, so do the per-joint widths of the joints that
    carry most of the predicted torque, and the fit removes at least half the residual's sum of
    squares; on a nominal log read as motor-side it removes next to nothing."""
    log = make_arm_log({"backlash_motor": {"b": 0.01}}, dataclasses.replace(CONFIG, noise=noise))
    rep = replay(dataclasses.replace(log, tau_cmd=None, q_cmd=None, dq_cmd=None))
    cands = candidates(rep, ["backlash_motor"])["backlash_motor"]
    fits = [_fit(rep, c) for c in cands]
    i = int(np.argmin([sse for _, sse in fits]))
    best, (coef, sse) = cands[i], fits[i]
    assert best.setting["b"] == pytest.approx(0.01, rel=0.3)
    share = np.sum((best.features["tau"][rep.valid] * coef) ** 2, axis=(0, 1))
    share /= share.sum()
    widths = np.asarray(best.to_params(coef)["b"])
    assert share[np.abs(widths / 0.01 - 1.0) <= 0.3].sum() > 0.8, (widths, share)
    assert sse < 0.5 * np.sum(rep.residual["tau"][rep.valid] ** 2)

    nominal = make_arm_log({}, CONFIG)
    nominal = dataclasses.replace(
        nominal, tau_cmd=None, q_cmd=None, dq_cmd=None, meta={**nominal.meta, "position_side": "motor"}
    )
    rep = replay(nominal)
    sse0 = np.sum(rep.residual["tau"][rep.valid] ** 2)
    for cand in candidates(rep, ["backlash_motor"])["backlash_motor"]:
        assert _fit(rep, cand)[1] > 0.98 * sse0


def test_untestable_lists_the_command_effects_of_a_torque_only_log():
    rep = _torque_only({})
    out = untestable(rep)
    for name in (
        "actuation_delay",
        "torque_saturation",
        "backlash",
        "torque_gain",
        "rotor_inertia",
        "controller_gain",
        "backlash_motor",
    ):
        assert name in out, out
    assert "tau_cmd" in out["torque_gain"]
    pool = candidates(rep)
    assert not set(pool) & set(out)
    assert {"link_inertia", "torque_scale", "torque_delay", "joint_inertia", "torque_offset"} <= set(pool)
