"""The simulated reality of the arm: a Panda whose logs have a known truth.

`make_arm_log` runs our Panda (sim2real.arm.arm_plant, Drake) along an exciting trajectory
(sim2real/trajectory.py) under a joint-space computed-torque + PD controller and logs it like the
robot would: measured q, dq and joint torques with sensor noise, the command and the reference.
The catalogue's arm effects (sim2real/catalogue.py, places dynamics / actuation / sensing /
controller) act where they act on a robot: in the equations of motion, in the actuator between the
command and the joint, in the torque sensor, in the controller; none is painted onto the log.

Signal chain per control tick k (t_k = k / log_rate; the controller runs at the log rate):
    measure    q_m = q + n_q, dq_m = dq + n_dq                                (sensors)
    control    tau_cmd = ID_nom(q_ref, dq_ref, ddq_ref) + kp_s Kp (q_ref - q_m) + kd_s Kd (dq_ref - dq_m)
    actuate    tau_a(t) = clip(k tau_cmd(t - delay), +-s TAU_MAX)             (zero-order hold)
    sense      tau(t) = k_tau [tau_a - (I_r + dI) ddq](t - d_tau) + offset + n_tau   (link-side sensor, tau_J)
    move       [M_links(q) + diag(I_r + dI + dJ)] ddq + c(q, dq) - g(q) = tau_a + tau_f(dq) + tau_stop(q, dq)
with M_links, c, g of the links as link_inertia changes them (mass, centre of mass, inertia per link),
dJ the link-side joint_inertia, and with backlash_motor the logged (and fed back) q, dq the motor side's
of the backlash transmission (meta position_side "motor").
Here tau_f = -(D + fv) dq - fc tanh(dq / v_smooth) - fs exp(-(dq / vs)^2) tanh(dq / 0.002) (the
model's joint damping D plus the friction effects), the payload in M, c and g, and, with backlash,
a two-mass transmission between tau_a and the joint. The torque sensor sits where a Panda's does,
between the gearbox and the link (torque_side "link", Franka's tau_J): the rotor's reflected
inertia is before it, the joint's friction and the link dynamics behind it, so
tau - ID_links(q, dq, ddq) = friction + payload + offset + noise, while the command sees the rotor
inertia and the actuator: A(tau_cmd) - ID_links - I_r ddq = friction + payload + dI ddq. docs/sim2real.md,
"The simulated reality", gives every equation, parameter and unit.

The plant is stepped by a fixed-step loop, not a Drake Simulator: the friction is numerically
stiff (fc / v_smooth reaches 2500 N m s/rad against joint inertias of 0.2 kg m^2 and less), so
each step is implicit in the velocities (backward Euler on the velocity-dependent and stiff
torques, Newton's method with a line search; M, c, g from Drake at the step's start).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from assembly.panda_model import ARM_JOINT_NAMES, JOINT_DAMPING, Q_MAX, Q_MIN, REFLECTED_INERTIA, TAU_MAX, V_MAX
from goflow_common.checks import check_choice, check_int, check_number
from goflow_common.config import config_to_dict
from goflow_common.errors import InputError, SimulationError
from sim2real.arm import END_EFFECTORS, N_ARM, ArmModel, arm_plant
from sim2real.catalogue import ARM_EFFECTS, effect
from sim2real.effects import (
    BACKLASH_DAMPING,
    BACKLASH_MOTOR_FRACTION,
    BACKLASH_MOTOR_INERTIA_MIN,
    BACKLASH_STIFFNESS,
    STRIBECK_SIGN_VELOCITY,
    backlash_motor_inertia,
)
from sim2real.clean import interpolate
from sim2real.log import UNITS, RobotLog
from sim2real.logger import apply_logger
from sim2real.trajectory import default_base_frequency, exciting_trajectory

__all__ = [
    "RealityConfig",
    "SENSORS",
    "make_arm_log",
    "resolve_effects",
    "ExtraTorque",
    "KP",
    "KD",
    "STRIBECK_SIGN_VELOCITY",
    "BACKLASH_MOTOR_FRACTION",
    "BACKLASH_STIFFNESS",
    "BACKLASH_DAMPING",
    "MOTOR_INERTIA_MIN",
    "STOP_STIFFNESS",
    "STOP_DAMPING",
]

Array = NDArray[np.float64]
#: Values of RealityConfig.sensors: the ideal logger of the control ticks, or the Panda's (sim2real.logger).
SENSORS: tuple[str, ...] = ("ideal", "panda")
#: An out-of-catalogue joint torque [N m] acting on the joints, a function of (q, dq) (7,) each.
ExtraTorque = Callable[[Array, Array], Array]

#: The controller's nominal gains per joint: stiffness [N m/rad], the k_gains of libfranka's joint
#: impedance example (examples/joint_impedance_control.cpp), and damping [N m s/rad], our choice:
#: lower than the example's d_gains (50, 50, 50, 50, 30, 25, 15) on joints 4-7; they track as well
#: here, and the example's wrist damping drives a backlash rattle into the wrist's torque limits.
KP: tuple[float, ...] = (600.0, 600.0, 600.0, 600.0, 250.0, 150.0, 50.0)
KD: tuple[float, ...] = (50.0, 50.0, 50.0, 20.0, 20.0, 20.0, 10.0)
# The Stribeck sign smoothing and the backlash transmission (motor-side inertia fraction and its
# floor, the mesh's spring and damper) are the ones sim2real/effects.py fits: defined there, once.
MOTOR_INERTIA_MIN = BACKLASH_MOTOR_INERTIA_MIN
#: Hard stops at the joint limits (only an effect that makes the arm fall reaches them): a
#: spring [N m/rad] and damper [N m s/rad] beyond Q_MIN / Q_MAX.
STOP_STIFFNESS = 1.0e4
STOP_DAMPING = 50.0
#: The fingers of a hand are held at this opening [m] and still (as sim2real.arm.ArmModel does).
FINGER_POSITION = 0.02

_NEWTON_TOL = 1e-8  # [N m] the implicit step's torque residual at convergence
_NEWTON_ITERATIONS = 30
_MAX_SPLITS = 5  # a step whose Newton iteration fails is halved up to this many times
_SPEED_DIVERGED = 4.0 * V_MAX  # [rad/s] a joint faster than this has diverged
_MAX_SUBSTEPS = 4  # per control tick with backlash (its stiff mesh wants short steps; implicit beyond)


# ---------------------------------------------------------------------------------------------- config


@dataclasses.dataclass(frozen=True)
class RealityConfig:
    """The simulated reality's settings (SI units); defaults make a 20 s, 1 kHz log.

    duration: the log's length [s]; log_rate: samples per second [Hz], also the control rate;
    end_effector: one of sim2real.arm.END_EFFECTORS; seed: the trajectory's and the noise's seed.
    Trajectory (sim2real.trajectory.exciting_trajectory): harmonics per joint, base_frequency [Hz]
    (None: a whole number of periods near 0.1 Hz), speed_fraction of V_MAX (and of DDQ_MAX),
    limit_margin [rad] kept from the joint limits.
    Controller: kp [N m/rad], kd [N m s/rad] (7 each; the nominal gains the log's meta states).
    Sensors: noise on or off; standard deviations q_noise [rad], dq_noise [rad/s], tau_noise [N m]
    of white Gaussian noise (our choice, see docs/sim2real.md).
    sensors: what logs q, dq and tau: "ideal" (the controller's noisy measurements at the control
    ticks) or "panda" (sim2real.logger.apply_logger with PANDA_LOGGER and this seed on the
    noise-free truth: jittered polling, stale rows, gaps, coloured noise; the controller still
    sees the measurements with the white noise above).
    time_step: the plant's step [s]; 1 / log_rate must be a whole multiple of it.
    """

    duration: float = 20.0
    log_rate: float = 1000.0
    end_effector: str = "hand"
    seed: int = 0
    harmonics: int = 5
    base_frequency: float | None = None
    speed_fraction: float = 0.65
    limit_margin: float = 0.2
    kp: tuple[float, ...] = KP
    kd: tuple[float, ...] = KD
    noise: bool = True
    q_noise: float = 1.0e-5
    dq_noise: float = 1.0e-3
    tau_noise: float = 0.05
    time_step: float = 5.0e-4
    sensors: str = "ideal"

    def __post_init__(self) -> None:
        name = "RealityConfig."
        check_number(self.duration, name + "duration", 0.1, 3600.0)
        check_number(self.log_rate, name + "log_rate", 50.0, 10000.0)
        check_choice(self.end_effector, END_EFFECTORS, name + "end_effector")
        check_int(self.seed, name + "seed", 0)
        check_int(self.harmonics, name + "harmonics", 2)
        if self.base_frequency is not None:
            check_number(self.base_frequency, name + "base_frequency", 0.0, low_open=True)
        check_number(self.speed_fraction, name + "speed_fraction", 0.0, 0.9, low_open=True)
        check_number(self.limit_margin, name + "limit_margin", 0.0, 0.5)
        for gains in ("kp", "kd"):
            value = getattr(self, gains)
            if isinstance(value, (str, bytes)) or not isinstance(value, Sequence) or len(value) != N_ARM:
                raise InputError(f"{name}{gains} = {value!r}; expected {N_ARM} gains")
            object.__setattr__(
                self,
                gains,
                tuple(check_number(v, f"{name}{gains}[{j}]", 0.0, low_open=True) for j, v in enumerate(value)),
            )
        if not isinstance(self.noise, bool):
            raise InputError(f"{name}noise = {self.noise!r}; expected True or False")
        for sigma in ("q_noise", "dq_noise", "tau_noise"):
            check_number(getattr(self, sigma), name + sigma, 0.0, 1.0)
        check_number(self.time_step, name + "time_step", 1e-5, 1.0 / self.log_rate)
        check_choice(self.sensors, SENSORS, name + "sensors")
        ratio = 1.0 / (self.log_rate * self.time_step)
        if abs(ratio - round(ratio)) > 1e-6:
            raise InputError(
                f"{name}time_step = {self.time_step:g} s; expected a whole fraction of the "
                f"control period 1 / log_rate = {1.0 / self.log_rate:g} s"
            )
        if self.base_frequency is not None:
            periods = self.duration * self.base_frequency
            if abs(periods - round(periods)) > 1e-6 or round(periods) < 1:
                raise InputError(
                    f"{name}base_frequency = {self.base_frequency:g} Hz; expected a whole number "
                    f"of periods in duration = {self.duration:g} s (e.g. "
                    f"{default_base_frequency(self.duration):g} Hz)"
                )


# ---------------------------------------------------------------------------------------------- effects


def _param_value(name: str, param: Any, value: Any) -> float | list[float]:
    """`value` of `param` (a catalogue EffectParam) checked: one number, or 7 for a per-joint one."""
    label = f"effect {name}.{param.name}"
    if param.per_joint:
        values = list(value) if isinstance(value, (list, tuple, np.ndarray)) else [value] * N_ARM
        if len(values) != N_ARM:
            raise InputError(f"{label} has {len(values)} values; expected 1 or {N_ARM} (one per joint)")
    else:
        if isinstance(value, (list, tuple, np.ndarray)):
            raise InputError(f"{label} = {value!r}; expected one number")
        values = [value]
    out = []
    for v in values:
        if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not math.isfinite(v):
            raise InputError(f"{label} = {v!r}; expected a number in [{param.low:g}, {param.high:g}] {param.unit}")
        if not param.low <= v <= param.high:
            raise InputError(
                f"{label} = {v:g} {param.unit}; expected a value in [{param.low:g}, {param.high:g}] {param.unit}"
            )
        out.append(float(v))
    return out if param.per_joint else out[0]


def resolve_effects(
    effects: Mapping[str, Mapping[str, float | Sequence[float]]] | None,
) -> dict[str, dict[str, float | list[float]]]:
    """`effects` ({effect: {param: value}}, as catalogue.parse_effect_values returns) checked and
    completed: every parameter of each named effect, a missing one at its catalogue `none` value,
    per-joint ones as lists of 7 floats.

    Raises:
        InputError naming the effect (and parameter) for an unknown effect, an effect that is not
        of an arm place (dynamics, actuation, sensing, controller), an unknown parameter, or a
        value outside the parameter's range.
    """
    if effects is None:
        return {}
    if not isinstance(effects, Mapping):
        raise InputError(f"effects = {effects!r}; expected a mapping effect -> {{parameter: value}}")
    out: dict[str, dict[str, float | list[float]]] = {}
    for name, values in effects.items():
        eff = effect(name)
        if name not in ARM_EFFECTS:
            raise InputError(f"effect {name!r} acts in the {eff.place}; an arm log can show only {list(ARM_EFFECTS)}")
        values = {} if values is None else values
        if not isinstance(values, Mapping):
            raise InputError(f"effect {name!r}: values = {values!r}; expected a mapping parameter -> value")
        for pname in values:
            eff.param(pname)
        out[name] = {p.name: _param_value(name, p, values.get(p.name, p.none)) for p in eff.params}
    return out


@dataclasses.dataclass(frozen=True)
class _Truth:
    """The resolved effects as the arrays the simulation uses (7 per joint)."""

    viscous: Array  # D + fv [N m s/rad]
    fc: Array
    v_smooth: float
    fs: Array
    vs: float
    inertia: Array  # the true reflected rotor inertia [kg m^2]
    payload: tuple[float, Array]  # dm [kg], com in panda_link8 [m]
    offset: Array
    delay: float
    gain: Array
    limit: Array  # delivered torque bound [N m]
    backlash: float
    kp_scale: Array
    kd_scale: Array
    notes: tuple[str, ...]
    links: tuple[Array, Array, Array] = (np.ones(N_ARM), np.zeros(N_ARM), np.ones(N_ARM))  # mass, com z, inertia
    joint_inertia: Array = dataclasses.field(default_factory=lambda: np.zeros(N_ARM))  # link side [kg m^2]
    sensor_scale: Array = dataclasses.field(default_factory=lambda: np.ones(N_ARM))
    sensor_delay: float = 0.0  # [s]
    motor_position: bool = False  # q, dq logged (and fed back) on the motor side of the backlash


def _truth(resolved: dict[str, dict[str, Any]]) -> _Truth:
    def get(name: str, param: str) -> Any:
        value = resolved.get(name, {}).get(param, effect(name).param(param).none)
        if effect(name).param(param).per_joint:
            return np.asarray(value, dtype=np.float64) * np.ones(N_ARM)
        return float(value)

    notes = []
    inertia = REFLECTED_INERTIA + get("rotor_inertia", "dI")
    if (neg := inertia < 0).any():
        notes.append(
            f"rotor_inertia: REFLECTED_INERTIA + dI < 0 on joints {(np.flatnonzero(neg) + 1).tolist()}; "
            "the simulated reflected inertia is clipped at 0 there"
        )
        inertia = np.maximum(inertia, 0.0)
    viscous = JOINT_DAMPING + get("viscous", "fv")
    if (neg := viscous < 0).any():
        notes.append(
            f"viscous: the total viscous coefficient D + fv < 0 on joints "
            f"{(np.flatnonzero(neg) + 1).tolist()} (the joint gains energy with speed; the controller "
            "has to hold it)"
        )
    com = np.array([get("payload", f"com_{a}") for a in "xyz"])
    if get("link_inertia", "base") != 0.0:
        raise InputError(
            f"effect link_inertia.base = {get('link_inertia', 'base'):g}; expected 0 (the fit's output): "
            "make a log with mass_scale, com_shift and inertia_scale"
        )
    b_act, b_mot = get("backlash", "b"), get("backlash_motor", "b")
    if b_act > 0.0 and b_mot > 0.0:
        raise InputError(
            f"effects backlash.b = {b_act:g} rad and backlash_motor.b = {b_mot:g} rad name one dead band "
            "twice; expected one of them"
        )
    return _Truth(
        viscous=viscous,
        fc=get("coulomb", "fc"),
        v_smooth=get("coulomb", "v_smooth"),
        fs=get("stribeck", "fs"),
        vs=get("stribeck", "vs"),
        inertia=inertia,
        payload=(get("payload", "dm"), com),
        offset=get("torque_offset", "offset"),
        delay=get("actuation_delay", "delay"),
        gain=get("torque_gain", "k"),
        limit=get("torque_saturation", "s") * TAU_MAX,
        backlash=max(b_act, b_mot),
        kp_scale=get("controller_gain", "kp_scale"),
        kd_scale=get("controller_gain", "kd_scale"),
        notes=tuple(notes),
        links=(
            get("link_inertia", "mass_scale"),
            get("link_inertia", "com_shift"),
            get("link_inertia", "inertia_scale"),
        ),
        joint_inertia=get("joint_inertia", "dJ"),
        sensor_scale=get("torque_scale", "k"),
        sensor_delay=get("torque_delay", "d"),
        motor_position=b_mot > 0.0,
    )


# ---------------------------------------------------------------------------------------------- plant


class _Plant:
    """The true arm: Drake's plant with the true rotor inertia and payload, and its implicit step.

    State: link q, dq (7 each) and, with backlash, the motor side's theta, dtheta (7 each)."""

    def __init__(self, end_effector: str, truth: _Truth, extra_torque: ExtraTorque | None = None) -> None:
        from pydrake.multibody.tree import SpatialInertia, UnitInertia

        self.truth = truth
        self.extra_torque = extra_torque
        self.plant, arm = arm_plant(end_effector)
        self.context = self.plant.CreateDefaultContext()
        self.nq = self.plant.num_positions()
        self.x = np.zeros(2 * self.nq)
        self.x[N_ARM : self.nq] = FINGER_POSITION
        self.plant.SetPositionsAndVelocities(self.context, self.x)
        self.two_mass = truth.backlash > 0.0
        if truth.fs.any():  # G(u) = int_0^u exp(-(s / vs)^2) tanh(s / 0.002) ds, constant beyond the grid
            grid = np.linspace(0.0, 8.0 * truth.vs + 20.0 * STRIBECK_SIGN_VELOCITY, 20001)
            y = np.exp(-((grid / truth.vs) ** 2)) * np.tanh(grid / STRIBECK_SIGN_VELOCITY)
            self._stribeck_grid = grid
            self._stribeck_integral = np.concatenate([[0.0], np.cumsum(0.5 * (y[1:] + y[:-1]) * np.diff(grid))])
        self.notes: list[str] = []
        link_inertia = truth.inertia * (1.0 - BACKLASH_MOTOR_FRACTION) if self.two_mass else truth.inertia
        self.link_inertia = link_inertia  # the reflected inertia the joint carries (before the sensor)
        self.motor_inertia = backlash_motor_inertia(truth.inertia)
        if self.two_mass and (low := truth.inertia * BACKLASH_MOTOR_FRACTION < MOTOR_INERTIA_MIN).any():
            self.notes.append(
                f"backlash: the motor-side inertia is raised to {MOTOR_INERTIA_MIN:g} kg m^2 on joints "
                f"{(np.flatnonzero(low) + 1).tolist()}"
            )
        for j, index in enumerate(self.plant.GetJointActuatorIndices(arm)[:N_ARM]):
            actuator = self.plant.get_joint_actuator(index)
            actuator.SetRotorInertia(self.context, link_inertia[j] / actuator.default_gear_ratio() ** 2)
        self._set_links(arm, truth.links)
        dm, com = truth.payload
        if dm != 0.0:
            flange = self.plant.GetBodyByName("panda_link8", arm)
            joint7 = self.plant.GetJointByName("panda_joint7", arm)
            carried = self.plant.CalcSpatialInertia(
                self.context, flange.body_frame(), self.plant.GetBodiesKinematicallyAffectedBy([joint7.index()])
            )
            _check_payload(
                carried.get_mass(), carried.get_com(), carried.CalcRotationalInertia().CopyToFullMatrix3(), dm, com
            )
            own = flange.default_spatial_inertia()
            m = own.get_mass() + dm
            first = own.get_mass() * own.get_com() + dm * com
            rot = own.CalcRotationalInertia().CopyToFullMatrix3() + dm * (com @ com * np.eye(3) - np.outer(com, com))
            G = UnitInertia(rot[0, 0] / m, rot[1, 1] / m, rot[2, 2] / m, rot[0, 1] / m, rot[0, 2] / m, rot[1, 2] / m)
            flange.SetSpatialInertiaInBodyFrame(self.context, SpatialInertia(m, first / m, G, skip_validity_check=True))

    def _set_links(self, arm: Any, links: tuple[Array, Array, Array]) -> None:
        """Links 1..7's bodies changed: mass times mass_scale, the centre of mass shifted by com_shift
        along the link frame's z, the rotational inertia about the centre of mass times
        mass_scale * inertia_scale (a positive multiple of a physical inertia stays physical)."""
        from pydrake.multibody.tree import RotationalInertia, SpatialInertia

        mass_scale, shift, inertia_scale = links
        for k in range(N_ARM):
            if mass_scale[k] == 1.0 and shift[k] == 0.0 and inertia_scale[k] == 1.0:
                continue
            body = self.plant.GetBodyByName(f"panda_link{k + 1}", arm)
            own = body.default_spatial_inertia()
            m = own.get_mass() * mass_scale[k]
            c = own.get_com() + np.array([0.0, 0.0, shift[k]])
            I_c = (
                own.Shift(own.get_com()).CalcRotationalInertia().CopyToFullMatrix3() * mass_scale[k] * inertia_scale[k]
            )
            body.SetSpatialInertiaInBodyFrame(
                self.context,
                SpatialInertia.MakeFromCentralInertia(
                    m, c, RotationalInertia(I_c[0, 0], I_c[1, 1], I_c[2, 2], I_c[0, 1], I_c[0, 2], I_c[1, 2])
                ),
            )

    def rigid(self, q: Array, v: Array) -> tuple[Array, Array]:
        """M (7, 7) with the link-side rotor inertia and the joint_inertia effect's dJ, and
        c(q, v) - g(q) (7,), fingers held still."""
        x = self.x
        x[:N_ARM] = q
        x[self.nq : self.nq + N_ARM] = v
        p, c = self.plant, self.context
        p.SetPositionsAndVelocities(c, x)
        M = p.CalcMassMatrix(c)[:N_ARM, :N_ARM] + np.diag(self.truth.joint_inertia)
        return M, p.CalcBiasTerm(c)[:N_ARM] - p.CalcGravityGeneralizedForces(c)[:N_ARM]

    def joint_potential(self, u: Array) -> tuple[Array, Array, Array]:
        """P(u), P'(u) = -tau_f(u) and P''(u) per joint, where tau_f is the joint's own torque
        (damping and friction): tau_f = -(D + fv) u - fc tanh(u / v_smooth)
        - fs exp(-(u / vs)^2) tanh(u / 0.002). P is the step's dissipation potential."""
        t = self.truth
        P = 0.5 * t.viscous * u * u
        dP = t.viscous * u
        ddP = t.viscous.copy()
        if t.fc.any():
            x = u / t.v_smooth
            th = np.tanh(x)
            P += t.fc * t.v_smooth * (np.abs(x) + np.log1p(np.exp(-2.0 * np.abs(x))) - math.log(2.0))  # log cosh
            dP += t.fc * th
            ddP += t.fc * (1.0 - th * th) / t.v_smooth
        if t.fs.any():
            e = np.exp(-((u / t.vs) ** 2))
            sg = np.tanh(u / STRIBECK_SIGN_VELOCITY)
            P += t.fs * np.interp(np.abs(u), self._stribeck_grid, self._stribeck_integral)
            dP += t.fs * e * sg
            ddP += t.fs * e * ((1.0 - sg * sg) / STRIBECK_SIGN_VELOCITY - 2.0 * u / t.vs**2 * sg)
        return P, dP, ddP

    def step(self, state: tuple[Array, ...], tau_a: Array, h: float) -> tuple[Array, ...] | None:
        """One backward-Euler step of length h [s] under the actuator torque tau_a (7,); None when
        its Newton iteration does not converge (see _Step)."""
        return _Step(self, state, tau_a, h).solve()


class _Step:
    """One backward-Euler step of the plant: the new velocities u (link) and w (motor, with
    backlash) minimise the step's incremental potential

        phi = 1/2 (u - v)' M (u - v) + h (c - g - tau_a)' u + h sum_j P_j(u_j)
              + stops + [1/2 J_m |w - omega|^2 - h tau_a' w + mesh spring and damper],

    whose gradient is the momentum balance M (u - v) = h (tau_a - c + g + tau_f(u) + ...); the
    positions follow as q + h u. M, c, g are taken at the step's start (semi-implicit), the
    joint torque tau_f (damping, friction), the stops and the mesh at the step's end (implicit), so
    that the stiff friction is stable at any step. Newton's method with an Armijo line search on
    phi always descends, also where the Stribeck hump makes phi non-convex."""

    def __init__(self, plant: _Plant, state: tuple[Array, ...], tau_a: Array, h: float) -> None:
        self.p, self.h, self.tau_a = plant, h, tau_a
        self.q, self.v = state[0], state[1]
        self.M, bias = plant.rigid(self.q, self.v)
        self.two = plant.two_mass
        if plant.extra_torque is not None:
            extra = np.asarray(plant.extra_torque(self.q.copy(), self.v.copy()), dtype=np.float64)
            if extra.shape != (N_ARM,):
                raise InputError(f"extra_torque returned shape {extra.shape}; expected ({N_ARM},)")
            bias = bias - extra
        self.lin = h * bias if self.two else h * (bias - tau_a)
        self.stop_damped = STOP_DAMPING * ((self.q > Q_MAX) | (self.q < Q_MIN))  # engaged at the start
        self.any_stop = bool(self.stop_damped.any())
        if self.two:
            self.theta, self.omega = state[2], state[3]
            self.half = plant.truth.backlash / 2.0
            self.delta0 = self.theta - self.q
            self.damper = BACKLASH_DAMPING * (np.abs(self.delta0) > self.half)  # engaged at the start
            self.J_m = plant.motor_inertia

    def evaluate(self, u: Array, w: Array | None) -> tuple[float, Array, Array | None, Array, Array | None]:
        """phi, its gradients in u and w, the u block's extra Hessian diagonal (true curvature, may
        be negative) and the mesh coupling S (d2/du2 += h S, d2/dudw = -h S, d2/dw2 = J_m + h S)."""
        h = self.h
        P, dP, ddP = self.p.joint_potential(u)
        du = u - self.v
        Mdu = self.M @ du
        phi = 0.5 * du @ Mdu + self.lin @ u + h * P.sum()
        g = Mdu + self.lin + h * dP
        curv = h * ddP
        qn = self.q + h * u
        pen = np.maximum(qn - Q_MAX, 0.0) + np.minimum(qn - Q_MIN, 0.0)
        if self.any_stop or pen.any():
            phi += 0.5 * STOP_STIFFNESS * pen @ pen + 0.5 * h * (self.stop_damped * u) @ u
            g = g + STOP_STIFFNESS * h * pen + h * self.stop_damped * u
            curv = curv + STOP_STIFFNESS * h * h * (pen != 0.0) + h * self.stop_damped
        if not self.two:
            return phi, g, None, curv, None
        dw = w - self.omega
        rel = w - u
        delta = self.delta0 + h * rel
        excess = np.maximum(np.abs(delta) - self.half, 0.0)
        spring = BACKLASH_STIFFNESS * np.sign(delta) * excess + self.damper * rel  # on the link; -spring on the motor
        phi += (
            0.5 * (self.J_m * dw) @ dw
            - h * self.tau_a @ w
            + 0.5 * BACKLASH_STIFFNESS * excess @ excess
            + 0.5 * h * (self.damper * rel) @ rel
        )
        return (
            phi,
            g - h * spring,
            self.J_m * dw - h * self.tau_a + h * spring,
            curv,
            BACKLASH_STIFFNESS * h * (excess > 0.0) + self.damper,
        )

    def direction(self, g: Array, gw: Array | None, curv: Array, S: Array | None) -> tuple[Array, Array | None]:
        """The Newton direction; where the Hessian is not positive definite (the Stribeck hump, a
        negative total viscous coefficient), its negative curvature is dropped."""
        h = self.h
        for c in (curv, np.maximum(curv, 0.0)):
            A = self.M + np.diag(c)
            rhs = -g
            if S is not None:  # eliminate the motor block (diagonal)
                Jww = self.J_m + h * S
                A = A + np.diag(h * S - (h * S) ** 2 / Jww)
                rhs = -g - h * S * gw / Jww
            try:
                L = np.linalg.cholesky(A)
            except np.linalg.LinAlgError:
                continue
            du = np.linalg.solve(L.T, np.linalg.solve(L, rhs))
            return du, (None if S is None else (-gw + h * S * du) / Jww)
        raise np.linalg.LinAlgError("no positive definite Newton matrix")

    def solve(self) -> tuple[Array, ...] | None:
        """The state at the step's end, or None when Newton's method does not converge."""
        u = self.v.copy()
        w = self.omega.copy() if self.two else None
        phi, g, gw, curv, S = self.evaluate(u, w)
        norm = _norm(g, gw)
        tol = _NEWTON_TOL * self.h
        for _ in range(_NEWTON_ITERATIONS):
            if norm <= tol:
                break
            try:
                du, dw = self.direction(g, gw, curv, S)
            except np.linalg.LinAlgError:
                return None
            slope = g @ du + (0.0 if dw is None else gw @ dw)
            s = 1.0
            for _ in range(40):  # Armijo on phi, or a smaller gradient (phi's round-off near the end)
                un, wn = u + s * du, (None if dw is None else w + s * dw)
                phi_n, g_n, gw_n, curv_n, S_n = self.evaluate(un, wn)
                norm_n = _norm(g_n, gw_n)
                if phi_n <= phi + 1e-4 * s * slope or norm_n < norm:
                    break
                s *= 0.5
            else:
                return None
            u, w, phi, g, gw, curv, S, norm = un, wn, phi_n, g_n, gw_n, curv_n, S_n, norm_n
        else:
            return None
        if self.two:
            return self.q + self.h * u, u, self.theta + self.h * w, w
        return self.q + self.h * u, u


def _norm(R: Array, Rw: Array | None) -> float:
    n = float(np.abs(R).max())
    return n if Rw is None else max(n, float(np.abs(Rw).max()))


def _check_payload(mass: float, com: Array, inertia: Array, dm: float, p: Array) -> None:
    """InputError unless the bodies the flange carries (mass [kg], com and rotational inertia about
    the flange origin [kg m^2], flange frame) plus a point mass dm at p stay a physical body."""
    m = mass + dm
    where = f"payload dm = {dm:g} kg at com ({p[0]:g}, {p[1]:g}, {p[2]:g}) m"
    if m <= 1e-6:
        raise InputError(
            f"{where} leaves the bodies the flange carries with mass {m:.4g} kg (they have "
            f"{mass:.4g} kg); expected dm > {-mass:.4g} kg"
        )
    c = (mass * com + dm * p) / m
    I_o = inertia + dm * (p @ p * np.eye(3) - np.outer(p, p))
    I_c = I_o - m * (c @ c * np.eye(3) - np.outer(c, c))
    ev = np.sort(np.linalg.eigvalsh(I_c))
    tol = 1e-9 + 1e-6 * abs(ev).max()
    if ev[0] < -tol or ev[0] + ev[1] < ev[2] - tol:
        raise InputError(
            f"{where} leaves the bodies the flange carries with a non-physical inertia (principal "
            f"moments {np.round(ev, 6).tolist()} kg m^2 about their centre of mass: negative or "
            "breaking the triangle inequality); expected a removal the carried bodies can give up"
        )


# ---------------------------------------------------------------------------------------------- simulation


def make_arm_log(
    effects: Mapping[str, Mapping[str, float | Sequence[float]]] | None = None,
    config: RealityConfig | None = None,
    extra_torque: ExtraTorque | None = None,
) -> RobotLog:
    """Simulate the arm with `effects` and log it.

    Arguments:
        effects: {effect: {parameter: value}} as sim2real.catalogue.parse_effect_values returns;
            only effects of arm places (catalogue.ARM_EFFECTS); a parameter left out takes its
            catalogue `none` value; per-joint values are one number or 7. None: no effect.
        config: the reality's settings (None: RealityConfig()).
        extra_torque: an effect outside the catalogue (to test that the diagnosis calls it
            unexplained): a joint torque [N m] acting on the joints like friction, f(q, dq) -> (7,),
            evaluated at each plant step's start (explicit: it must be smooth, not stiff). Its
            qualified name goes to meta["extra_torque"]. None: none.

    Returns:
        A RobotLog of config.duration * config.log_rate + 1 samples (both ends at rest): time, q, dq
        (measured, with noise; with backlash_motor the motor side's, fed back too), tau (the joint
        torque sensor: the link-side torque, delayed by torque_delay, scaled by torque_scale, plus
        offset and noise), tau_cmd (the controller's command), q_cmd, dq_cmd (the reference),
        phase 0 ("free"); meta: robot, joint_names, units, end_effector, torque_side "link",
        position_side ("motor" with backlash_motor, else "link"),
        controller (law "computed_torque_pd" and the nominal kp, kd), source, truth (the resolved
        effects), reality (the config), notes (clipped values, limit stops, saturation).

    Raises:
        InputError: an unknown or non-arm effect, a value out of range, a payload that leaves no
            physical body (the message names the effect).
        SimulationError: the simulation diverged or a step failed (naming the time and effects).

    Example:
        >>> log = make_arm_log({"coulomb": {"fc": 0.5}}, RealityConfig(duration=2.0))
        >>> log.tau.shape
        (2001, 7)
    """
    cfg = config if config is not None else RealityConfig()
    if not isinstance(cfg, RealityConfig):
        raise InputError(f"config = {cfg!r}; expected a RealityConfig or None")
    resolved = resolve_effects(effects)
    truth = _truth(resolved)
    if extra_torque is not None and not callable(extra_torque):
        raise InputError(f"extra_torque = {extra_torque!r}; expected None or a function (q, dq) -> torque (7,)")
    plant = _Plant(cfg.end_effector, truth, extra_torque)
    run = _Run(cfg, truth, plant, sorted(resolved) + (["extra_torque"] if extra_torque is not None else []))
    run.simulate()
    units = {name: UNITS[name] for name in ("time", "q", "dq", "tau", "tau_cmd", "q_cmd", "dq_cmd")}
    meta = {
        "robot": "panda",
        "joint_names": list(ARM_JOINT_NAMES),
        "units": units,
        "end_effector": cfg.end_effector,
        "torque_side": "link",
        "position_side": "motor" if truth.motor_position else "link",
        "controller": {
            "law": "computed_torque_pd",
            "kp": list(cfg.kp),
            "kd": list(cfg.kd),
            "rate": cfg.log_rate,
            "feedforward": "nominal ArmModel total torque at the reference",
        },
        "source": "goflow simulated reality (sim2real/reality.py)",
        "truth": resolved,
        "reality": config_to_dict(cfg),
        "simulation": {
            "plant_step": run.dt / run.substeps,
            "base_frequency": run.base_frequency,
            "backlash": {
                "motor_fraction": BACKLASH_MOTOR_FRACTION,
                "stiffness": BACKLASH_STIFFNESS,
                "damping": BACKLASH_DAMPING,
            },
        },
        "notes": list(truth.notes) + plant.notes + run.notes(),
    }
    if extra_torque is not None:
        meta["extra_torque"] = ".".join(getattr(extra_torque, key, "?") for key in ("__module__", "__qualname__"))
    if cfg.sensors == "panda":  # the logger records the truth: the measurements less their noise
        nq, ndq, ntau = run.noise
        return apply_logger(
            RobotLog(
                time=run.time,
                q=run.q_meas - nq,
                dq=run.dq_meas - ndq,
                tau=run.tau_meas - ntau,
                tau_cmd=run.tau_cmd,
                q_cmd=run.q_ref,
                dq_cmd=run.dq_ref,
                phase=np.zeros(run.time.shape[0], dtype=np.int64),
                meta=meta,
            ),
            seed=cfg.seed,
        )
    return RobotLog(
        time=run.time,
        q=run.q_meas,
        dq=run.dq_meas,
        tau=run.tau_meas,
        tau_cmd=run.tau_cmd,
        q_cmd=run.q_ref,
        dq_cmd=run.dq_ref,
        phase=np.zeros(run.time.shape[0], dtype=np.int64),
        meta=meta,
    )


class _Run:
    """One simulation: the trajectory, the controller, the actuator, the sensors and the loop."""

    def __init__(self, cfg: RealityConfig, truth: _Truth, plant: _Plant, names: list[str]) -> None:
        self.cfg, self.truth, self.plant, self.names = cfg, truth, plant, names
        n = int(round(cfg.duration * cfg.log_rate)) + 1
        self.dt = 1.0 / cfg.log_rate
        self.time = np.arange(n) * self.dt
        traj = exciting_trajectory(
            cfg.duration, cfg.seed, cfg.harmonics, cfg.base_frequency, cfg.speed_fraction, cfg.limit_margin
        )
        self.base_frequency = traj.omega / (2.0 * math.pi)
        self.q_ref, self.dq_ref, ddq_ref = traj(self.time)
        self.feedforward = ArmModel(cfg.end_effector).terms(self.q_ref, self.dq_ref, ddq_ref).total
        self.kp = truth.kp_scale * np.asarray(cfg.kp)
        self.kd = truth.kd_scale * np.asarray(cfg.kd)
        noise_rng = np.random.default_rng(np.random.SeedSequence([cfg.seed, 1]))
        sigmas = (cfg.q_noise, cfg.dq_noise, cfg.tau_noise) if cfg.noise else (0.0, 0.0, 0.0)
        self.noise = [s * noise_rng.standard_normal((n, N_ARM)) for s in sigmas]
        substeps = int(round(self.dt / cfg.time_step))
        if plant.two_mass:  # the mesh's motor-side mode: at least ~5 steps per radian of its phase
            omega = math.sqrt(BACKLASH_STIFFNESS / float(plant.motor_inertia.min()))
            substeps = min(max(substeps, math.ceil(self.dt * omega / 0.2)), max(substeps, _MAX_SUBSTEPS))
        self.substeps = substeps
        self.lag = truth.delay * cfg.log_rate  # the delay in control ticks
        self.q_meas, self.dq_meas, self.tau_meas, self.tau_cmd, self.delivered = (
            np.empty((n, N_ARM)) for _ in range(5)
        )
        self.stops: dict[int, float] = {}

    def _initial_state(self) -> tuple[Array, ...]:
        q, v = self.q_ref[0].copy(), np.zeros(N_ARM)
        if not self.plant.two_mass:
            return q, v
        # the mesh holds the arm at rest: the spring carries the static joint torque
        _, hold = self.plant.rigid(q, v)  # c - g at rest: the torque that holds the arm
        delta = np.sign(hold) * (self.truth.backlash / 2.0 + np.abs(hold) / BACKLASH_STIFFNESS)
        return q, v, q + delta, np.zeros(N_ARM)

    def _average_delivered(self, a: float, b: float) -> Array:
        """The delivered torque averaged over control-tick times [a, b) (b - a <= 1)."""
        a, b = a - self.lag, b - self.lag
        j = math.floor(a + 1e-9)
        if j + 1 >= b - 1e-9:
            return self.delivered[max(j, 0)]
        w = (j + 1 - a) / (b - a)
        return w * self.delivered[max(j, 0)] + (1.0 - w) * self.delivered[max(j + 1, 0)]

    def _advance(self, state: tuple[Array, ...], a: float, b: float, depth: int = 0) -> tuple[Array, ...]:
        """The state after control-tick times [a, b), halving the step where Newton fails."""
        new = self.plant.step(state, self._average_delivered(a, b), (b - a) * self.dt)
        if new is not None:
            return new
        if depth >= _MAX_SPLITS:
            raise SimulationError(
                f"the simulated arm's implicit step failed at t = {a * self.dt:.4f} s "
                f"(step {(b - a) * self.dt:.3g} s) with effects {self.names}"
            )
        mid = 0.5 * (a + b)
        return self._advance(self._advance(state, a, mid, depth + 1), mid, b, depth + 1)

    def simulate(self) -> None:
        """Run the loop over every control tick, filling the logged arrays."""
        t = self.truth
        state = self._initial_state()
        n = self.time.shape[0]
        nq, ndq, ntau = self.noise
        side = 2 if t.motor_position else 0  # backlash_motor: the encoder (and the controller) on the motor
        for k in range(n):
            q_m = state[side] + nq[k]
            dq_m = state[side + 1] + ndq[k]
            cmd = self.feedforward[k] + self.kp * (self.q_ref[k] - q_m) + self.kd * (self.dq_ref[k] - dq_m)
            self.q_meas[k], self.dq_meas[k], self.tau_cmd[k] = q_m, dq_m, cmd
            self.delivered[k] = np.clip(t.gain * cmd, -t.limit, t.limit)
            if k == n - 1:  # at rest at the end: the sensor carries the held torque
                self.tau_meas[k] = self._link_torque(state, state)
                break
            start = state
            for i in range(self.substeps):
                state = self._advance(state, k + i / self.substeps, k + (i + 1) / self.substeps)
            self._check(state, (k + 1) * self.dt)
            self.tau_meas[k] = self._link_torque(start, state, k)
        # the sensor: its delay (the first reading held before the start), scale, offset and noise
        true = self.tau_meas
        if t.sensor_delay > 0.0:
            src = np.arange(n) - t.sensor_delay * self.cfg.log_rate
            true = interpolate(src, np.arange(n), true)
        self.tau_meas = t.sensor_scale * true + t.offset + ntau

    def _link_torque(self, start: tuple[Array, ...], end: tuple[Array, ...], k: int | None = None) -> Array:
        """What the link-side torque sensor reads over the tick from `start` to `end`: the torque
        the gearbox passes into the link (Franka's tau_J), i.e. the delivered torque less what
        accelerates the reflected rotor inertia (before the sensor); with backlash the link's own
        balance M_links a + c - g - tau_f, the mesh's torque net of the rotor's share."""
        p = self.plant
        a = (end[1] - start[1]) / self.dt
        if not p.two_mass and k is not None:
            return self._average_delivered(k, k + 1) - p.link_inertia * a
        M, bias = p.rigid(start[0], start[1])
        _, dP, _ = p.joint_potential(end[1])  # tau_f = -dP at the step's end (implicit)
        extra = 0.0 if p.extra_torque is None else np.asarray(p.extra_torque(start[0].copy(), start[1].copy()))
        return (M - np.diag(p.link_inertia)) @ a + bias + dP - extra

    def _check(self, state: tuple[Array, ...], time: float) -> None:
        q, v = state[0], state[1]
        finite = all(np.isfinite(s).all() for s in state)
        if not finite or (np.abs(v) > _SPEED_DIVERGED).any():
            j = int(np.argmax(np.where(np.isfinite(v), np.abs(v), np.inf)))
            raise SimulationError(
                f"the simulated arm diverged at t = {time:.4f} s (joint {j + 1}: dq = {v[j]:.4g} "
                f"rad/s) with effects {self.names}; the controller cannot hold the arm with "
                "these values"
            )
        for j in np.flatnonzero((q > Q_MAX) | (q < Q_MIN)):
            self.stops.setdefault(int(j), time)

    def notes(self) -> list[str]:
        """Notes for meta: limit stops reached, actuator saturation."""
        out = [f"joint {j + 1} reached its limit stop at t = {t:.3f} s" for j, t in sorted(self.stops.items())]
        cmd = self.truth.gain * self.tau_cmd
        saturated = np.abs(cmd) > self.truth.limit
        if saturated.any():
            joints = (np.flatnonzero(saturated.any(axis=0)) + 1).tolist()
            out.append(
                f"the actuators saturated on {int(saturated.any(axis=1).sum())} of {cmd.shape[0]} samples "
                f"(joints {joints})"
            )
        return out
