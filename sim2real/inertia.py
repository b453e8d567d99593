"""The links' inertial-parameter regressor of the Panda and its base (identifiable) parameters.

The joint torque of the arm's 7 links is linear in their 10 standard inertial parameters each,
pi_k = (m, m c_x, m c_y, m c_z, I_xx, I_yy, I_zz, I_xy, I_xz, I_yz) in the link's body frame, the
rotational inertia about the body's origin: tau = Y(q, dq, ddq) pi with Y (T, 7, 70). Y is built
from each body's angular velocity w, angular acceleration alpha and origin acceleration minus
gravity a (body frame): the body wrench about its origin is
    n = I alpha + w x (I w) + h x a,    f = m a + alpha x h + w x (w x h)    (h = m c),
mapped to the joints by the body's Jacobian. The kinematics are the plant's own (joint frames and
axes read from sim2real.arm's Drake plant) evaluated by numpy over all samples at once (a 20 s,
1 kHz log takes a fraction of a second). The welded flange (panda_link8) is lumped into link 7.

Only combinations of the 70 parameters reach the torque: `base_parameters` finds them
numerically (QR with column pivoting of Y stacked over random states within the joint limits).
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import qr

from assembly.panda_model import Q_MAX, Q_MIN, V_MAX
from sim2real.arm import N_ARM, ArmModel

__all__ = ["PARAM_NAMES", "LinkRegressor", "BaseParameters", "base_parameters", "link_regressor"]

Array = NDArray[np.float64]
_LOCAL = ("m", "mx", "my", "mz", "Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")
#: The 70 standard parameters' names, link by link: "m3" (kg), "mx3" (kg m), "Ixx3" (kg m^2 about the origin).
PARAM_NAMES: tuple[str, ...] = tuple(f"{p}{k + 1}" for k in range(N_ARM) for p in _LOCAL)
# The inertia basis E_i (I = sum I_i E_i) in _LOCAL[4:]'s order.
_E = np.zeros((6, 3, 3))
for _i, (_a, _b) in enumerate(((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))):
    _E[_i, _a, _b] = _E[_i, _b, _a] = 1.0


class LinkRegressor:
    """The link regressor of `model`'s arm (its 7 links, whatever the end effector)."""

    def __init__(self, model: ArmModel) -> None:
        from pydrake.multibody.tree import RevoluteJoint

        plant, arm = model.plant, model.arm
        context = plant.CreateDefaultContext()
        self.gravity = np.asarray(plant.gravity_field().gravity_vector(), dtype=float)
        base = plant.GetBodyByName("panda_link0", arm)
        X = plant.EvalBodyPoseInWorld(context, base)
        self.R0, self.p0 = X.rotation().matrix(), X.translation()
        self.R_PF, self.p_PF, self.R_CM, self.p_CM, self.axis = [], [], [], [], []
        links = []
        for j in range(N_ARM):
            joint = plant.GetJointByName(f"panda_joint{j + 1}", arm)
            assert isinstance(joint, RevoluteJoint)
            XF = joint.frame_on_parent().GetFixedPoseInBodyFrame()
            XM = joint.frame_on_child().GetFixedPoseInBodyFrame()
            self.R_PF.append(XF.rotation().matrix())
            self.p_PF.append(XF.translation())
            self.R_CM.append(XM.rotation().matrix())
            self.p_CM.append(XM.translation())
            self.axis.append(np.asarray(joint.revolute_axis(), dtype=float))
            links.append(joint.child_body())
        pi = []
        flange = plant.GetBodyByName("panda_link8", arm)
        for k, body in enumerate(links):
            bodies = [body.index()] + ([flange.index()] if k == N_ARM - 1 else [])
            M = plant.CalcSpatialInertia(context, body.body_frame(), bodies)
            m, c = M.get_mass(), M.get_com()
            I = M.CalcRotationalInertia().CopyToFullMatrix3()
            pi.append([m, *(m * c), I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]])
        self.nominal = np.asarray(pi, dtype=float).ravel()  # (70,)

    def kinematics(self, q: Array, dq: Array, ddq: Array) -> tuple[Array, ...]:
        """Per body k (T, 7, ...) in the world: rotation R (3, 3), origin o, joint axis z, joint
        point p, angular velocity w, angular acceleration alpha, origin acceleration minus gravity a."""
        T = q.shape[0]
        R_prev = np.broadcast_to(self.R0, (T, 3, 3))
        o_prev = np.broadcast_to(self.p0, (T, 3))
        w_prev = np.zeros((T, 3))
        al_prev = np.zeros((T, 3))
        a_prev = np.broadcast_to(-self.gravity, (T, 3))
        out = {
            k: np.empty((T, N_ARM) + s)
            for k, s in (
                ("R", (3, 3)),
                ("o", (3,)),
                ("z", (3,)),
                ("p", (3,)),
                ("w", (3,)),
                ("alpha", (3,)),
                ("a", (3,)),
            )
        }
        for j in range(N_ARM):
            u = self.axis[j]
            R_WF = R_prev @ self.R_PF[j]
            p = o_prev + R_prev @ self.p_PF[j]
            z = R_WF @ u
            c, s = np.cos(q[:, j]), np.sin(q[:, j])
            K = np.array([[0, -u[2], u[1]], [u[2], 0, -u[0]], [-u[1], u[0], 0]])
            R_FM = np.eye(3) + s[:, None, None] * K + (1 - c)[:, None, None] * (K @ K)  # Rodrigues
            R_WM = R_WF @ R_FM
            R = R_WM @ self.R_CM[j].T
            o = p - R @ self.p_CM[j]
            w = w_prev + z * dq[:, j : j + 1]
            alpha = al_prev + z * ddq[:, j : j + 1] + np.cross(w_prev, z) * dq[:, j : j + 1]
            r = p - o_prev
            a_p = a_prev + np.cross(al_prev, r) + np.cross(w_prev, np.cross(w_prev, r))
            r = o - p
            a = a_p + np.cross(alpha, r) + np.cross(w, np.cross(w, r))
            for key, v in (("R", R), ("o", o), ("z", z), ("p", p), ("w", w), ("alpha", alpha), ("a", a)):
                out[key][:, j] = v
            R_prev, o_prev, w_prev, al_prev, a_prev = R, o, w, alpha, a
        return tuple(out[k] for k in ("R", "o", "z", "p", "w", "alpha", "a"))

    def __call__(self, q: Array, dq: Array, ddq: Array) -> Array:
        """Y (T, 7, 70): the joint torques per unit of each standard parameter at (T, 7) q, dq, ddq."""
        q, dq, ddq = (np.atleast_2d(np.asarray(x, dtype=float)) for x in (q, dq, ddq))
        R, o, z, p, w, alpha, a = self.kinematics(q, dq, ddq)
        T = q.shape[0]
        Rt = np.swapaxes(R, -1, -2)
        wb, alb, ab = (np.einsum("tkij,tkj->tki", Rt, x) for x in (w, alpha, a))  # body frame
        # body wrench (n, f) about the origin per unit parameter, body frame: (T, 7, 10, 3) each
        n = np.zeros((T, N_ARM, 10, 3))
        f = np.zeros((T, N_ARM, 10, 3))
        f[:, :, 0] = ab
        for i in range(3):
            e = np.zeros(3)
            e[i] = 1.0
            eb = np.broadcast_to(e, ab.shape)
            f[:, :, 1 + i] = np.cross(alb, eb) + np.cross(wb, np.cross(wb, eb))
            n[:, :, 1 + i] = np.cross(eb, ab)
        for i in range(6):
            Ea = alb @ _E[i].T
            Ew = wb @ _E[i].T
            n[:, :, 4 + i] = Ea + np.cross(wb, Ew)
        nW = np.einsum("tkij,tkpj->tkpi", R, n)
        fW = np.einsum("tkij,tkpj->tkpi", R, f)
        Y = np.zeros((T, N_ARM, N_ARM, 10))  # joint, body, param
        for jt in range(N_ARM):
            lever = o[:, jt:, :] - p[:, jt : jt + 1, :]  # (T, bodies >= jt, 3)
            zc = np.cross(np.broadcast_to(z[:, jt : jt + 1, :], lever.shape), lever)
            Y[:, jt, jt:] = np.einsum("tkpi,ti->tkp", nW[:, jt:], z[:, jt]) + np.einsum("tkpi,tki->tkp", fW[:, jt:], zc)
        return Y.reshape(T, N_ARM, N_ARM * 10)


@functools.lru_cache(maxsize=8)
def link_regressor(end_effector: str = "none") -> LinkRegressor:
    """The (cached) link regressor of the arm with `end_effector` (the links are the same for all)."""
    return LinkRegressor(ArmModel(end_effector))


@dataclasses.dataclass(frozen=True)
class BaseParameters:
    """The identifiable combinations of the 70 standard parameters.

    independent: the P standard parameters whose regressor columns span Y's column space (their
    columns are the base regressor); beta (P, 70): base parameter i = beta[i] @ pi (1 on its own
    parameter, the dependent ones it absorbs elsewhere); groups: per base parameter the
    standard parameters it combines, as "name" or "coef*name"; rank tolerance as used."""

    independent: tuple[int, ...]
    beta: Array
    groups: tuple[str, ...]

    @property
    def count(self) -> int:
        return len(self.independent)

    def nominal(self, pi: Array) -> Array:
        """The base parameters (P,) of the standard parameters `pi` (70,)."""
        return self.beta @ pi


@functools.lru_cache(maxsize=4)
def base_parameters(end_effector: str = "none", n_states: int = 300, seed: int = 0) -> BaseParameters:
    """The base parameters of the links: QR with column pivoting of Y stacked over `n_states`
    random states (q uniform within the joint limits, dq within V_MAX, ddq within 10 rad/s^2).
    A column is independent where |R_ii| > 1e-8 |R_00| (the column scaling is normalised first)."""
    reg = link_regressor(end_effector)
    rng = np.random.default_rng(seed)
    q = rng.uniform(Q_MIN, Q_MAX, (n_states, N_ARM))
    dq = rng.uniform(-1, 1, (n_states, N_ARM)) * V_MAX
    ddq = rng.uniform(-10, 10, (n_states, N_ARM))
    W = reg(q, dq, ddq).reshape(-1, 70)
    scale = np.linalg.norm(W, axis=0)
    scale[scale == 0] = 1.0
    _, Rm, piv = qr(W / scale, mode="economic", pivoting=True)
    d = np.abs(np.diag(Rm))
    r = int(np.sum(d > 1e-8 * d[0]))
    ind, dep = np.sort(piv[:r]), piv[r:]
    # W[:, dep] = W[:, ind] @ B  (least squares; exact up to round-off)
    B, *_ = np.linalg.lstsq(W[:, ind], W[:, dep], rcond=None)
    B[np.abs(B) < 1e-9] = 0.0
    beta = np.zeros((r, 70))
    beta[np.arange(r), ind] = 1.0
    beta[:, dep] = B
    groups = []
    for i in range(r):
        parts = [PARAM_NAMES[ind[i]]] + [f"{B[i, c]:+.4g}*{PARAM_NAMES[d_]}" for c, d_ in enumerate(dep) if B[i, c]]
        groups.append(" ".join(parts))
    return BaseParameters(tuple(int(i) for i in ind), beta, tuple(groups))
