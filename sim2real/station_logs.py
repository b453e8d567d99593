"""Station insertion logs: "real" logs of the insertion skill made with withheld contact or grasp
effects, their open-loop replay in the station, and the skill's success rate under the effects.

The effects are the catalogue's "contact" and "grasp" entries (sim2real.catalogue), put into the
physics of the Panda station (assembly.station) through two config hooks, never painted onto a log:

- shaft_friction (mu): every gear, the plate and the shafts get Coulomb friction mu (static =
  dynamic), so the gear slides on its shaft and the plate at exactly mu (nominal ~0.32);
- hydroelastic_modulus (scale): the plate's and shafts' hydroelastic modulus times scale (the
  gears are rigid hydroelastic, so the compliant side sets the contact's stiffness);
- hydroelastic_dissipation (d): Hunt-Crossley dissipation d [s/m] on gears, plate and shafts
  (nominal 20 s/m);
- grasp_slip (mu_scale): the gear is no longer welded to the hand; it hangs from the tool on three
  friction-limited springs (tilt about the finger axis, slides across the fingers and along the
  gear's axis; assembly.world.GraspHold) whose force and torque limits are mu_scale times the
  nominal hold's (40 N, 0.13 N m); a slip stays (the springs' rest points follow it). mu_scale = 1
  (the catalogue's "none") is the nominal weld.

Each effect's "none" value (catalogue) gives the nominal station. The phase segmentation rule and
the measured numbers are in docs/sim2real.md, "Contact and insertion logs".
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping
from typing import Any

import gymnasium
import numpy as np
from numpy.typing import NDArray
from pydrake.math import RigidTransform

import assembly.envs  # noqa: F401  (registers goflow/GearInsertion-v0)
from assembly.envs.drake_sim import advance
from assembly.gearset import GEAR_BORE_CHAMFER, GEAR_BORE_RADIUS, SHAFT_CHAMFER, SHAFT_HEIGHT, gear_spec
from assembly.samplers import FullDR, NoDR
from assembly.world import ContactOverrides, GraspHold
from goflow_common.checks import check_choice, check_finite_array, check_int
from goflow_common.errors import InputError
from sim2real.catalogue import CATALOGUE
from sim2real.log import PHASES, UNITS, RobotLog

__all__ = [
    "STATION_EFFECTS",
    "NOMINAL_HOLD",
    "CONTACT_FORCE_MIN",
    "APPROACH_HEIGHT",
    "APPROACH_RADIUS",
    "INSERTION_DEPTH",
    "CONTACT_CASE",
    "GRASP_CASE",
    "check_station_effects",
    "station_physics",
    "make_insertion_env",
    "make_insertion_log",
    "replay_insertion",
    "skill_success",
    "geometry_phases",
    "phase_residuals",
    "with_sensor_noise",
]

#: The catalogue effects the station implements.
STATION_EFFECTS: tuple[str, ...] = tuple(n for n, e in CATALOGUE.items() if e.place in ("contact", "grasp"))
#: The hold that grasp_slip scales (mu_scale = 1 is the nominal weld, not this hold).
NOMINAL_HOLD = GraspHold()
#: [N] a contact force on the gear above this counts as touching (phase "contact").
CONTACT_FORCE_MIN = 0.1
#: [m] the gear's bottom within this height above the shaft top and its axis within APPROACH_RADIUS
#: of the shaft's: phase "approach" (else "free").
APPROACH_HEIGHT = 0.02
APPROACH_RADIUS = 0.02
#: [m] how far the gear's bottom must be below the shaft top for "insertion": past the shaft's and
#: the bore's 1 mm chamfers (a gear jammed on the chamfers is still in "contact").
INSERTION_DEPTH = SHAFT_CHAMFER + GEAR_BORE_CHAMFER

#: The contact validation case: visible in the contact phase (tool height 8 mm off the nominal
#: replay) and the skill's success 0.3 against 1.0 nominal (medium gear, 10 episodes, docs/sim2real.md).
CONTACT_CASE: dict[str, dict[str, float]] = {"shaft_friction": {"mu": 1.0}}
#: The grasp case: the gear slips ~2.5 mm up the fingers while seating (success 0.9 against 1.0).
GRASP_CASE: dict[str, dict[str, float]] = {"grasp_slip": {"mu_scale": 0.1}}

_ARM_JOINTS = [f"panda_joint{i}" for i in range(1, 8)]


# -- effects -> physics ---------------------------------------------------------------------


def check_station_effects(effects: Mapping[str, Any] | None) -> dict[str, dict[str, float]]:
    """The effects as {name: {param: value}} with every parameter present, checked.

    `effects` maps an effect of STATION_EFFECTS to {param: value} (missing parameters take their
    "none" value) or to a bare number (its one parameter). A value must be the parameter's "none"
    or lie in the catalogue's [low, high]. InputError names the bad effect, parameter or value."""
    if effects is None:
        return {}
    if not isinstance(effects, Mapping):
        raise InputError(f"effects = {effects!r}; expected a mapping {{effect: {{param: value}}}}")
    out: dict[str, dict[str, float]] = {}
    for name, given in effects.items():
        if name not in STATION_EFFECTS:
            raise InputError(
                f"effect {name!r} is not a station effect; expected one of "
                f"{list(STATION_EFFECTS)} (arm effects: sim2real.reality)"
            )
        eff = CATALOGUE[name]
        values = {eff.params[0].name: given} if not isinstance(given, Mapping) else dict(given)
        for pname in values:
            eff.param(pname)  # InputError naming the parameters
        out[name] = {}
        for par in eff.params:
            v = values.get(par.name, par.none)
            if (
                isinstance(v, bool)
                or not isinstance(v, (int, float, np.integer, np.floating))
                or not (v == par.none or par.low <= v <= par.high)
            ):
                raise InputError(
                    f"effects[{name!r}][{par.name!r}] = {v!r}; expected {par.none:g} (no "
                    f"effect) or a number in [{par.low:g}, {par.high:g}] {par.unit}"
                )
            out[name][par.name] = float(v)
    return out


def station_physics(effects: Mapping[str, Any] | None) -> dict[str, ContactOverrides | GraspHold | None]:
    """GearInsertionConfig overrides {"contact": ContactOverrides | None, "grasp_hold": GraspHold |
    None} that put `effects` (check_station_effects) into the panda station; {} effects (or every
    effect at its "none") give both None, the nominal station."""
    e = check_station_effects(effects)
    mu = e.get("shaft_friction", {}).get("mu", 0.0)
    scale = e.get("hydroelastic_modulus", {}).get("scale", 1.0)
    d = e.get("hydroelastic_dissipation", {}).get("d", 0.0)
    contact = None
    if mu != 0.0 or scale != 1.0 or d != 0.0:
        contact = ContactOverrides(mu=mu or None, modulus_scale=scale, dissipation=d or None)
    s = e.get("grasp_slip", {}).get("mu_scale", 1.0)
    hold = (
        None
        if s == 1.0
        else dataclasses.replace(
            NOMINAL_HOLD, force_limit=s * NOMINAL_HOLD.force_limit, torque_limit=s * NOMINAL_HOLD.torque_limit
        )
    )
    return {"contact": contact, "grasp_hold": hold}


def _load(skill: Any, gear: str):
    from learning.skill_file import load_skill, Skill

    if skill is None:
        return load_skill("insert", gear)
    if isinstance(skill, Skill):
        return skill
    if isinstance(skill, (str, os.PathLike)):
        return load_skill(gear=gear, path=skill)
    raise InputError(f"skill = {skill!r}; expected None (the shipped skill), a Skill or a skill file path")


def make_insertion_env(
    effects: Mapping[str, Any] | None = None,
    gear: str = "medium",
    skill: Any = None,
    variant: str = "panda",
    xi: str | tuple[float, float, float] = "flow",
) -> gymnasium.Env:
    """The skill's GearInsertion env in `variant` with `effects` in its physics, drawing xi from the
    skill's flow (`xi="flow"`) or uniformly over the box (`"uniform"`), as Skill.make_env does, or
    holding every episode at one grasp error (`xi` = (x [m], y [m], yaw [rad]) in the box).
    Effects need variant "panda" (InputError otherwise)."""
    if isinstance(xi, str):
        check_choice(xi, ("flow", "uniform"), "xi")
    else:
        xi = check_finite_array(xi, "xi", (3,))
    sk = _load(skill, gear)
    if sk.gear != gear:
        raise InputError(f"skill {sk.name}-{sk.gear} is for the {sk.gear} gear; expected gear = {gear!r}")
    env = _env(effects, gear, variant, sk.env_id, sk.env_kwargs)
    env.unwrapped.sampler = (
        (sk.sampler if xi == "flow" else FullDR(sk.space)) if isinstance(xi, str) else NoDR(sk.space, point=tuple(xi))
    )
    return env


def _env(
    effects: Mapping[str, Any] | None,
    gear: str,
    variant: str,
    env_id: str = "goflow/GearInsertion-v0",
    env_kwargs: Mapping[str, Any] | None = None,
) -> gymnasium.Env:
    check_choice(variant, ("fast", "panda"), "variant")
    physics = {k: v for k, v in station_physics(effects).items() if v is not None}
    if variant != "panda" and physics:
        raise InputError(
            f"variant = {variant!r} with effects {sorted(check_station_effects(effects))}; "
            "expected variant 'panda' (only the station models contact and grasp effects)"
        )
    return gymnasium.make(env_id, **{**dict(env_kwargs or {}), "gear": gear, "variant": variant, **physics})


# -- logging --------------------------------------------------------------------------------


class _Recorder:
    """Samples the station before each physics step (the step's target already held)."""

    def __init__(self, env: gymnasium.Env) -> None:
        sim = env.unwrapped.sim
        self.station, self.root = sim.station, sim.context
        st = self.station
        self.pc = st.plant.GetMyContextFromRoot(self.root)
        self.dc = st.diagram.GetMyContextFromRoot(self.root)
        self.gear = st.models.held.name
        self.X_SW = st.models.X_WS(self.gear).inverse()
        self.gear_body = st.plant.get_body(st.plant.GetBodyIndices(st.models.held.instance)[0])
        self._ports = {n: st.diagram.GetOutputPort(n) for n in ("torque", "X_WT", "contact_results")}
        self._target = st.diagram.GetInputPort("X_WT_desired")
        self._inspector = st.scene_graph.model_inspector()
        self._body_of: dict[Any, Any] = {}  # geometry id -> body index, filled lazily
        self.rows: dict[str, list] = {
            k: []
            for k in (
                "time",
                "q",
                "dq",
                "tau",
                "tool_pose",
                "tool_target",
                "wrench",
                "gripper_width",
                "lateral",
                "height",
            )
        }

    def _body(self, gid) -> Any:
        if gid not in self._body_of:
            self._body_of[gid] = self.station.plant.GetBodyFromFrameId(self._inspector.GetFrameId(gid)).index()
        return self._body_of[gid]

    def _wrench(self, p_WT: NDArray[np.float64]) -> NDArray[np.float64]:
        """Contact force and torque about the tool origin on the gear from everything it touches
        (the plate and shafts; robot contact is filtered), world axes."""
        results = self._ports["contact_results"].Eval(self.dc)
        g = self.gear_body.index()
        f, m = np.zeros(3), np.zeros(3)
        for i in range(results.num_hydroelastic_contacts()):
            info = results.hydroelastic_contact_info(i)
            surface = info.contact_surface()
            sign = (1.0 if self._body(surface.id_M()) == g else 0.0) - (1.0 if self._body(surface.id_N()) == g else 0.0)
            if sign:
                F = info.F_Ac_W()
                fi, mi = sign * F.translational(), sign * F.rotational()
                f += fi
                m += mi + np.cross(surface.centroid() - p_WT, fi)
        for i in range(results.num_point_pair_contacts()):
            info = results.point_pair_contact_info(i)
            sign = (1.0 if info.bodyB_index() == g else 0.0) - (1.0 if info.bodyA_index() == g else 0.0)
            if sign:
                fi = sign * info.contact_force()
                f += fi
                m += np.cross(info.contact_point() - p_WT, fi)
        return np.r_[f, m]

    def __call__(self) -> None:
        st, pc = self.station, self.pc
        X_WT = self._ports["X_WT"].Eval(self.dc).GetAsMatrix4()
        r = self.rows
        r["time"].append(self.root.get_time())
        r["q"].append(st.plant.GetPositions(pc, st.models.arm))
        r["dq"].append(st.plant.GetVelocities(pc, st.models.arm))
        r["tau"].append(self._ports["torque"].Eval(self.dc).copy())
        r["tool_pose"].append(X_WT)
        r["tool_target"].append(self._target.Eval(self.dc).GetAsMatrix4())
        r["wrench"].append(self._wrench(X_WT[:3, 3]))
        r["gripper_width"].append(float(np.sum(st.plant.GetPositions(pc, st.models.hand))))
        p = self.X_SW @ self.gear_body.EvalPoseInWorld(pc).translation()
        r["lateral"].append(math.hypot(p[0], p[1]))
        r["height"].append(float(p[2]))

    def log(self, meta: dict[str, Any]) -> RobotLog:
        a = {k: np.asarray(v, dtype=np.float64) for k, v in self.rows.items()}
        phase = geometry_phases(a["lateral"], a["height"], np.linalg.norm(a["wrench"][:, :3], axis=1))
        return RobotLog(
            time=a["time"],
            q=a["q"],
            dq=a["dq"],
            tau=a["tau"],
            tau_cmd=a["tau"].copy(),
            tool_pose=a["tool_pose"],
            tool_target=a["tool_target"],
            wrench=a["wrench"],
            gripper_width=a["gripper_width"],
            phase=phase,
            meta=meta,
        )


def geometry_phases(
    lateral: NDArray[np.float64], height: NDArray[np.float64], force: NDArray[np.float64]
) -> NDArray[np.int64]:
    """Phase labels (indices into PHASES) from the gear's geometry, sample by sample:

    - insertion: the shaft is in the bore past both chamfers (the gear's bottom more than
      INSERTION_DEPTH below the shaft top, `height` < SHAFT_HEIGHT - INSERTION_DEPTH, and its axis
      within the bore radius of the shaft's, `lateral` < GEAR_BORE_RADIUS): descending or seated;
    - contact: otherwise, a contact force on the gear above CONTACT_FORCE_MIN (on the shaft's top,
      the chamfers, or the plate beside the shaft);
    - approach: otherwise, the gear's bottom within APPROACH_HEIGHT above the shaft top and its axis
      within APPROACH_RADIUS of the shaft's; free: the rest.

    A phase, once entered, lasts until a later one begins (running maximum), so the labels never
    decrease. lateral, height [m]: the gear frame's offset from its seated pose (shaft frame);
    force [N]: the contact force's magnitude on the gear."""
    lateral, height, force = (np.asarray(x, dtype=np.float64) for x in (lateral, height, force))
    raw = np.full(lateral.shape, PHASES.index("free"), dtype=np.int64)
    near = (height - SHAFT_HEIGHT < APPROACH_HEIGHT) & (lateral < APPROACH_RADIUS)
    raw[near] = PHASES.index("approach")
    raw[force > CONTACT_FORCE_MIN] = PHASES.index("contact")
    raw[(height < SHAFT_HEIGHT - INSERTION_DEPTH) & (lateral < GEAR_BORE_RADIUS)] = PHASES.index("insertion")
    return np.maximum.accumulate(raw) if len(raw) else raw


def _meta(
    gear: str, xi: NDArray[np.float64], seed: int | None, skill_name: str, effects: dict, env, source: str, **extra: Any
) -> dict[str, Any]:
    c = env.unwrapped.config
    st = env.unwrapped.sim.station
    gains = st.config.gains
    return {
        "robot": "panda",
        "joint_names": list(_ARM_JOINTS),
        "end_effector": f"hand+gear_{gear}",
        "torque_side": "motor",
        "units": {
            k: UNITS[k]
            for k in ("time", "q", "dq", "tau", "tau_cmd", "tool_pose", "tool_target", "wrench", "gripper_width")
        },
        "frames": {
            "base": "W: the Panda's base on the table top, z up",
            "tool": "panda_hand_tcp (between the finger pads, z along the approach)",
            "wrench": "contact force on the held gear from the plate and shafts, world axes; "
            "torque about the tool origin",
        },
        "controller": {
            "law": "cartesian_impedance",
            "stiffness": gains.stiffness.tolist(),
            "damping": gains.damping.tolist(),
            "control_dt": c.control_dt,
            "time_step": c.panda_time_step,
        },
        "source": source,
        "license": "generated (goflow sim2real.station_logs)",
        "task": {
            "gear": gear,
            "xi": [float(v) for v in xi],
            "seed": seed,
            "skill": skill_name,
            "variant": c.variant,
            "control_dt": c.control_dt,
            "t_max": c.t_max,
        },
        "truth": effects,
        **extra,
    }


def make_insertion_log(
    effects: Mapping[str, Any] | None,
    gear: str = "medium",
    xi: tuple[float, float, float] | None = None,
    seed: int = 0,
    skill: Any = None,
    variant: str = "panda",
) -> tuple[RobotLog, bool]:
    """One episode of the insertion skill's deterministic policy with `effects` in the physics,
    logged before every physics step (8 ms) and once at the end: (log, success).

    Arguments:
        effects: {effect: {param: value}} of STATION_EFFECTS (check_station_effects); {} nominal.
        gear: "small", "medium" or "large".
        xi: the grasp error (x [m], y [m], yaw [rad]); None draws it from the skill's flow with `seed`.
        seed: the env's reset seed (only the xi draw depends on it: the policy is deterministic).
        skill: None (the shipped `insert` skill for `gear`), a learning.skill_file.Skill or a file path.
        variant: "panda" (the only one with a station to log).

    Returns:
        The RobotLog (time, q, dq, tau = tau_cmd = the impedance controller's torque as applied,
        tool_pose, tool_target = the impedance target the action made, wrench = contact wrench on
        the gear, gripper_width, phase from geometry_phases; meta "task" {gear, xi, seed, skill,
        ...}, "truth" = the effects, "success", "episode_return") and whether the episode met the
        env's success criterion (return >= J_T). A failed physics step ends the log early
        (meta "sim_error"; success False).
    """
    check_choice(variant, ("panda",), "variant")
    check_int(seed, "seed", 0)
    truth = check_station_effects(effects)
    sk = _load(skill, gear)
    env = make_insertion_env(truth, gear, sk, variant)
    options = None
    if xi is not None:
        options = {"xi": check_finite_array(xi, "xi", (3,))}
    obs, info = env.reset(seed=int(seed), options=options)
    xi_used = np.asarray(info["xi"], dtype=np.float64)
    rec = _Recorder(env)
    env.unwrapped.sim.on_step = rec
    try:
        done, ret = False, 0.0
        while not done:
            obs, reward, term, trunc, info = env.step(sk.act(obs))
            ret += float(reward)
            done = term or trunc
        rec()
    finally:
        env.unwrapped.sim.on_step = None
    success = bool(info.get("success", False)) and "sim_error" not in info
    extra = {"success": success, "episode_return": float(info.get("episode_return", ret))}
    if "sim_error" in info:
        extra["sim_error"] = str(info["sim_error"])
    meta = _meta(
        gear,
        xi_used,
        int(seed),
        f"{sk.name}-{sk.gear}",
        truth,
        env,
        "simulated reality: the panda station with withheld effects",
        **extra,
    )
    env.close()
    return rec.log(meta), success


def with_sensor_noise(
    log: RobotLog, seed: int = 0, tau: float = 0.05, position: float = 2e-5, force: float = 0.2
) -> RobotLog:
    """`log` as sensors would record it: white Gaussian noise on the joint torques [N m], the tool
    position [m] and the contact force [N] (the arm reality's torque noise; our choice for the
    others). The simulation itself is noise-free, so a "real" insertion log gets this."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 2]))
    pose = log.tool_pose.copy()
    pose[:, :3, 3] += position * rng.standard_normal((log.n_samples, 3))
    wrench = log.wrench.copy()
    wrench[:, :3] += force * rng.standard_normal((log.n_samples, 3))
    return dataclasses.replace(
        log, tau=log.tau + tau * rng.standard_normal(log.tau.shape), tool_pose=pose, wrench=wrench
    )


def replay_insertion(log: RobotLog, effects: Mapping[str, Any] | None) -> RobotLog:
    """Re-run the station with `effects` from the log's start, applying the LOGGED tool targets open
    loop (each held from the sample where it changes, i.e. at the control rate), and log it on the
    same time base.

    The start: the env reset to the grasp error xi = log.meta["task"]["xi"] (gear from meta), then
    the arm set to the log's first q and dq. Returns a RobotLog with the fields of
    make_insertion_log (its own phase labels; compare by the real log's), meta "source" "replay",
    "truth" = the effects simulated. InputError when the log lacks tool_target, meta["task"]
    (gear, xi) or samples."""
    truth = check_station_effects(effects)
    task = log.meta.get("task") if isinstance(log.meta, Mapping) else None
    if not isinstance(task, Mapping) or "gear" not in task or "xi" not in task:
        raise InputError(f"log.meta['task'] must hold 'gear' and 'xi' (the grasp error) to replay it; it is {task!r}")
    if log.tool_target is None or log.n_samples < 2:
        raise InputError("replay_insertion needs a log with tool_target and at least 2 samples")
    gear = task["gear"]
    gear_spec(gear)
    xi = check_finite_array(task["xi"], "log.meta['task']['xi']", (3,))
    env = _env(truth, gear, "panda")
    env.reset(options={"xi": xi})
    sim = env.unwrapped.sim
    st, root = sim.station, sim.context
    pc = st.plant.GetMyMutableContextFromRoot(root)
    st.plant.SetPositions(pc, st.models.arm, np.asarray(log.q[0], dtype=np.float64))
    st.plant.SetVelocities(pc, st.models.arm, np.asarray(log.dq[0], dtype=np.float64))
    port = st.diagram.GetInputPort("X_WT_desired")
    rec = _Recorder(env)
    t0 = root.get_time() - float(log.time[0])
    held = None
    error = None
    for i in range(log.n_samples):
        if held is None or not np.array_equal(log.tool_target[i], held):
            held = log.tool_target[i]
            port.FixValue(root, RigidTransform(np.asarray(held, dtype=np.float64)))
        rec()
        if i + 1 < log.n_samples:
            try:
                advance(sim.simulator, t0 + float(log.time[i + 1]), "replay_insertion")
            except RuntimeError as exc:  # SimulationError: stop the replay where the physics failed
                error = str(exc)
                break
    extra: dict[str, Any] = {"replay_of": log.meta.get("source")}
    if error is not None:
        extra["sim_error"] = error
    meta = _meta(gear, xi, task.get("seed"), str(task.get("skill", "")), truth, env, "replay", **extra)
    env.close()
    return rec.log(meta)


def skill_success(
    effects: Mapping[str, Any] | None,
    gear: str = "medium",
    episodes: int = 10,
    seed: int = 0,
    variant: str = "panda",
    skill: Any = None,
    xi: str | tuple[float, float, float] = "flow",
    num_envs: int = 1,
) -> float:
    """The success rate of the skill's deterministic policy over `episodes` episodes with `effects`
    in the physics, xi drawn as learning.skill_evaluation.evaluate_skill draws it (the skill's flow or the
    uniform box, reset seed `seed`), or held at one grasp error (`make_insertion_env`): the same
    seed gives the same xi for every `effects`, so two rates differ by the effect alone (with
    num_envs as in evaluate_skill, the same episodes as it)."""
    episodes = check_int(episodes, "episodes", 1)
    check_int(seed, "seed", 0)
    n = max(1, min(check_int(num_envs, "num_envs", 1), episodes))
    sk = _load(skill, gear)
    make_insertion_env(effects, gear, sk, variant, xi).close()  # checks before building n envs
    vec = gymnasium.vector.SyncVectorEnv(
        [lambda: make_insertion_env(effects, gear, sk, variant, xi) for _ in range(n)],
        autoreset_mode=gymnasium.vector.AutoresetMode.SAME_STEP,
    )
    try:
        _, _, successes = sk.agent.evaluate(vec, episodes, deterministic=True, seed=int(seed))
    finally:
        vec.close()
    return float(np.mean(successes))


# -- measurement ------------------------------------------------------------------------------


def phase_residuals(log: RobotLog, sim: RobotLog) -> dict[str, dict[str, float]]:
    """Per phase of `log` (its labels), the RMS of sim - log: tool height "z" [m], tool position
    "p" [m] (3-D norm), joint torques "tau" [N m] (over joints) and contact force "force" [N]
    (3-D norm), and the phase's sample count "n". The two logs must share the time base."""
    if sim.n_samples != log.n_samples or not np.allclose(sim.time, log.time):
        raise InputError(
            f"sim has {sim.n_samples} samples on another time base than the log's "
            f"{log.n_samples}; expected replay_insertion(log, ...)"
        )
    if log.phase is None:
        raise InputError("log.phase is None; expected a labelled log")
    dp = sim.tool_pose[:, :3, 3] - log.tool_pose[:, :3, 3]
    df = sim.wrench[:, :3] - log.wrench[:, :3]
    out = {}
    for k, name in enumerate(PHASES):
        m = log.phase == k
        if m.any():
            out[name] = {
                "n": int(m.sum()),
                "z": float(np.sqrt(np.mean(dp[m, 2] ** 2))),
                "p": float(np.sqrt(np.mean(np.sum(dp[m] ** 2, axis=1)))),
                "tau": float(np.sqrt(np.mean((sim.tau[m] - log.tau[m]) ** 2))),
                "force": float(np.sqrt(np.mean(np.sum(df[m] ** 2, axis=1)))),
            }
    return out


def _main(argv: list[str] | None = None) -> None:
    """The measurement of docs/sim2real.md, "Contact and insertion logs"."""
    import argparse
    import json
    import time

    from learning.skill_file import load_skill
    from sim2real.catalogue import parse_effect_values

    parser = argparse.ArgumentParser(prog="python -m sim2real.station_logs", description=_main.__doc__)
    parser.add_argument(
        "--effect",
        action="append",
        default=None,
        help="NAME=VALUE, one case each (default: CONTACT_CASE and GRASP_CASE)",
    )
    parser.add_argument("--gear", default="medium")
    parser.add_argument("--episodes", type=int, default=10, help="episodes per success rate (0: none)")
    parser.add_argument("--seed", type=int, default=0, help="the logged episode's xi draw; the rates' seed")
    parser.add_argument("--json", default=None, help="write the numbers here")
    args = parser.parse_args(argv)
    cases = [parse_effect_values([spec]) for spec in args.effect] if args.effect else [CONTACT_CASE, GRASP_CASE]
    sk = load_skill("insert", args.gear)
    out: dict[str, Any] = {"gear": args.gear, "seed": args.seed, "episodes": args.episodes, "cases": []}
    if args.episodes:
        t0 = time.perf_counter()
        out["nominal_success"] = skill_success({}, args.gear, args.episodes, args.seed, skill=sk)
        out["seconds_per_episode"] = (time.perf_counter() - t0) / args.episodes
        print(
            f"nominal success {out['nominal_success']:.2f} ({args.episodes} episodes, "
            f"{out['seconds_per_episode']:.2f} s/episode)"
        )
    for effects in cases:
        t0 = time.perf_counter()
        log, ok = make_insertion_log(effects, args.gear, seed=args.seed, skill=sk)
        t_log = time.perf_counter() - t0
        t0 = time.perf_counter()
        same = replay_insertion(log, effects)
        t_replay = time.perf_counter() - t0
        nominal = replay_insertion(log, {})
        case = {
            "effects": effects,
            "log_success": ok,
            "log_seconds": t_log,
            "replay_seconds": t_replay,
            "samples": log.n_samples,
            "vs_nominal_replay": phase_residuals(log, nominal),
            "vs_true_replay": phase_residuals(log, same),
        }
        print(
            f"\n{json.dumps(effects)}: logged episode success {ok} ({log.n_samples} samples, log "
            f"{t_log:.2f} s, replay {t_replay:.2f} s)"
        )
        for which in ("vs_nominal_replay", "vs_true_replay"):
            for phase, r in case[which].items():
                print(
                    f"  {which:17s} {phase:9s} n={r['n']:3d}  z {1e3 * r['z']:7.3f} mm  p {1e3 * r['p']:7.3f} mm"
                    f"  tau {r['tau']:6.3f} N m  force {r['force']:6.2f} N"
                )
        if args.episodes:
            t0 = time.perf_counter()
            case["success"] = skill_success(effects, args.gear, args.episodes, args.seed, skill=sk)
            case["success_seconds"] = time.perf_counter() - t0
            print(
                f"  success with the effect {case['success']:.2f} vs nominal {out['nominal_success']:.2f} "
                f"({args.episodes} episodes, {case['success_seconds']:.1f} s)"
            )
        out["cases"].append(case)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    _main()
