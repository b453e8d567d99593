"""Force sensing for insertion: the Panda's estimated external wrench at the tool, as libfranka
reports it (`O_F_ext_hat_K`), with the errors such an estimate has.

libfranka has no wrist force/torque sensor: it estimates the external joint torques as the
measured link-side torques minus its dynamic model, tau_ext = tau_J - tau_model(q, dq), and maps
them to the tool with the pseudo-inverse of the Jacobian's transpose, F = pinv(J^T) tau_ext (J the
tool's 6 x 7 spatial-velocity Jacobian; F = [torque; force] in the base frame). We simulate it the
same way: tau_ext is what contact puts on the arm's joints (the station's "tau_contact" port,
with the tool's Jacobian on "tool_jacobian"), and the estimate carries, per joint,

- the torque sensors' noise: the in-band noise floor of the real Panda log (Gaz et al. 2019,
  `goflow diagnose --log data/panda-gaz2019`: 0.006-0.106 N m below 7.6 Hz, docs/sim2real.md),
  white over the control period's band;
- the dynamic model's error: a bias drawn per episode with the real log's residual after the
  identified effects (0.047-0.235 N m, same table), what an identified model still leaves; the
  model of a friction that changes with the motion's direction is not modelled here.

`PANDA_WRENCH` holds these numbers, `IDEAL_WRENCH` none. The policy sees four components, those
of the tool pose's dofs: the force (x, y, z) and the torque about z, in the base frame.

    sensor = WrenchSensor(PANDA_WRENCH, control_dt=0.04)
    sensor.reset(rng)                                   # draws the episode's bias
    f = sensor.measure(tau_ext, J, rng)                 # (4,): Fx, Fy, Fz [N], Mz [N m]
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import Frame, ModelInstanceIndex
from pydrake.systems.framework import Context, LeafSystem

from assembly.impedance import arm_velocity_columns, tool_jacobian
from goflow_common.checks import check_finite_array, check_number

__all__ = [
    "ExternalWrenchEstimate",
    "IDEAL_WRENCH",
    "PANDA_WRENCH",
    "ToolJacobian",
    "WRENCH_MODELS",
    "WrenchSensor",
    "WrenchSensorModel",
    "joint_torque_of",
    "observed_wrench",
]

N_JOINTS = 7
#: Rows of the spatial force [torque; force] the policy sees, in its order: Fx, Fy, Fz, Mz.
_ROWS = (3, 4, 5, 2)


@dataclass(frozen=True)
class WrenchSensorModel:
    """The errors of an external-wrench estimate from joint torques. noise_std: per joint, the
    torque noise's std [N m] within `noise_band` [Hz] (white within it); bias_std: per joint, the
    std [N m] of the model error, drawn once per episode."""

    name: str
    noise_std: tuple[float, ...] = (0.0,) * N_JOINTS
    noise_band: float = 1.0
    bias_std: tuple[float, ...] = (0.0,) * N_JOINTS

    def __post_init__(self) -> None:
        for field in ("noise_std", "bias_std"):
            check_finite_array(getattr(self, field), f"{self.name}: {field}", (N_JOINTS,), low=0.0)
        check_number(self.noise_band, f"{self.name}: noise_band", 0.0, low_open=True)

    def noise_std_at(self, control_dt: float) -> NDArray[np.float64]:
        """Per joint, the noise std [N m] of one sample at period `control_dt` [s]: the band's std
        scaled to the sample's band, 1 / (2 control_dt)."""
        check_number(control_dt, "control_dt", 0.0, low_open=True)
        return np.asarray(self.noise_std) * np.sqrt(1.0 / (2.0 * control_dt) / self.noise_band)


#: libfranka's estimate on a Panda, its errors from the real log (module docstring).
PANDA_WRENCH = WrenchSensorModel(
    "panda",
    noise_std=(0.106, 0.103, 0.071, 0.060, 0.006, 0.009, 0.008),
    noise_band=7.6,
    bias_std=(0.153, 0.235, 0.146, 0.159, 0.072, 0.052, 0.047),
)
IDEAL_WRENCH = WrenchSensorModel("ideal")
WRENCH_MODELS = {m.name: m for m in (PANDA_WRENCH, IDEAL_WRENCH)}


def observed_wrench(F: ArrayLike) -> NDArray[np.float64]:
    """The policy's four components (Fx, Fy, Fz [N], Mz [N m]) of a spatial force [torque; force] (6,)."""
    return np.asarray(F, dtype=float)[list(_ROWS)]


def joint_torque_of(J: ArrayLike, wrench: ArrayLike) -> NDArray[np.float64]:
    """The joint torques J^T F (7,) an arm with Jacobian `J` (6, 7) feels from the four observed
    components (Fx, Fy, Fz [N], Mz [N m]) of an external wrench on its tool (the others zero):
    how a tool without an arm (the fast insertion model) feeds `WrenchSensor.measure`."""
    fx, fy, fz, mz = np.asarray(wrench, dtype=float)
    return np.asarray(J, dtype=float).T @ np.array([0.0, 0.0, mz, fx, fy, fz])


class WrenchSensor:
    """One arm's external-wrench estimate under `model` at the policy's period `control_dt`.
    `reset(rng)` draws the episode's bias; `measure(tau_ext, J, rng)` gives the four observed
    components for the true external joint torques `tau_ext` (7,) at Jacobian `J` (6, 7)."""

    def __init__(self, model: WrenchSensorModel, control_dt: float) -> None:
        self.model = model
        self._noise = model.noise_std_at(control_dt)
        self.bias = np.zeros(N_JOINTS)

    def reset(self, rng: np.random.Generator) -> None:
        self.bias = rng.normal(0.0, 1.0, N_JOINTS) * np.asarray(self.model.bias_std)

    def measure(self, tau_ext: ArrayLike, J: ArrayLike, rng: np.random.Generator) -> NDArray[np.float64]:
        tau = np.asarray(tau_ext, dtype=float) + self.bias + self._noise * rng.standard_normal(N_JOINTS)
        J = np.asarray(J, dtype=float)
        if J.shape != (6, N_JOINTS) or tau.shape != (N_JOINTS,):
            raise ValueError(f"J {J.shape} and tau_ext {tau.shape}; expected (6, {N_JOINTS}) and ({N_JOINTS},)")
        return observed_wrench(np.linalg.lstsq(J.T, tau, rcond=None)[0])


class ToolJacobian(LeafSystem):
    """The tool's Jacobian as a port: input "arm_state" (2 n: q, v), output "J" (6 n, row-major
    (6, n): `assembly.impedance.tool_jacobian` of `plant`'s `tool` frame with respect to `arm`'s velocities). `plant`
    is a model of the arm alone (the controller's), owned by this system."""

    def __init__(self, plant: MultibodyPlant, arm: ModelInstanceIndex, tool: Frame) -> None:
        super().__init__()
        self.set_name("tool_jacobian")
        self._plant, self._arm, self._tool = plant, arm, tool
        self._columns = arm_velocity_columns(plant, arm)
        self._context = plant.CreateDefaultContext()
        self._n = plant.num_positions(arm)
        self.DeclareVectorInputPort("arm_state", 2 * self._n)
        self.DeclareVectorOutputPort("J", 6 * self._n, self._calc)

    def _calc(self, context: Context, output) -> None:
        x = self.get_input_port(0).Eval(context)
        self._plant.SetPositions(self._context, self._arm, x[: self._n])
        output.SetFromVector(tool_jacobian(self._plant, self._context, self._tool, self._columns).reshape(-1))


class ExternalWrenchEstimate(LeafSystem):
    """The station's external-wrench estimate as a port: inputs "tau_contact" (7) and
    "tool_jacobian" (42, row-major (6, 7)), output "external_wrench" (4: Fx, Fy, Fz [N], Mz [N m])
    through a `WrenchSensor` of `model` at period `control_dt`. The bias is drawn once from `seed`;
    the noise of a sample from (seed, the context's time in microseconds), so the same time gives
    the same reading."""

    def __init__(self, model: WrenchSensorModel, control_dt: float, seed: int) -> None:
        super().__init__()
        self.set_name("external_wrench_estimate")
        self.sensor = WrenchSensor(model, control_dt)
        self._seed = int(seed)
        self.sensor.reset(np.random.default_rng([self._seed]))
        self.DeclareVectorInputPort("tau_contact", N_JOINTS)
        self.DeclareVectorInputPort("tool_jacobian", 6 * N_JOINTS)
        self.DeclareVectorOutputPort("external_wrench", 4, self._calc)

    def _calc(self, context: Context, output) -> None:
        rng = np.random.default_rng([self._seed, int(round(context.get_time() * 1e6))])
        J = self.get_input_port(1).Eval(context).reshape(6, N_JOINTS)
        output.SetFromVector(self.sensor.measure(self.get_input_port(0).Eval(context), J, rng))
