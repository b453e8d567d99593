"""Replay a log against the nominal arm model: the residual channels the diagnosis works on.

A channel is one signal compared with what the model predicts for it, per joint:
- "tau": the measured joint torque against inverse dynamics at the logged motion (torque logs);
  a link-side torque (Franka's tau_J, the default) holds no reflected rotor inertia;
- "cmd": the commanded torque against the same inverse dynamics (actuation effects show here);
- "ctrl": the commanded torque against the control law in meta["controller"] evaluated at the
  logged reference and state (controller effects show here);
- "dq": k-step forward replay for state logs: from each logged state the model integrates the
  commanded torque for k samples (re-synchronised to the log every k samples) and the predicted
  velocity is compared with the logged one.
Accelerations come from a Savitzky-Golay derivative of the logged velocity on a uniform grid.
The measured and commanded torques are smoothed with the kernel that derivative implies ("parallel
filtering", as in robot identification): a torque and the velocity change it causes are seen through
the same filter, so that a sharp event (a gear's impact across its backlash) leaves no residual of
its own; `Replay.smooth` applies the kernel to an effect's predicted torque the same way.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import correlate1d
from scipy.signal import savgol_coeffs, savgol_filter

from goflow_common.checks import check_choice
from goflow_common.errors import InputError
from sim2real.arm import ArmModel, ArmTerms
from sim2real.clean import resample
from sim2real.log import RobotLog

__all__ = ["ReplayConfig", "Replay", "replay", "uniform", "matched_kernel", "CHANNELS"]

CHANNELS: tuple[str, ...] = ("tau", "cmd", "ctrl", "dq")


@dataclasses.dataclass(frozen=True)
class ReplayConfig:
    """derivative_window: Savitzky-Golay window [s] for ddq (cubic); forward_steps: k of the
    k-step forward replay; end_effector: override of the log's meta["end_effector"];
    rotor_in_tau: whether the measured torque includes the reflected rotor inertia's torque
    (None: as meta["torque_side"] says, "link" (default, Franka's tau_J) excludes it: the
    sensor sits between the gearbox and the link, the rotor before it); torque_hold: "zoh" (a
    torque sample holds over the period after it, as in a 1 kHz torque loop: the model is
    evaluated at the period's midpoint) or "sample" (at the sample instant); torque_filter:
    "matched" (default: the torques are smoothed with the kernel matched to the acceleration's
    derivative filter, see `matched_kernel`) or "none" (raw torques against the smoothed
    acceleration); velocity_source: "dq" (the velocity and acceleration are the measured velocity
    and its Savitzky-Golay derivative) or "q" (the first and second Savitzky-Golay derivatives of
    the measured position: an encoder's position is far less noisy than a velocity estimate, whose
    differentiated noise grows as f^2 into the band the diagnosis analyses)."""

    derivative_window: float = 0.041
    forward_steps: int = 20
    end_effector: str | None = None
    rotor_in_tau: bool | None = None
    torque_hold: str = "zoh"
    torque_filter: str = "matched"
    velocity_source: str = "dq"


@dataclasses.dataclass
class Replay:
    """A log on a uniform time grid with the nominal model evaluated on it.

    residual[channel]: (T, 7) measured minus predicted; base[channel]: the nominal prediction's
    pieces the effects build on (see sim2real/effects.py). valid: (T,) samples away from the
    ends (the derivative filter's half window and the forward horizon) that the fits use.
    kernel: the torque channels' smoothing kernel (None: none); unfiltered: the torque channels'
    residual before it; window: the derivative filter's length in samples."""

    log: RobotLog
    dt: float
    q: NDArray[np.float64]  # the motion where the torques apply (midpoints under "zoh")
    dq: NDArray[np.float64]
    ddq: NDArray[np.float64]
    terms: ArmTerms
    model: ArmModel
    residual: dict[str, NDArray[np.float64]]
    valid: NDArray[np.bool_]
    forward_steps: int
    tau_cmd: NDArray[np.float64] | None
    law: NDArray[np.float64] | None
    rotor_in_tau: bool = False
    kernel: NDArray[np.float64] | None = None
    unfiltered: dict[str, NDArray[np.float64]] = dataclasses.field(default_factory=dict)
    window: int = 1
    velocity_source: str = "dq"
    torque_hold: str = "zoh"

    def at_instants(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """x (T, ...) on the log's samples taken at the instants the model is evaluated at: each
        hold period's midpoint under torque_hold "zoh" (the last sample kept), the samples
        themselves under "sample"."""
        return instants(x, self.torque_hold)

    @property
    def reach(self) -> int:
        """The residual noise's correlation length in samples: the derivative filter's and the
        torque kernel's span, plus the forward replay's horizon."""
        span = max(self.window, 0 if self.kernel is None else len(self.kernel)) + 2
        return span + (self.forward_steps if "dq" in self.residual else 0)

    @property
    def channels(self) -> tuple[str, ...]:
        return tuple(c for c in CHANNELS if c in self.residual)

    def smooth(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """x (T, ...) seen through the torque channels' filter along time (as is without one)."""
        if self.kernel is None:
            return x
        return correlate1d(x, self.kernel, axis=0, mode="nearest")

    @property
    def noise_gain(self) -> float:
        """The factor by which the torque filter scales white noise's standard deviation."""
        return 1.0 if self.kernel is None else float(np.sqrt(np.sum(self.kernel**2)))

    def forward(self, torque: NDArray[np.float64]) -> NDArray[np.float64]:
        """The k-step integral of M_total^-1 torque dt (T, 7): how a torque perturbation of the
        joint balance moves the "dq" channel's prediction (sample t holds the sum since the last
        re-synchronisation)."""
        Minv = self._inverse_mass()
        acc = np.einsum("tij,tj->ti", Minv, torque) * self.dt
        out = np.zeros_like(acc)
        k = self.forward_steps
        T = acc.shape[0]
        for start in range(0, T, k):  # re-synchronised to the log at each window's start
            seg = np.cumsum(acc[start : start + k], axis=0)
            out[start + 1 : start + len(seg)] = seg[:-1]
        return out

    def _inverse_mass(self) -> NDArray[np.float64]:
        if not hasattr(self, "_minv"):
            M = self.terms.mass + np.eye(7)[None] * self.model.reflected_inertia[None, :, None]
            self._minv = np.linalg.inv(M)
        return self._minv


def instants(x: NDArray[np.float64], hold: str) -> NDArray[np.float64]:
    """x (T, ...) at the model's instants for `hold`: the periods' midpoints ("zoh"; the last
    sample kept) or the samples ("sample")."""
    return np.concatenate([0.5 * (x[:-1] + x[1:]), x[-1:]]) if hold == "zoh" else x


def matched_kernel(window: int, hold: str = "zoh") -> NDArray[np.float64]:
    """The smoothing kernel s (window + 1 taps, centred) that turns the torque's acceleration into
    the replay's: sum_i s_i a[k + i] equals the cubic Savitzky-Golay derivative of the velocity at
    the torque's instant k (the hold period's midpoint under "zoh", the sample under "sample"),
    where a[k] is the velocity's change over the torque's period divided by it ("zoh":
    v[k+1] - v[k]; "sample": the central difference). The taps sum to 1."""
    h = window // 2
    g = savgol_coeffs(window, 3, deriv=1, use="dot")  # per unit time step: sum_j g_j v[k - h + j]
    if hold == "zoh":
        g = 0.5 * (np.concatenate([g, [0.0]]) + np.concatenate([[0.0], g]))  # taps k-h .. k+h+1
        first, lo, hi = -h, 0, 1  # a[k] = v[k + 1] - v[k]
    else:
        first, lo, hi = -h, -1, 1  # a[k] = (v[k + 1] - v[k - 1]) / 2
    n = window + 1
    taps = np.arange(n) - n // 2  # s_i for i in taps
    cols = np.zeros((len(g) + 2, n))  # the velocity index j - first + 1 (room for the ends)
    for c, i in enumerate(taps):
        scale = 1.0 if hold == "zoh" else 0.5
        cols[i + hi - first + 1, c] += scale
        cols[i + lo - first + 1, c] -= scale
    target = np.zeros(len(g) + 2)
    target[1 : 1 + len(g)] = g
    s, *_ = np.linalg.lstsq(cols, target, rcond=None)
    return s / s.sum()


def uniform(log: RobotLog) -> RobotLog:
    """The log resampled (linear interpolation) onto a uniform grid at its median sample period,
    so that filters and delays mean the same time everywhere; a uniform log is returned as is."""
    t = log.time
    dt = float(np.median(np.diff(t)))
    if np.allclose(np.diff(t), dt, rtol=1e-6, atol=1e-9):
        return log
    out = resample(log, dt)
    out.meta["resampled"] = {"from_samples": len(t), "period": dt}
    return out


def _controller_law(log: RobotLog, terms_ref: ArmTerms | None) -> NDArray[np.float64] | None:
    ctrl = log.meta.get("controller")
    if not isinstance(ctrl, dict) or log.q_cmd is None or log.dq_cmd is None or terms_ref is None:
        return None
    kp = np.asarray(ctrl.get("kp", []), dtype=float)
    kd = np.asarray(ctrl.get("kd", []), dtype=float)
    if kp.shape != (7,) or kd.shape != (7,):
        raise InputError(f"meta controller gains kp {kp.shape}, kd {kd.shape}; expected 7 each")
    return terms_ref.total + kp * (log.q_cmd - log.q) + kd * (log.dq_cmd - log.dq)


def _gravity(model: ArmModel, q: NDArray[np.float64]) -> NDArray[np.float64]:
    """The model's gravity torque g(q) (T, 7) (the torque that holds the arm still)."""
    zeros = np.zeros_like(q)
    return model.terms(q, zeros, zeros).rigid


def replay(log: RobotLog, config: ReplayConfig | None = None) -> Replay:
    """Replay `log` (any sample spacing; resampled to uniform) against the nominal arm model with
    the log's end effector; returns the residual channels the log's signals allow."""
    c = config or ReplayConfig()
    log = uniform(log)
    dt = float(log.time[1] - log.time[0])
    window = max(5, int(round(c.derivative_window / dt)) | 1)
    if log.n_samples < 4 * window:
        raise InputError(
            f"log has {log.n_samples} samples; expected at least {4 * window} "
            f"(4 derivative windows of {c.derivative_window} s)"
        )
    ee = c.end_effector or log.meta.get("end_effector", "hand")
    model = ArmModel(ee)
    check_choice(c.torque_hold, ("zoh", "sample"), "ReplayConfig.torque_hold")
    check_choice(c.torque_filter, ("matched", "none"), "ReplayConfig.torque_filter")
    kernel = matched_kernel(window, c.torque_hold) if c.torque_filter == "matched" else None
    check_choice(c.velocity_source, ("dq", "q"), "ReplayConfig.velocity_source")
    q_t = log.q
    if c.velocity_source == "q":
        dq_s = savgol_filter(log.q, window, 3, deriv=1, delta=dt, axis=0)
        ddq = savgol_filter(log.q, window, 3, deriv=2, delta=dt, axis=0)
    else:
        dq_s = savgol_filter(log.dq, window, 3, axis=0)
        ddq = savgol_filter(log.dq, window, 3, deriv=1, delta=dt, axis=0)
    q_t, dq_s, ddq = (instants(x, c.torque_hold) for x in (q_t, dq_s, ddq))
    terms = model.terms(q_t, dq_s, ddq)
    residual: dict[str, NDArray[np.float64]] = {}
    rotor_in_tau = (log.meta.get("torque_side", "link") == "motor") if c.rotor_in_tau is None else c.rotor_in_tau
    if log.tau is not None:
        residual["tau"] = log.tau - terms.total + (0.0 if rotor_in_tau else terms.rotor)
    law = None
    terms_ref = None
    if log.q_cmd is not None and log.dq_cmd is not None and isinstance(log.meta.get("controller"), dict):
        ddq_cmd = savgol_filter(log.dq_cmd, window, 3, deriv=1, delta=dt, axis=0)
        terms_ref = model.terms(log.q_cmd, log.dq_cmd, ddq_cmd)
        law = _controller_law(log, terms_ref)
    commanded = log.tau_cmd
    if commanded is not None and log.meta.get("tau_cmd_gravity", "included") == "excluded":
        # libfranka's tau_d: the robot adds its own gravity compensation; ours is the model's
        commanded = commanded + _gravity(model, log.q)
    tau_cmd = commanded if commanded is not None else law
    if commanded is not None:
        residual["cmd"] = commanded - terms.total
        if law is not None:
            residual["ctrl"] = commanded - law
    rep = Replay(
        log=log,
        dt=dt,
        q=q_t,
        dq=dq_s,
        ddq=ddq,
        terms=terms,
        model=model,
        residual=residual,
        valid=np.ones(log.n_samples, dtype=bool),
        forward_steps=c.forward_steps,
        tau_cmd=tau_cmd,
        law=law,
        rotor_in_tau=rotor_in_tau,
        kernel=kernel,
        window=window,
        velocity_source=c.velocity_source,
        torque_hold=c.torque_hold,
    )
    measured = {"tau": log.tau, "cmd": commanded}
    for ch in ("tau", "cmd"):  # the measured torque through the filter; the model's side is smooth
        if ch in residual and kernel is not None:
            rep.unfiltered[ch] = residual[ch]
            residual[ch] = residual[ch] + rep.smooth(measured[ch]) - measured[ch]
    if log.tau is None and tau_cmd is not None:
        # state log: from each re-synchronisation the model integrates its own acceleration
        # M_total^-1 (tau_cmd - h); the logged velocity integrates the logged one. Their
        # difference after i samples is the sum of M_total^-1 (tau_cmd - total) dt, linearised
        # about the logged states (M and h taken there); residual = logged - predicted.
        residual["dq"] = -rep.forward(tau_cmd - terms.total)
    if not residual:
        raise InputError(
            "log has none of tau, tau_cmd, or q_cmd/dq_cmd with meta controller gains; "
            "expected measured or commanded torques to replay"
        )
    half = window // 2 + max(1, c.forward_steps)
    rep.valid[:half] = False
    rep.valid[-half:] = False
    return rep
