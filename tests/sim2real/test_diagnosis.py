"""The diagnosis on the easy logs of the simulated reality (white noise, uniform sampling, every
channel) whose truth is known: replay, the noise floor, each effect's fit, selection, the
unexplained verdict, localisation and the report/CLI. These logs' in-band torque noise (0.006 N m)
is below the simulated reality's own discretisation misfit (up to 0.008 N m), so they are judged
with every sample against the broadband floor (`EASY`: DiagnosisConfig(band=None), `--band none`);
tests/sim2real/test_realistic.py checks the default, banded diagnosis on realistic logs."""

from __future__ import annotations

import dataclasses
import functools
import json

import numpy as np
import pytest

from goflow_cli import main
from sim2real.diagnosis import DiagnosisConfig, diagnose, noise_floor
from sim2real.log import save_log
from sim2real.reality import RealityConfig, make_arm_log
from sim2real.replay import ReplayConfig, matched_kernel, replay, uniform
from sim2real.validation import MAGNITUDES, Case, ripple_torque, run_case

DURATION = 6.0
EASY = DiagnosisConfig(band=None)


@pytest.fixture(scope="module")
def nominal_log():
    return make_arm_log({}, RealityConfig(duration=DURATION, seed=3))


def test_nominal_log_is_at_the_noise_floor(nominal_log):
    """No gap, and the floor is calibrated: a log of the nominal model reads what noise alone
    gives (1 noise variance per torque column; the control law, reproduced to rounding, ~0)."""
    d = diagnose(nominal_log, EASY)
    assert d.verdict["label"] == "no gap", d.verdict
    assert d.verdict["heldout_before"] < 1.5
    assert d.selected == []
    v = d.verdict
    assert v["floor_level"] == pytest.approx(2 / 3, abs=0.01)  # tau, cmd at 1; ctrl at ~0
    assert abs(v["heldout_before"] - v["floor_level"]) < 0.03, v


@pytest.mark.parametrize("gap", ["delay 1 ms", "ripple 0.02 N m"])
def test_a_gap_under_the_sensor_noise_is_found_and_told_apart(gap):
    """Effects far under the 0.05 N m torque noise are still gaps: a 1 ms actuation delay is
    named, a 0.02 N m ripple no catalogue effect explains reads unexplained."""
    cfg = RealityConfig(duration=DURATION, seed=4)
    if gap.startswith("delay"):
        log = make_arm_log(Case("x", ("actuation_delay",), "faint", 4).settings(), cfg)
    else:
        log = make_arm_log({}, cfg, extra_torque=functools.partial(ripple_torque, amplitude=0.02))
    d = diagnose(log, EASY)
    if gap.startswith("delay"):
        assert d.verdict["label"] == "explained", d.verdict
        assert d.selected[0]["effect"] == "actuation_delay"
    else:
        assert d.verdict["label"] == "unexplained", d.verdict
        assert d.verdict["heldout_before"] > d.verdict["floor_level"] + 0.2


def test_noise_floor_reads_filtered_noise_whatever_its_spectrum():
    """Noise bluer than the kernel-smoothed white noise the fast-part estimate assumes (a
    Savitzky-Golay derivative's) reads at its level once its correlation length is known."""
    from scipy.signal import savgol_filter

    rng = np.random.default_rng(1)
    n, window = 20_000, 41
    kernel = matched_kernel(window)
    t = np.arange(n) * 1e-3
    sensor = np.convolve(rng.standard_normal(n), kernel, mode="same")
    derivative = savgol_filter(rng.standard_normal(n), window, 3, deriv=1)
    noise = sensor / sensor.std() + derivative / derivative.std()
    r = (np.sin(2 * np.pi * 0.4 * t) + noise)[:, None]
    valid = np.ones(n, dtype=bool)
    assumed = noise_floor(r, valid, kernel=kernel)[0]
    known = noise_floor(r, valid, kernel=kernel, reach=window + 2)[0]
    assert assumed > 1.1 * noise.std()  # the assumed spectrum reads too high
    assert known == pytest.approx(noise.std(), rel=0.06)


def test_noise_floor_recovers_white_noise_under_a_slow_signal():
    rng = np.random.default_rng(0)
    t = np.linspace(0, 10, 10_000)
    r = np.stack(
        [np.sin(2 * np.pi * 0.3 * t) + 0.05 * rng.standard_normal(len(t)), 0.2 * rng.standard_normal(len(t))], axis=1
    )
    floor = noise_floor(r, np.ones(len(t), dtype=bool))
    assert floor == pytest.approx([0.05, 0.2], rel=0.1)


def test_uniform_resamples_jittered_time(nominal_log):
    t = nominal_log.time.copy()
    t[1::2] += 0.0002  # jitter
    jittered = dataclasses.replace(nominal_log, time=t)
    out = uniform(jittered)
    assert np.allclose(np.diff(out.time), np.diff(out.time)[0])
    assert out.q.shape[1] == 7


def test_the_replay_has_the_channels_the_log_allows(nominal_log):
    rep = replay(nominal_log)
    assert set(rep.channels) == {"tau", "cmd", "ctrl"}
    state_only = dataclasses.replace(nominal_log, tau=None)
    assert "dq" in replay(state_only).channels


@pytest.mark.parametrize("hold", ["zoh", "sample"])
def test_matched_kernel_turns_the_periods_acceleration_into_the_replays(hold):
    """Smoothing each period's velocity change with the matched kernel gives exactly the replay's
    Savitzky-Golay acceleration: a torque and the motion it causes pass through one filter."""
    from scipy.ndimage import correlate1d
    from scipy.signal import savgol_filter

    rng = np.random.default_rng(0)
    dt, window = 1e-3, 41
    v = np.cumsum(rng.standard_normal(2000)) * 0.01
    ddq = savgol_filter(v, window, 3, deriv=1, delta=dt)
    a = np.zeros_like(v)
    if hold == "zoh":
        ddq = 0.5 * (ddq[:-1] + ddq[1:])
        a[:-1] = np.diff(v) / dt
        a = a[:-1]
    else:
        a[1:-1] = (v[2:] - v[:-2]) / (2 * dt)
    s = matched_kernel(window, hold)
    assert s.sum() == pytest.approx(1.0)
    inner = slice(window, len(a) - window)
    assert np.allclose(correlate1d(a, s, mode="nearest")[inner], ddq[inner], rtol=0, atol=1e-9 * np.abs(ddq).max())


def test_the_matched_filter_fits_backlash_with_its_compliant_mesh():
    """With the torques filtered like the acceleration (the default), a gear's impact across its
    dead band leaves no residual of its own, and the backlash candidate (the mesh simulated behind
    each joint) finds the band's width per joint and closes most of the gap, far more than the
    rigid model under raw torques does."""
    log = make_arm_log({"backlash": {"b": 0.01}}, RealityConfig(duration=DURATION, seed=1))
    plain = diagnose(log, DiagnosisConfig(replay=ReplayConfig(torque_filter="none"), band=None))
    matched = diagnose(log, EASY)
    assert [s["effect"] for s in matched.selected][:1] == ["backlash"], matched.selected
    widths = np.asarray(matched.selected[0]["params"]["b"]["value"])
    assert np.sum(np.abs(widths / 0.01 - 1.0) < 0.1) >= 4, widths
    closed = matched.how_far["closed_total"]
    assert closed > 0.6 and closed > plain.how_far["closed_total"] + 0.2, (closed, plain.how_far["closed_total"])
    with pytest.raises(ValueError, match="torque_filter"):
        replay(log, ReplayConfig(torque_filter="lowpass"))


@pytest.mark.parametrize("effect, key, truth", [("actuation_delay", "delay", 0.0055), ("coulomb", "v_smooth", 0.03)])
def test_a_setting_between_grid_values_is_refined(effect, key, truth):
    """A nonlinear setting between two of its grid's values (5.5 ms between 4 and 7; 0.03 rad/s
    between 0.02 and 0.04) is found by refining between the neighbours, not rounded to the grid."""
    params = {key: truth, **({"fc": 0.8} if effect == "coulomb" else {})}
    d = diagnose(make_arm_log({effect: params}, RealityConfig(duration=DURATION, seed=1)), EASY)
    assert [s["effect"] for s in d.selected][:1] == [effect], d.selected
    assert d.selected[0]["setting"][key] == pytest.approx(truth, rel=0.05)
    assert d.how_far["closed_total"] > 0.9


def test_the_mesh_search_holds_its_memory_budget(monkeypatch):
    """The compliant-mesh backlash search in chunks (a long log) finds what it finds in one pass."""
    from sim2real import effects

    log = make_arm_log({"backlash": {"b": 0.004}}, RealityConfig(duration=2.0, seed=2))
    rep = replay(log, ReplayConfig(torque_filter="matched"))
    whole = effects.candidates(rep, ["backlash"])["backlash"][0]
    monkeypatch.setattr(effects, "_MESH_BYTES", 8 * 7 * log.n_samples * 5)  # five widths at a time
    chunked = effects.candidates(rep, ["backlash"])["backlash"][0]
    assert chunked.to_params(np.zeros(0)) == whole.to_params(np.zeros(0))
    np.testing.assert_allclose(chunked.offset["cmd"], whole.offset["cmd"], atol=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("effect", sorted(MAGNITUDES))
def test_leave_one_effect_out_names_the_effect(effect):
    """The small-size leave-one-effect-out: each catalogue effect at its larger magnitude, the
    diagnosis not told which, names it first and closes most of the gap."""
    result = run_case(Case(f"{effect}-large", (effect,), "large", seed=1), duration=DURATION, config=EASY)
    assert result["selected"][:1] == [effect], result
    assert result["located"], result
    assert result["closed"] > 0.5, result


def test_an_effect_active_in_a_few_blocks_is_significant():
    """A saturation the trajectory reaches on one joint in a few stretches only (s = 0.4 on
    seed 0's 10 s log) closes the gap there and is selected: its held-out gain's interval does
    not depend on resamples that happen to leave those blocks out."""
    case = Case("torque_saturation-small", ("torque_saturation",), "small", seed=0)
    result = run_case(case, duration=10.0, config=EASY)
    assert result["selected"][:1] == ["torque_saturation"], result
    assert result["closed"] > 0.9, result


def test_an_effect_that_never_acts_is_scored_as_no_gap():
    """A saturation at 60 % of the torque limit that seed 0's trajectory never reaches leaves
    the nominal log: the validation scores "no gap" as right there, not as a miss."""
    result = run_case(
        Case("torque_saturation-faint", ("torque_saturation",), "faint", seed=0), duration=DURATION, config=EASY
    )
    assert result["verdict"] == "no gap" and not result["active"], result
    assert result["top1"] and result["closed"] is None


def test_fitted_values_match_the_truth():
    log = make_arm_log(
        {"coulomb": {"fc": [0.8] * 7}, "torque_offset": {"offset": [0.0, 0.5, 0, 0, 0, 0, -0.3]}},
        RealityConfig(duration=DURATION, seed=2),
    )
    d = diagnose(log, EASY)
    fitted = {s["effect"]: s["params"] for s in d.selected}
    assert set(fitted) >= {"coulomb", "torque_offset"}
    fc = np.asarray(fitted["coulomb"]["fc"]["value"])
    assert np.allclose(fc, 0.8, atol=0.15), fc
    off = np.asarray(fitted["torque_offset"]["offset"]["value"])
    assert off[1] == pytest.approx(0.5, abs=0.1) and off[6] == pytest.approx(-0.3, abs=0.1)
    assert d.verdict["label"] == "explained"


def test_an_effect_outside_the_catalogue_is_unexplained():
    log = make_arm_log({}, RealityConfig(duration=DURATION, seed=4), extra_torque=ripple_torque)
    d = diagnose(log, EASY)
    assert d.verdict["label"] == "unexplained", d.verdict


def test_diagnosis_config_rejects_bad_values():
    with pytest.raises(ValueError, match="effects"):
        DiagnosisConfig(effects=("friction",))
    with pytest.raises(ValueError, match="blocks"):
        DiagnosisConfig(blocks=21, folds=5)


def test_cli_diagnose_writes_the_report(tmp_path, nominal_log, capsys):
    log = make_arm_log({"viscous": {"fv": [0.6] * 7}}, RealityConfig(duration=DURATION, seed=5))
    path = save_log(log, tmp_path / "log.npz")
    out = tmp_path / "report"
    assert main(["diagnose", "--log", str(path), "--out-dir", str(out), "--band", "none"]) == 0
    assert {"report.md", "report.json", "where.png", "ranking.png", "before_after.png", "residual_vs_velocity.png"} <= {
        p.name for p in out.iterdir()
    }
    report = json.loads((out / "report.json").read_text())
    assert report["selected"][0]["effect"] == "viscous"
    assert "viscous" in (out / "report.md").read_text()


def test_cli_make_log_then_diagnose_csv(tmp_path, capsys):
    csv = tmp_path / "log.csv"
    assert (
        main(
            ["sim2real", "make-log", "--effect", "torque_offset=0.6", "--model-kwarg", "duration=5", "--out", str(csv)]
        )
        == 0
    )
    assert main(["diagnose", "--log", str(csv), "--out-dir", str(tmp_path / "r"), "--band", "none"]) == 0
    report = json.loads((tmp_path / "r" / "report.json").read_text())
    assert report["selected"][0]["effect"] == "torque_offset"


def test_cli_bad_input_is_one_line(tmp_path, capsys):
    assert main(["diagnose", "--log", str(tmp_path / "missing.npz"), "--out-dir", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip()
    assert "missing.npz" in err and len(err.splitlines()) == 1
    assert main(["sim2real", "make-log", "--effect", "coulomb=9", "--out", str(tmp_path / "x.npz")]) == 2
    err = capsys.readouterr().err.strip()
    assert "coulomb=9" in err and "[0, 5]" in err
    assert not (tmp_path / "x.npz").exists()
    assert main(["sim2real", "make-log", "--effect", "friction=1", "--out", str(tmp_path / "x.npz")]) == 2
    assert "friction" in capsys.readouterr().err
    assert (
        main(["diagnose", "--log", str(tmp_path / "missing.npz"), "--out-dir", str(tmp_path / "r"), "--band", "x"]) == 2
    )
    assert "--band = 'x'" in capsys.readouterr().err


def test_a_state_log_is_diagnosed_by_forward_replay():
    """Without measured or commanded torques, the reference and the control law's gains drive the
    k-step forward replay ("dq" channel) and still name the effect."""
    log = make_arm_log({"coulomb": {"fc": [1.0] * 7}}, RealityConfig(duration=DURATION, seed=6))
    state = dataclasses.replace(log, tau=None, tau_cmd=None)
    d = diagnose(state, EASY)
    assert d.channels == ("dq",)
    assert [s["effect"] for s in d.selected][:1] == ["coulomb"]
