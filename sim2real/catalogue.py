"""The effect catalogue: the unmodelled effects the diagnosis can name, with their parameters.

Each effect has a name, a physical meaning, the place it acts (which decides the log channels it
can show in) and parameters with units, ranges and the value that means "no effect". The
simulated reality (sim2real/reality.py) implements every arm effect in the dynamics; the fits
(sim2real/effects.py) give each its prediction of the residuals. Both read this table, so a name
means the same effect everywhere.

Places and the channels they reach (see docs/sim2real.md, "Channels"):
- "dynamics": a torque in the joint's own balance (friction, inertia, payload); it shows in the
  measured torque against inverse dynamics (channel "tau") and in the command channel ("cmd").
- "actuation": between the commanded torque and the torque the joint receives; it shows only in
  the command channel.
- "sensing": in the torque sensor; it shows only in the "tau" channel.
- "controller": in the control law; it shows in the controller channel ("ctrl").
- "contact", "grasp": in the gear/shaft contact or the fingers' hold (station logs).
- "perception": in the camera (station logs with images).
"""

from __future__ import annotations

import dataclasses
from typing import Literal

from goflow_common.errors import InputError

__all__ = ["EffectParam", "Effect", "CATALOGUE", "ARM_EFFECTS", "effect", "parse_effect_values"]

Place = Literal["dynamics", "actuation", "sensing", "controller", "contact", "grasp", "perception"]


@dataclasses.dataclass(frozen=True)
class EffectParam:
    """One parameter: `per_joint` parameters hold one value per joint, others one value.

    low/high bound the fit and the values `make-log` accepts; `none` is the value meaning no
    effect (the nominal model)."""

    name: str
    unit: str
    low: float
    high: float
    none: float
    per_joint: bool = False
    meaning: str = ""


@dataclasses.dataclass(frozen=True)
class Effect:
    name: str
    place: Place
    meaning: str
    params: tuple[EffectParam, ...]

    def param(self, name: str) -> EffectParam:
        for p in self.params:
            if p.name == name:
                return p
        raise InputError(
            f"effect {self.name!r} has no parameter {name!r}; expected one of {[p.name for p in self.params]}"
        )


_J = True  # per joint

CATALOGUE: dict[str, Effect] = {
    e.name: e
    for e in (
        Effect(
            "coulomb",
            "dynamics",
            "Coulomb friction in the joint: a torque of constant size opposing the joint velocity, "
            "tau = -fc tanh(dq / v_smooth)",
            (
                EffectParam("fc", "N m", 0.0, 5.0, 0.0, _J, "Coulomb friction torque"),
                EffectParam(
                    "v_smooth", "rad/s", 0.002, 0.5, 0.02, False, "velocity over which the friction changes sign"
                ),
            ),
        ),
        Effect(
            "stribeck",
            "dynamics",
            "Stribeck (breakaway) friction: extra friction near rest that decays with speed, "
            "tau = -fs exp(-(dq / vs)^2) tanh(dq / 0.002 rad/s)",
            (
                EffectParam("fs", "N m", 0.0, 5.0, 0.0, _J, "breakaway friction above the Coulomb level"),
                EffectParam("vs", "rad/s", 0.005, 0.5, 0.05, False, "Stribeck velocity"),
            ),
        ),
        Effect(
            "viscous",
            "dynamics",
            "viscous friction beyond the model's joint damping, tau = -fv dq",
            (EffectParam("fv", "N m s/rad", -0.6, 3.0, 0.0, _J, "extra viscous coefficient"),),
        ),
        Effect(
            "rotor_inertia",
            "dynamics",
            "reflected rotor inertia other than the model's, tau = dI ddq (negative: the model "
            "has more than the joint)",
            (EffectParam("dI", "kg m^2", -0.7, 0.7, 0.0, _J, "reflected inertia error"),),
        ),
        Effect(
            "payload",
            "dynamics",
            "a mass at the flange other than the model's (the hand, a held gear or a tool): a "
            "point mass dm at offset com in the flange frame (panda_link8); dm < 0 removes mass",
            (
                EffectParam("dm", "kg", -1.5, 3.0, 0.0, False, "mass error"),
                EffectParam("com_x", "m", -0.15, 0.15, 0.0, False, "its centre of mass, flange x"),
                EffectParam("com_y", "m", -0.15, 0.15, 0.0, False, "flange y"),
                EffectParam("com_z", "m", -0.15, 0.25, 0.0, False, "flange z"),
            ),
        ),
        Effect(
            "torque_offset",
            "sensing",
            "a constant offset of the joint torque sensor, tau_measured = tau + offset",
            (EffectParam("offset", "N m", -3.0, 3.0, 0.0, _J, "sensor offset"),),
        ),
        Effect(
            "actuation_delay",
            "actuation",
            "the joint receives the commanded torque late, tau(t) = tau_cmd(t - delay)",
            (EffectParam("delay", "s", 0.0, 0.03, 0.0, False, "transport delay"),),
        ),
        Effect(
            "torque_gain",
            "actuation",
            "the joint receives a scaled commanded torque (motor constant error), tau = k tau_cmd",
            (EffectParam("k", "1", 0.6, 1.4, 1.0, _J, "torque gain"),),
        ),
        Effect(
            "torque_saturation",
            "actuation",
            "the actuators saturate below their rated torque, tau = clip(tau_cmd, +-s TAU_MAX)",
            (EffectParam("s", "1", 0.05, 1.0, 1.0, False, "saturation level as a fraction of TAU_MAX"),),
        ),
        Effect(
            "backlash",
            "actuation",
            "gear backlash: the motor turns through a dead band of width b before it drives the "
            "link again after a torque reversal (a two-mass transmission with a dead zone)",
            (EffectParam("b", "rad", 0.0, 0.02, 0.0, False, "dead band width (motor side, reflected)"),),
        ),
        Effect(
            "controller_gain",
            "controller",
            "the controller runs stiffness and damping gains other than the configured ones, "
            "tau_cmd = ... + kp_scale Kp (q_cmd - q) + kd_scale Kd (dq_cmd - dq)",
            (
                EffectParam("kp_scale", "1", 0.3, 3.0, 1.0, _J, "stiffness gain ratio"),
                EffectParam("kd_scale", "1", 0.3, 3.0, 1.0, _J, "damping gain ratio"),
            ),
        ),
        Effect(
            "link_inertia",
            "dynamics",
            "the links' inertial parameters other than the model's (mass, centre of mass, rotational "
            "inertia of links 1..7); made as per-link changes, fitted as the identifiable base-parameter "
            "corrections (sim2real/inertia.py)",
            (
                EffectParam(
                    "mass_scale",
                    "1",
                    0.5,
                    1.5,
                    1.0,
                    _J,
                    "link mass ratio (the rotational inertia about the centre of mass scales with it)",
                ),
                EffectParam(
                    "com_shift", "m", -0.05, 0.05, 0.0, _J, "centre-of-mass shift along the link frame's z axis"
                ),
                EffectParam(
                    "inertia_scale",
                    "1",
                    0.5,
                    1.5,
                    1.0,
                    _J,
                    "ratio of the rotational inertia about the centre of mass (on top of mass_scale)",
                ),
                EffectParam(
                    "base",
                    "kg, kg m, kg m^2",
                    -20.0,
                    20.0,
                    0.0,
                    False,
                    "the fitted base-parameter corrections (fit output only; make-log takes the three above)",
                ),
            ),
        ),
        Effect(
            "torque_scale",
            "sensing",
            "a scale error of the joint torque sensor, tau_measured = k tau",
            (EffectParam("k", "1", 0.8, 1.2, 1.0, _J, "sensor scale"),),
        ),
        Effect(
            "torque_delay",
            "sensing",
            "the logged torque lags the logged state, tau_measured(t) = tau(t - d) (one delay for all joints, "
            "as a logger produces)",
            (EffectParam("d", "s", 0.0, 0.02, 0.0, False, "torque delay"),),
        ),
        Effect(
            "joint_inertia",
            "dynamics",
            "an acceleration-proportional link-side torque the model lacks, tau = dJ ddq (behind the "
            "link-side sensor, unlike rotor_inertia)",
            (EffectParam("dJ", "kg m^2", -0.5, 0.5, 0.0, _J, "link-side joint inertia error"),),
        ),
        Effect(
            "backlash_motor",
            "sensing",
            'gear backlash seen through a motor-side position encoder (meta position_side "motor"): the '
            "logged position is the motor's, which moves across the dead band b against the link's at "
            "torque reversals (the backlash effect's two-mass transmission)",
            (EffectParam("b", "rad", 0.0, 0.02, 0.0, False, "dead band width (motor side, reflected)"),),
        ),
        Effect(
            "shaft_friction",
            "contact",
            "friction between a gear's bore and its shaft other than the model's",
            (EffectParam("mu", "1", 0.05, 1.5, 0.0, False, "Coulomb friction coefficient (0: nominal)"),),
        ),
        Effect(
            "hydroelastic_modulus",
            "contact",
            "the hydroelastic modulus of the gear/shaft contact scaled",
            (EffectParam("scale", "1", 0.1, 10.0, 1.0, False, "modulus ratio"),),
        ),
        Effect(
            "hydroelastic_dissipation",
            "contact",
            "the Hunt-Crossley dissipation of the gear/shaft contact other than the model's",
            (EffectParam("d", "s/m", 0.0, 50.0, 0.0, False, "dissipation (0: nominal)"),),
        ),
        Effect(
            "grasp_slip",
            "grasp",
            "the fingers hold the gear with less friction, so it slips and tilts under load",
            (EffectParam("mu_scale", "1", 0.05, 1.0, 1.0, False, "finger friction ratio"),),
        ),
        Effect(
            "camera_offset",
            "perception",
            "the camera sits off its calibrated pose: a translation in the camera frame",
            (
                EffectParam("dx", "m", -0.03, 0.03, 0.0, False, ""),
                EffectParam("dy", "m", -0.03, 0.03, 0.0, False, ""),
                EffectParam("dz", "m", -0.03, 0.03, 0.0, False, ""),
            ),
        ),
    )
}

#: The effects an arm log (no contact, no camera) can show.
ARM_EFFECTS: tuple[str, ...] = tuple(
    name for name, e in CATALOGUE.items() if e.place in ("dynamics", "actuation", "sensing", "controller")
)


def effect(name: str) -> Effect:
    """The catalogue entry `name`; InputError listing the known names otherwise."""
    if name not in CATALOGUE:
        raise InputError(f"effect = {name!r}; expected one of {sorted(CATALOGUE)}")
    return CATALOGUE[name]


def parse_effect_values(specs: list[str], n_joints: int = 7) -> dict[str, dict[str, list[float] | float]]:
    """Parse command-line effect settings into {effect: {param: value}}.

    Each spec is NAME=VALUE (the effect's first parameter) or NAME.PARAM=VALUE; a per-joint value
    is one number (all joints) or n_joints comma-separated numbers. Values outside the parameter's
    range raise InputError naming the spec and the range."""
    out: dict[str, dict[str, list[float] | float]] = {}
    for spec in specs:
        if "=" not in spec:
            raise InputError(f"--effect {spec!r}; expected NAME=VALUE or NAME.PARAM=VALUE")
        key, text = spec.split("=", 1)
        name, _, pname = key.partition(".")
        eff = effect(name.strip())
        par = eff.param(pname.strip()) if pname else eff.params[0]
        try:
            values = [float(v) for v in text.split(",")]
        except ValueError:
            raise InputError(f"--effect {spec!r}: {text!r} is not a number or a comma-separated list") from None
        if par.per_joint:
            if len(values) == 1:
                values = values * n_joints
            if len(values) != n_joints:
                raise InputError(f"--effect {spec!r}: {len(values)} values; expected 1 or {n_joints} (one per joint)")
        elif len(values) != 1:
            raise InputError(f"--effect {spec!r}: {par.name} takes one value, got {len(values)}")
        for v in values:
            if not (par.low <= v <= par.high) or v != v:
                raise InputError(
                    f"--effect {spec!r}: {par.name} = {v:g} {par.unit}; expected a value in "
                    f"[{par.low:g}, {par.high:g}] {par.unit}"
                )
        out.setdefault(eff.name, {})[par.name] = values if par.per_joint else values[0]
    return out
