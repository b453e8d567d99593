"""What each catalogue effect predicts for a replayed log's residual channels.

An effect at one setting of its nonlinear parameters (a friction's smoothing velocity, a delay, a
saturation level, a backlash width) is a `Candidate`: a fixed prediction `offset` plus linear
`features` whose coefficients the fit chooses. The prediction is what the effect adds to the
residual "measured minus nominal" of each channel (sim2real/replay.py):
- a dynamics effect's torque G (the extra torque the joint needs) adds G to "tau" and "cmd" and
  -forward(G) to "dq";
- a sensing effect adds its reading error to "tau" only;
- an actuation effect that delivers A(c) for the command c adds c - A(c) to "cmd" and
  forward(A(c) - c) to "dq";
- a controller effect adds its extra command to "ctrl".
`to_params` turns the fitted coefficients back into the catalogue's parameters.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numba
import numpy as np
from numpy.typing import NDArray

from assembly.panda_model import TAU_MAX
from sim2real.catalogue import CATALOGUE, effect
from sim2real.replay import Replay

__all__ = [
    "Candidate",
    "Family",
    "candidates",
    "untestable",
    "motor_band_offset",
    "backlash_excess",
    "backlash_motor_inertia",
    "FITTABLE",
    "STRIBECK_SIGN_VELOCITY",
    "BACKLASH_MOTOR_FRACTION",
    "BACKLASH_STIFFNESS",
    "BACKLASH_DAMPING",
]

STRIBECK_SIGN_VELOCITY = 0.002  # [rad/s] the sign smoothing of the Stribeck term (catalogue)
# The backlash transmission (sim2real/reality.py simulates the same one): the motor side holds
# this fraction of the reflected inertia (at least BACKLASH_MOTOR_INERTIA_MIN: a massless motor
# has no dynamics to cross the dead band with); the engaged gear mesh is a spring-damper (our
# choice: the order of a harmonic drive's torsional stiffness).
BACKLASH_MOTOR_FRACTION = 0.5
BACKLASH_STIFFNESS = 2.0e4  # [N m/rad]
BACKLASH_DAMPING = 100.0  # [N m s/rad]
BACKLASH_MOTOR_INERTIA_MIN = 1.0e-3  # [kg m^2]
N = 7

Array = NDArray[np.float64]


def backlash_motor_inertia(reflected_inertia: Array) -> Array:
    """The motor side's inertia behind a dead band [kg m^2], per joint: BACKLASH_MOTOR_FRACTION of
    the reflected inertia, at least BACKLASH_MOTOR_INERTIA_MIN."""
    return np.maximum(np.asarray(reflected_inertia) * BACKLASH_MOTOR_FRACTION, BACKLASH_MOTOR_INERTIA_MIN)


@dataclasses.dataclass
class Candidate:
    """One effect at one setting: prediction = offset[channel] + features[channel] @ coef.

    features[channel]: (T, 7, P); offset[channel]: (T, 7) or absent (zero); names: the P
    coefficients' names; bounds: (P, 2); to_params(coef) -> the catalogue parameters."""

    name: str
    setting: dict[str, float]
    features: dict[str, Array]
    offset: dict[str, Array]
    names: list[str]
    bounds: Array
    to_params: Callable[[Array], dict[str, float | list[float]]]
    family: Family | None = None  # the one-parameter family this candidate is a member of

    @property
    def n_coef(self) -> int:
        return len(self.names)


@dataclasses.dataclass(frozen=True)
class Family:
    """An effect's candidates along its one nonlinear setting `key`: the ascending `grid` they were
    made at, the range [low, high] (> 0) a refinement may explore, and `at(value)`, the member at
    any value in that range (made once per value)."""

    key: str
    grid: tuple[float, ...]
    low: float
    high: float
    at: Callable[[float], Candidate]

    def bracket(self, value: float) -> tuple[float, float]:
        """The grid's neighbours of `value` (beyond an end of the grid: one grid step further,
        within [low, high])."""
        g = self.grid
        i = int(np.argmin(np.abs(np.log(np.asarray(g) / value))))
        below = g[i - 1] if i > 0 else (g[0] ** 2 / g[1] if len(g) > 1 else g[0] / 2.0)
        above = g[i + 1] if i + 1 < len(g) else (g[-1] ** 2 / g[-2] if len(g) > 1 else g[-1] * 2.0)
        return max(below, self.low), min(above, self.high)


def _family(
    name: str, key: str, grid: tuple[float, ...], make: Callable[[float], Candidate], high: float | None = None
) -> list[Candidate]:
    """The candidates of `make` at `grid` (ascending), members of one Family whose range is the
    catalogue's bounds of `key` capped at `high`; where the catalogue's lower bound is 0 (no
    effect), the grid's first value is the smallest setting resolved (a 1 ms delay, a 1 mrad band)."""
    spec = effect(name).param(key)
    made: dict[float, Candidate] = {}

    def at(value: float) -> Candidate:
        value = float(value)
        if value not in made:
            made[value] = dataclasses.replace(make(value), family=fam)
        return made[value]

    low = spec.low if spec.low > 0 else grid[0]
    fam = Family(key, tuple(grid), low, min(spec.high, high) if high is not None else spec.high, at)
    return [at(v) for v in grid]


def _diag(x: Array) -> Array:
    """(T, 7) per-joint feature -> (T, 7, 7) with joint j's feature in column j."""
    out = np.zeros(x.shape + (N,))
    idx = np.arange(N)
    out[:, idx, idx] = x
    return out


def _route(rep: Replay, place: str, torque: Array) -> dict[str, Array]:
    """A per-unit torque (T, 7, P) of `place` routed into the replay's channels ("motor": a
    dynamics term on the motor side of a link-side torque sensor); the torque channels see it
    through the replay's torque filter, as they see the measured torque."""
    out: dict[str, Array] = {}
    chans = rep.channels
    seen = rep.smooth(torque) if place != "controller" else torque
    if place == "motor" and rep.rotor_in_tau:
        place = "dynamics"
    if place in ("dynamics", "motor"):
        for c in ("tau", "cmd") if place == "dynamics" else ("cmd",):
            if c in chans:
                out[c] = seen
        if "dq" in chans:
            out["dq"] = -np.stack([rep.forward(torque[..., p]) for p in range(torque.shape[-1])], axis=-1)
    elif place == "sensing":
        if "tau" in chans:
            out["tau"] = seen
    elif place == "actuation":  # torque = c - A(c)
        if "cmd" in chans:
            out["cmd"] = seen
        if "dq" in chans:
            out["dq"] = np.stack([rep.forward(torque[..., p]) for p in range(torque.shape[-1])], axis=-1)
    elif place == "controller":
        if "ctrl" in chans:
            out["ctrl"] = torque
    return out


def _per_joint(
    name: str, param: str, value: Callable[[Array], Array] = lambda c: c
) -> tuple[list[str], Callable[[Array], dict[str, float | list[float]]]]:
    names = [f"{param}[{j + 1}]" for j in range(N)]
    return names, lambda coef: {param: [float(v) for v in value(np.asarray(coef))]}


def _bounds(name: str, param: str, shift: float = 0.0, count: int = N) -> Array:
    p = effect(name).param(param)
    return np.tile([p.low - shift, p.high - shift], (count, 1)).astype(float)


def _friction(
    rep: Replay, name: str, shape: Array, pname: str, setting: dict[str, float], extra: dict[str, float]
) -> Candidate:
    names, to_params = _per_joint(name, pname)
    feats = _route(rep, "dynamics", _diag(shape))
    return Candidate(name, setting, feats, {}, names, _bounds(name, pname), lambda coef: {**to_params(coef), **extra})


def _coulomb(rep: Replay) -> list[Candidate]:
    dq = rep.dq
    return _family(
        "coulomb",
        "v_smooth",
        (0.005, 0.01, 0.02, 0.04, 0.08, 0.15, 0.3, 0.5),
        lambda vs: _friction(rep, "coulomb", np.tanh(dq / vs), "fc", {"v_smooth": vs}, {"v_smooth": vs}),
    )


def _stribeck(rep: Replay) -> list[Candidate]:
    dq = rep.dq
    sign = np.tanh(dq / STRIBECK_SIGN_VELOCITY)
    return _family(
        "stribeck",
        "vs",
        (0.01, 0.02, 0.05, 0.1, 0.2, 0.4),
        lambda vs: _friction(rep, "stribeck", np.exp(-((dq / vs) ** 2)) * sign, "fs", {"vs": vs}, {"vs": vs}),
    )


def _viscous(rep: Replay) -> list[Candidate]:
    names, to_params = _per_joint("viscous", "fv")
    return [
        Candidate("viscous", {}, _route(rep, "dynamics", _diag(rep.dq)), {}, names, _bounds("viscous", "fv"), to_params)
    ]


def _rotor(rep: Replay) -> list[Candidate]:
    names, to_params = _per_joint("rotor_inertia", "dI")
    b = _bounds("rotor_inertia", "dI")
    b[:, 0] = np.maximum(b[:, 0], -rep.model.reflected_inertia)  # total inertia stays >= 0
    return [Candidate("rotor_inertia", {}, _route(rep, "motor", _diag(rep.ddq)), {}, names, b, to_params)]


def _payload(rep: Replay) -> list[Candidate]:
    """A point mass dm with first moment h = dm com at the flange (its own rotational inertia
    about its centre neglected): the flange wrench m a + alpha x h + w x (w x h), h x a, mapped
    through the flange Jacobian; linear in (dm, h)."""
    log = rep.log
    J, w, alpha, a = rep.model.flange_kinematics(rep.q, rep.dq, rep.ddq)
    cols = []
    wrench = np.zeros((log.n_samples, 6))
    wrench[:, 3:] = a
    cols.append(np.einsum("tki,tk->ti", J, wrench))
    for axis in range(3):
        e = np.zeros(3)
        e[axis] = 1.0
        wrench = np.zeros((log.n_samples, 6))
        wrench[:, :3] = np.cross(np.broadcast_to(e, a.shape), a)
        wrench[:, 3:] = np.cross(alpha, e) + np.cross(w, np.cross(w, np.broadcast_to(e, w.shape)))
        cols.append(np.einsum("tki,tk->ti", J, wrench))
    torque = np.stack(cols, axis=-1)
    spec = effect("payload")
    dm_b = (spec.param("dm").low, spec.param("dm").high)
    hmax = max(abs(dm_b[0]), abs(dm_b[1])) * 0.25
    bounds = np.array([dm_b, (-hmax, hmax), (-hmax, hmax), (-hmax, hmax)], dtype=float)

    def to_params(coef: Array) -> dict[str, float | list[float]]:
        dm = float(coef[0])
        com = coef[1:] / dm if abs(dm) > 1e-6 else np.zeros(3)
        return {"dm": dm, "com_x": float(com[0]), "com_y": float(com[1]), "com_z": float(com[2])}

    return [Candidate("payload", {}, _route(rep, "dynamics", torque), {}, ["dm", "hx", "hy", "hz"], bounds, to_params)]


def _offset(rep: Replay) -> list[Candidate]:
    names, to_params = _per_joint("torque_offset", "offset")
    ones = np.ones((rep.log.n_samples, N))
    return [
        Candidate(
            "torque_offset",
            {},
            _route(rep, "sensing", _diag(ones)),
            {},
            names,
            _bounds("torque_offset", "offset"),
            to_params,
        )
    ]


def _shift(x: Array, steps: float) -> Array:
    """x(t - steps samples) with linear interpolation, the first value held before the start."""
    T = x.shape[0]
    src = np.arange(T) - steps
    return np.stack([np.interp(src, np.arange(T), x[:, j]) for j in range(x.shape[1])], axis=1)


def _fixed_actuation(rep: Replay, name: str, key: str, value: float, excess: Array) -> Candidate:
    """An actuation effect with no linear coefficient at setting `key` = `value`, whose delivered
    torque falls short of the command by `excess` (T, 7) = c - A(c)."""
    off = _route(rep, "actuation", excess[..., None])
    return Candidate(
        name, {key: value}, {}, {k: v[..., 0] for k, v in off.items()}, [], np.zeros((0, 2)), lambda coef: {key: value}
    )


def _delay(rep: Replay) -> list[Candidate]:
    c = rep.tau_cmd
    if c is None:
        return []
    return _family(
        "actuation_delay",
        "delay",
        (0.001, 0.002, 0.004, 0.007, 0.01, 0.015, 0.02, 0.03),
        lambda d: _fixed_actuation(rep, "actuation_delay", "delay", d, c - _shift(c, d / rep.dt)),
    )


def _gain(rep: Replay) -> list[Candidate]:
    c = rep.tau_cmd
    if c is None:
        return []
    # c - k c = -(k - 1) c: coefficient (k - 1)
    names, to_params = _per_joint("torque_gain", "k", lambda coef: 1.0 + coef)
    return [
        Candidate(
            "torque_gain",
            {},
            _route(rep, "actuation", _diag(-c)),
            {},
            names,
            _bounds("torque_gain", "k", shift=1.0),
            to_params,
        )
    ]


def _saturation(rep: Replay) -> list[Candidate]:
    c = rep.tau_cmd
    if c is None:
        return []
    peak = float(np.max(np.abs(c) / TAU_MAX))  # a level at or above the peak changes nothing
    grid = tuple(s for s in (0.05, 0.08, 0.12, 0.17, 0.25, 0.35, 0.5, 0.7) if s < peak)
    if not grid:
        return []
    return _family(
        "torque_saturation",
        "s",
        grid,
        lambda s: _fixed_actuation(rep, "torque_saturation", "s", s, c - np.clip(c, -s * TAU_MAX, s * TAU_MAX)),
        high=peak,
    )


def backlash_excess(command: Array, ddq: Array, dt: float, b: float, motor_inertia: Array) -> Array:
    """What a dead band of width b in a stiff two-mass transmission adds to the command channel.

    The rigid-mesh limit of the transmission: while engaged the motor (inertia `motor_inertia`)
    moves with the link and passes m = command - J ddq to it; when m changes sign the motor leaves
    the flank and crosses the band, the relative position x obeying J x'' = m with the link's
    logged acceleration, and the link gets nothing until x has crossed b. The command then holds
    m more than the nominal model needs (T, 7); engaged, nothing. (A stiff spring driven by the
    logged positions would turn their noise into torque: 1e-5 rad is 0.2 N m at 2e4 N m/rad.)"""
    T = command.shape[0]
    m_all = command - motor_inertia * ddq
    side = np.sign(m_all[0])  # the flank the motor rests on (+1: pushing forward)
    side[side == 0] = 1.0
    x = side * b / 2.0  # the motor's position in the band, relative to its centre
    v = np.zeros_like(x)
    out = np.zeros_like(command)
    for t in range(T):
        m = m_all[t]
        engaged = (np.abs(x) >= b / 2.0 - 1e-12) & (np.sign(m) == np.sign(x))
        free = ~engaged
        v = np.where(free, v + dt * m / motor_inertia, 0.0)
        x = np.where(free, np.clip(x + dt * v, -b / 2.0, b / 2.0), x)
        out[t] = np.where(free, m, 0.0)
    return out


BACKLASH_WIDTHS = np.geomspace(0.0005, 0.03, 43)  # [rad] the coarse search over a joint's band
_BAND_STARTS = (-1.0, 0.0, 1.0)  # where in its band the motor may start: a flank or the centre


def mesh_motor_acceleration(
    command: Array,
    q: Array,
    dq: Array,
    dt: float,
    widths: Array,
    starts: Array,
    motor_inertia: Array,
    substeps: int = 4,
) -> Array:
    """The motor's acceleration behind a dead band, driven by `command` and pushed by the logged link.

    Per row of `widths` (B, 7) [rad] and `starts` (B, 7) (the motor's start in its band, -1 to 1
    of the half width), the motor side of the two-mass transmission that sim2real/reality.py
    simulates (inertia `motor_inertia`, the engaged mesh a spring BACKLASH_STIFFNESS with the
    damper BACKLASH_DAMPING) is integrated (backward Euler, `substeps` per sample) against the
    logged link motion q, dq (T, 7), linear within a sample. The joints are independent given
    the link's motion. Returns (B, T, 7): the mean acceleration over each sample's period
    (the last is 0)."""
    half = 0.5 * np.asarray(widths, dtype=np.float64)
    starts = np.ascontiguousarray(np.broadcast_to(np.asarray(starts, dtype=np.float64), half.shape))
    out = np.zeros((half.shape[0], command.shape[0], command.shape[1]))
    _mesh_loop(
        np.ascontiguousarray(command, dtype=np.float64),
        np.ascontiguousarray(q, dtype=np.float64),
        np.ascontiguousarray(dq, dtype=np.float64),
        float(dt),
        np.ascontiguousarray(half),
        starts,
        np.ascontiguousarray(np.broadcast_to(np.asarray(motor_inertia, dtype=np.float64), command.shape[1:])),
        int(substeps),
        BACKLASH_STIFFNESS,
        BACKLASH_DAMPING,
        out,
    )
    return out


@numba.njit(cache=True)
def _mesh_loop(
    command: Array,
    q: Array,
    dq: Array,
    dt: float,
    half: Array,
    starts: Array,
    J: Array,
    substeps: int,
    stiffness: float,
    damping: float,
    out: Array,
) -> None:
    """`mesh_motor_acceleration`'s integration, one (row, joint) at a time, into `out` (B, T, 7)."""
    h = dt / substeps
    for b in range(out.shape[0]):
        for j in range(out.shape[2]):
            theta = q[0, j] + starts[b, j] * half[b, j]
            omega = dq[0, j]
            stiff = J[j] + h * h * stiffness
            for k in range(out.shape[1] - 1):
                w0 = omega
                c = command[k, j]
                for i in range(substeps):
                    f0, f1 = i / substeps, (i + 1) / substeps
                    q_end = q[k, j] + f1 * (q[k + 1, j] - q[k, j])
                    v_end = dq[k, j] + f1 * (dq[k + 1, j] - dq[k, j])
                    d = damping if abs(theta - q[k, j] - f0 * (q[k + 1, j] - q[k, j])) > half[b, j] else 0.0
                    free = omega + h * c / J[j]
                    delta = theta + h * free - q_end
                    if abs(delta) > half[b, j]:  # engaged at the end: the mesh spring-damper acts
                        side = 1.0 if delta > 0 else -1.0
                        omega = (
                            J[j] * omega + h * c - h * stiffness * (theta - q_end - side * half[b, j]) + h * d * v_end
                        ) / (stiff + h * d)
                    else:
                        omega = free
                    theta = theta + h * omega
                out[b, k, j] = (omega - w0) / dt


_MESH_BYTES = 2**28  # the size of one array of the mesh search's predictions (a few are held at once)


def _backlash_mesh(rep: Replay, c: Array, motor: Array) -> list[Candidate]:
    """Backlash seen through the replay's torque filter: the compliant mesh simulated behind each
    joint (motor inertias `motor`, (7,)); per joint the width and the motor's start in the band
    that best fit the command channel (a geometric search in steps of 10 %, then three halvings of
    the step; width 0: none)."""
    log = rep.log
    T = log.n_samples
    a_fd = np.zeros_like(log.dq)
    a_fd[:-1] = np.diff(log.dq, axis=0) / rep.dt  # the link's acceleration over each period
    target = rep.residual["cmd"]
    weight = rep.valid.astype(float)
    cols = np.arange(N)
    best_sse = weight @ (target**2)  # width 0
    best_pred = np.zeros_like(target)
    best_w = np.zeros(N)
    chunk = max(1, _MESH_BYTES // (8 * N * T))

    def search(widths: Array, allowed: NDArray[np.bool_]) -> None:
        """Keep, per joint where `allowed`, the row of `widths` (W, 7) at any start in the band
        that fits better than the best so far."""
        nonlocal best_sse, best_w
        rows = np.repeat(widths, len(_BAND_STARTS), axis=0)
        starts = np.tile(np.array(_BAND_STARTS)[:, None], (len(widths), N))
        for lo in range(0, len(rows), chunk):
            acc = mesh_motor_acceleration(
                c, log.q, log.dq, rep.dt, rows[lo : lo + chunk], starts[lo : lo + chunk], motor
            )
            acc -= a_fd
            acc *= motor
            pred = rep.smooth(np.moveaxis(acc, 0, -1))  # (T, 7, rows)
            del acc
            miss = target[..., None] - pred
            miss *= miss
            sse = np.einsum("tjr,t->jr", miss, weight)  # (7, rows)
            del miss
            pick = np.argmin(sse, axis=1)
            better = (sse[cols, pick] < best_sse) & allowed
            best_sse = np.where(better, sse[cols, pick], best_sse)
            best_pred[:, better] = pred[:, cols, pick][:, better]
            best_w = np.where(better, rows[lo + pick, cols], best_w)

    search(np.tile(BACKLASH_WIDTHS[:, None], (1, N)), np.ones(N, dtype=bool))
    ratio = BACKLASH_WIDTHS[1] / BACKLASH_WIDTHS[0]
    for step in (0.5, 0.25, 0.125):
        base = np.where(best_w > 0, best_w, BACKLASH_WIDTHS[0])
        search(np.stack([base * ratio**-step, base * ratio**step]), best_w > 0)
    widths = [float(w) for w in best_w]
    return [
        Candidate(
            "backlash",
            {"b": float(np.median(best_w))},
            {},
            {"cmd": best_pred},
            [],
            np.zeros((0, 2)),
            lambda coef, widths=widths: {"b": widths},
        )
    ]


def _backlash(rep: Replay) -> list[Candidate]:
    c = rep.tau_cmd
    if c is None:
        return []
    motor = backlash_motor_inertia(rep.model.reflected_inertia)
    if rep.kernel is not None and "cmd" in rep.residual:
        return _backlash_mesh(rep, c, motor)
    return _family(
        "backlash",
        "b",
        (0.001, 0.002, 0.004, 0.007, 0.01, 0.015, 0.02),
        lambda b: _fixed_actuation(rep, "backlash", "b", b, backlash_excess(c, rep.ddq, rep.dt, b, motor)),
    )


def _controller(rep: Replay) -> list[Candidate]:
    ctrl = rep.log.meta.get("controller")
    if "ctrl" not in rep.residual or not isinstance(ctrl, dict):
        return []
    log = rep.log
    kp = np.asarray(ctrl["kp"], dtype=float)
    kd = np.asarray(ctrl["kd"], dtype=float)
    feats = np.concatenate([_diag(kp * (log.q_cmd - log.q)), _diag(kd * (log.dq_cmd - log.dq))], axis=-1)
    names = [f"kp_scale[{j + 1}]" for j in range(N)] + [f"kd_scale[{j + 1}]" for j in range(N)]
    bounds = np.concatenate([_bounds("controller_gain", "kp_scale", 1.0), _bounds("controller_gain", "kd_scale", 1.0)])

    def to_params(coef: Array) -> dict[str, float | list[float]]:
        return {"kp_scale": [float(1 + v) for v in coef[:N]], "kd_scale": [float(1 + v) for v in coef[N:]]}

    return [Candidate("controller_gain", {}, _route(rep, "controller", feats), {}, names, bounds, to_params)]


# Plausible corrections of one link's standard parameters (the bounds of the base-parameter fit):
# the mass within LINK_MASS_FRACTION of the link's, the first moments by that fraction of the
# nominal plus the link's mass times LINK_COM_SHIFT, the rotational inertia by that fraction of
# its largest nominal moment plus the mass times LINK_COM_SHIFT^2 (and the parallel-axis change
# of a first moment shifted that far). A base parameter, a combination beta @ pi, is bounded by
# the sum of |beta| times its members' bounds: every combination reachable by plausible links.
LINK_MASS_FRACTION = 0.5
LINK_COM_SHIFT = 0.05  # [m]


def _link_bounds(pi: Array) -> Array:
    """(70,) half-widths of plausible corrections of the standard parameters `pi` (70,)."""
    out = np.zeros(70)
    for k in range(N):
        p = pi[10 * k : 10 * k + 10]
        m = p[0]
        out[10 * k] = LINK_MASS_FRACTION * m
        out[10 * k + 1 : 10 * k + 4] = LINK_MASS_FRACTION * np.abs(p[1:4]) + m * LINK_COM_SHIFT
        scale = (
            LINK_MASS_FRACTION * np.abs(p[4:7]).max()
            + m * LINK_COM_SHIFT**2
            + 2.0 * np.linalg.norm(p[1:4]) * LINK_COM_SHIFT
        )
        out[10 * k + 4 : 10 * k + 10] = scale
    return out


def _link_inertia(rep: Replay) -> list[Candidate]:
    """Corrections of the links' base parameters (sim2real/inertia.py): the features are the base
    regressor's columns at the replayed motion, the bounds `_link_bounds` combined per base
    parameter; to_params gives {"base": corrections} in the order of the base parameters' groups."""
    from sim2real.inertia import base_parameters, link_regressor

    reg = link_regressor("none")
    bp = base_parameters("none")
    Y = reg(rep.q, rep.dq, rep.ddq)[..., list(bp.independent)]
    half = np.abs(bp.beta) @ _link_bounds(reg.nominal)
    bounds = np.stack([-half, half], axis=1)
    names = [f"base[{i + 1}]" for i in range(bp.count)]
    return [
        Candidate(
            "link_inertia",
            {},
            _route(rep, "dynamics", Y),
            {},
            names,
            bounds,
            lambda coef: {"base": [float(v) for v in coef]},
        )
    ]


def _tau_prediction(rep: Replay) -> Array:
    """The nominal model's prediction of the "tau" channel (T, 7): the torque the sensor sees."""
    t = rep.terms
    return t.total - (0.0 if rep.rotor_in_tau else t.rotor)


def _torque_scale(rep: Replay) -> list[Candidate]:
    if "tau" not in rep.residual:
        return []
    # k tau - tau = (k - 1) tau: coefficient (k - 1) on the predicted sensor torque
    names, to_params = _per_joint("torque_scale", "k", lambda coef: 1.0 + coef)
    return [
        Candidate(
            "torque_scale",
            {},
            _route(rep, "sensing", _diag(_tau_prediction(rep))),
            {},
            names,
            _bounds("torque_scale", "k", shift=1.0),
            to_params,
        )
    ]


def _torque_delay(rep: Replay) -> list[Candidate]:
    """One delay d for all joints: the offset tau(t - d) - tau(t) of the predicted sensor torque."""
    if "tau" not in rep.residual:
        return []
    pred = _tau_prediction(rep)

    def make(d: float) -> Candidate:
        off = rep.smooth(_shift(pred, d / rep.dt) - pred)
        return Candidate("torque_delay", {"d": d}, {}, {"tau": off}, [], np.zeros((0, 2)), lambda coef: {"d": d})

    return _family("torque_delay", "d", (0.001, 0.002, 0.004, 0.007, 0.01, 0.015, 0.02), make)


def _joint_inertia(rep: Replay) -> list[Candidate]:
    names, to_params = _per_joint("joint_inertia", "dJ")
    return [
        Candidate(
            "joint_inertia",
            {},
            _route(rep, "dynamics", _diag(rep.ddq)),
            {},
            names,
            _bounds("joint_inertia", "dJ"),
            to_params,
        )
    ]


def motor_band_offset(drive: Array, dt: float, b: float, motor_inertia: Array) -> tuple[Array, Array]:
    """The motor's position and velocity relative to the link behind a dead band of width b, (T, 7) each.

    The rigid-mesh limit of the backlash transmission: the motor rests on the flank its torque
    pushes against (`drive`, the torque the mesh passes to the link, (T, 7)); when that torque
    changes sign it crosses the band, J x'' = drive, until it strikes the other flank (velocity
    0 there). With drive = the link-side sensor's torque plus the link side's share of the
    reflected inertia times the acceleration (`_mesh_torque`) the crossing is nearly exact: while
    the mesh is open that torque is J_link x'' (the sensor reads -J_link a_link), and J_link = J_m
    (BACKLASH_MOTOR_FRACTION 1/2)."""
    drive = np.ascontiguousarray(drive, dtype=np.float64)
    J = np.ascontiguousarray(np.broadcast_to(np.asarray(motor_inertia, dtype=np.float64), drive.shape[1:]))
    xs = np.empty_like(drive)
    vs = np.empty_like(drive)
    _band_loop(drive, float(dt), 0.5 * float(b), J, xs, vs)
    return xs, vs


@numba.njit(cache=True)
def _band_loop(drive: Array, dt: float, half: float, J: Array, xs: Array, vs: Array) -> None:
    """`motor_band_offset`'s integration (semi-implicit Euler), one joint at a time, into xs, vs."""
    for j in range(drive.shape[1]):
        x = half if drive[0, j] >= 0.0 else -half
        v = 0.0
        for t in range(drive.shape[0]):
            m = drive[t, j]
            engaged = abs(x) >= half - 1e-12 and (m > 0.0) == (x > 0.0) and m != 0.0
            if not engaged:
                v += dt * m / J[j]
                x_new = min(max(x + dt * v, -half), half)
                if abs(x_new) >= half:  # stopped by the flank
                    v = 0.0
                x = x_new
            else:
                v = 0.0
            xs[t, j] = x
            vs[t, j] = v


# The widths the motor-side candidate is made at: its crossing times (the band's travel under the
# measured torque) fit only within about 10 % of the true width, so the grid steps 15 %.
_MOTOR_BAND_GRID = tuple(float(b) for b in np.geomspace(0.001, 0.02, 22))


def _link_share(rep: Replay) -> Array:
    """The link side's share of the reflected inertia behind a dead band (7,) [kg m^2]."""
    return (1.0 - BACKLASH_MOTOR_FRACTION) * np.asarray(rep.model.reflected_inertia)


def _mesh_torque(rep: Replay) -> Array:
    """What the gear mesh passes to the link (T, 7), from the log: the link-side sensor's torque
    (seen through the replay's filter) plus the link side's share of the reflected inertia times
    the replayed acceleration."""
    return rep.smooth(rep.log.tau) + _link_share(rep) * rep.ddq


def _backlash_motor(rep: Replay) -> list[Candidate]:
    """Backlash seen through a motor-side encoder: the logged q, dq are the link's plus the motor's
    offset x, v in the band, so the model evaluated at the logged motion errs by what the offset's
    motion costs: residual = ID(link) - ID(logged) = -(M(q) x'' + D x') (the position and bias
    sensitivities, and the mesh's elastic deflection, are under 0.2 % of it on the catalogue's
    logs), x'' and x' taken with the replay's own Savitzky-Golay filter at its torque instants
    (what the matched kernel applied to each period's velocity change gives). x per unit width is
    `motor_band_offset` at the member's width b, driven by the mesh torque measured in the log
    (`_mesh_torque`): the width sets when the motor strikes the other flank, the coefficient b_j
    per joint scales the offset (a joint that never reverses its torque has no feature). Needs the
    measured torque; "cmd" sees -(M + J_link) x'' (the link's share of the rotor moves with it)."""
    from scipy.signal import savgol_filter

    if rep.log.meta.get("position_side", "link") != "motor" or rep.log.tau is None:
        return []
    motor = backlash_motor_inertia(rep.model.reflected_inertia)
    drive = _mesh_torque(rep)
    mass = rep.terms.mass
    damping = np.asarray(rep.model.damping)
    link_share = _link_share(rep)
    idx = np.arange(N)
    names, to_params = _per_joint("backlash_motor", "b")
    bounds = _bounds("backlash_motor", "b")

    def make(b: float) -> Candidate:
        _, v = motor_band_offset(drive, rep.dt, b, motor)
        v /= b  # per unit width
        vel = rep.at_instants(savgol_filter(v, rep.window, 3, axis=0))
        acc = rep.at_instants(savgol_filter(v, rep.window, 3, deriv=1, delta=rep.dt, axis=0))
        feat = -mass * acc[:, None, :]  # column j: joint j's offset through the mass matrix
        feat[:, idx, idx] -= damping * vel
        feats = {"tau": feat} if "tau" in rep.residual else {}
        if "cmd" in rep.residual:
            cmd = feat.copy()
            cmd[:, idx, idx] -= link_share * acc
            feats["cmd"] = cmd
        return Candidate("backlash_motor", {"b": b}, feats, {}, names, bounds, to_params)

    return _family("backlash_motor", "b", _MOTOR_BAND_GRID, make)


#: The effects a replayed arm log can be fitted with, and how to make their candidates.
FITTABLE: dict[str, Callable[[Replay], list[Candidate]]] = {
    "coulomb": _coulomb,
    "stribeck": _stribeck,
    "viscous": _viscous,
    "rotor_inertia": _rotor,
    "payload": _payload,
    "torque_offset": _offset,
    "actuation_delay": _delay,
    "torque_gain": _gain,
    "torque_saturation": _saturation,
    "backlash": _backlash,
    "controller_gain": _controller,
    "link_inertia": _link_inertia,
    "torque_scale": _torque_scale,
    "torque_delay": _torque_delay,
    "joint_inertia": _joint_inertia,
    "backlash_motor": _backlash_motor,
}
assert set(FITTABLE) <= set(CATALOGUE)

_NEEDS_CMD = "needs the commanded torque (tau_cmd), which the log lacks"


def untestable(rep: Replay) -> dict[str, str]:
    """The catalogue's arm effects that the log's channels cannot show, each with the reason.

    Arguments:
        rep: the replayed log.
    Returns:
        {effect: reason}: the actuation effects and rotor_inertia without a commanded torque (a
        link-side torque does not see the rotor), controller_gain without q_cmd/dq_cmd and meta
        controller gains, backlash_motor without meta position_side "motor", the sensing effects
        without a measured torque."""
    out: dict[str, str] = {}
    has_cmd = rep.tau_cmd is not None  # the log's command, or the control law's from its reference
    if not has_cmd:
        for name in ("actuation_delay", "torque_saturation", "backlash", "torque_gain"):
            out[name] = _NEEDS_CMD
        if not rep.rotor_in_tau:
            out["rotor_inertia"] = _NEEDS_CMD + " (a link-side torque does not see the rotor)"
    if "ctrl" not in rep.residual:
        out["controller_gain"] = (
            "needs the reference (q_cmd, dq_cmd), the commanded torque and meta controller gains, which the log lacks"
        )
    if rep.log.meta.get("position_side", "link") != "motor":
        out["backlash_motor"] = "needs a motor-side position (meta position_side \"motor\"); the log's is the link's"
    if "tau" not in rep.residual:
        for name in ("torque_offset", "torque_scale", "torque_delay"):
            out[name] = "needs the measured joint torque (tau), which the log lacks"
    return out


def candidates(rep: Replay, names: list[str] | tuple[str, ...] | None = None) -> dict[str, list[Candidate]]:
    """The candidates of each effect in `names` (default: every fittable effect) that the log's
    channels can show; an effect no channel can show is left out."""
    out: dict[str, list[Candidate]] = {}
    skip = untestable(rep)
    for name in names or FITTABLE:
        if name in skip:
            continue
        cands = [c for c in FITTABLE[name](rep) if c.features or c.offset]
        cands = [c for c in cands if any(ch in rep.residual for ch in (*c.features, *c.offset))]
        if cands:
            out[name] = cands
    return out
