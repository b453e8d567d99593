"""planning.BeliefSpacePlanner: the belief-space planner as a Drake system in the station diagram.

Its inputs are what the robot senses: the scene and wrist cameras' RGB-D images, the measured tool
pose and the hand's state. It never reads the plant's gear poses (only the final scoring does).
Its outputs are the command ports the scripted source drives (`X_WT_desired`, `V_WT_desired`,
`A_WT_desired`, `gripper_width`), so the controller's wiring is unchanged. A periodic unrestricted
update (every `period`, the insertion policy's control period) runs the state machine, whose whole
state (beliefs, plan, current skill and its internal state, what was executed) is the system's
abstract state (the pattern of the manipulation course's clutter-clearing Planner system):

    perceive (scene camera: detection, a far posterior per gear) -> plan (Algorithm 2)
    -> per step: inspect (motion, close view, belief update, replan) | pick (motion; a miss,
       read off the fingers' width, re-perceives) | insert (transport to the policy's start, the
       learned policy closed loop at its control rate, release, and a look at the seated face with
       the wrist camera; unseated with the gear in hand puts it back and re-perceives, unseated
       on the shaft fails with the reason). A gear whose pick or insert failed is doubted
       (planning.domain.GearBelief) until a close view of it: the plan inspects it before picking
       it again rather than retry from the same, possibly biased, far view.
    -> done, or failed with the reason.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field, replace

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import Context, Diagram, DiagramBuilder, LeafSystem, State

from assembly.envs.gear_insertion import GearInsertionConfig
from assembly.cameras import extrinsic_error_on_table
from assembly.gearset import GEAR_NAMES, GEAR_THICKNESS, SHAFT_HEIGHT, gear_spec
from assembly.inspection import X_HT, InspectConfig, append_inspect
from assembly.insertion_law import InsertionLaw, PoseHistory
from assembly.scripted_motion import (
    Keyframe, KeyframePlan, ScriptedInsertionConfig, append_move, append_pick, append_place, carry_height,
    down_pose, grasp_tool_pose, gripper_widths, sample_plan, start_keyframe_plan,
)
from assembly.station import COMMAND_PORTS, Station
from assembly.world import nominal_grasp, planar_pose
from perception.detection import detect_gears
from perception.observation import Observation
from perception.search import Prior, estimate_pose
from perception.seat_check import SeatCheckConfig, check_seat
from perception.station_views import observation_from_images
from planning.bfs import plan_bfs
from planning.domain import AssemblyDomain, BeliefState, GearBelief, table_belief
from planning.grasp import aim_tool

PHASES = ("perceive", "motion", "policy", "done", "failed")


@dataclass
class PlannerSystemConfig:
    """period: the state machine's and the insertion policy's period [s]; motion, inspect: the
    skills' keyframe motions; max_replans: re-perceptions after a failed pick or insert; close_prior:
    the close view's prior box (multiple of the belief's std, min, max half-width [m]);
    seated_tolerance: the tool within this of its seated height means the gear is on its shaft;
    settle_tolerance, max_wait: a motion ends when the tool is this close to its last keyframe, or
    this long after it; scene_extrinsic_std: how well the scene camera's extrinsics are known,
    (translation [m], rotation [rad]) std: the x-y shift it causes on the table (assembly.cameras.
    extrinsic_error_on_table) and the rotation in yaw are added to each far belief's std (the
    wrist camera rides on the hand: its close views do not inherit it); seat_check: after an insert
    the tool says seated, the wrist camera's view from the retreat checks the gear's face
    (perception.seat_check; None: trust the tool's height alone)."""

    period: float = 0.04
    motion: ScriptedInsertionConfig = field(default_factory=ScriptedInsertionConfig)
    inspect: InspectConfig = field(default_factory=InspectConfig)
    max_replans: int = 2
    close_prior: tuple[float, float, float] = (4.0, 0.005, 0.03)
    seated_tolerance: float = 0.002
    settle_tolerance: float = 0.002
    max_wait: float = 3.0
    scene_extrinsic_std: tuple[float, float] = (0.0, 0.0)
    seat_check: SeatCheckConfig | None = field(default_factory=SeatCheckConfig)


@dataclass
class _Run:
    """The planner's abstract state."""

    phase: str = "perceive"
    beliefs: dict = field(default_factory=dict)          # gear -> GearBelief
    steps: list = field(default_factory=list)             # remaining planned Steps
    plans: list = field(default_factory=list)             # every plan made: [[skill, gear], ...]
    executed: list = field(default_factory=list)
    current: dict | None = None                            # the skill being executed
    keyframes: KeyframePlan | None = None
    after: str = ""                                        # what ends the current motion
    target: RigidTransform | None = None                   # the policy's last target
    width: float = 0.08
    history: PoseHistory | None = None
    policy_end: float = 0.0
    replans: int = 0
    reason: str = ""
    log: list = field(default_factory=list)


def _pose4(X: RigidTransform) -> np.ndarray:
    m = X.rotation().matrix()
    return np.array([*X.translation(), np.arctan2(m[1, 0], m[0, 0])])


class BeliefSpacePlanner(LeafSystem):
    """See the module docstring. `skills`: the insert Skill per gear; `domain`: the planning
    domain (planning.domain.gearbox_domain); `X_WS`: each shaft's pose (from the plate's known
    pose); `cameras`: the station's CamerasConfig; `X_WT_start`, `width_start`: the robot's
    start; `meshcat`: if given, each gear's belief is drawn there (its mean as a thin disc of the
    gear's tip radius, its 3-sigma x-y region as a translucent one) whenever it changes."""

    def __init__(self, skills: dict, domain: AssemblyDomain, X_WS: dict[str, RigidTransform],
                 cameras, X_WT_start: RigidTransform, width_start: float,
                 config: PlannerSystemConfig | None = None, meshcat=None) -> None:
        super().__init__()
        self.set_name("belief_space_planner")
        self.config = config or PlannerSystemConfig()
        self.skills, self.domain, self.X_WS, self.cameras = skills, domain, X_WS, cameras
        self.X_WT_start = X_WT_start
        self.meshcat = meshcat
        missing = [g for g in domain.goal if g not in skills or g not in X_WS]
        if missing:
            raise ValueError(f"no insert skill or shaft pose for gear(s) {missing}")
        self.laws = {}
        for gear in domain.goal:
            c = GearInsertionConfig(gear=gear)
            seated = _pose4(X_WS[gear] @ nominal_grasp(gear).inverse())
            self.laws[gear] = InsertionLaw(tuple(seated), c.action_scale, c.workspace, c.history, c.control_dt)
            self.t_max = c.t_max
        for cam in ("scene", "wrist"):
            self.DeclareAbstractInputPort(f"{cam}_rgb", AbstractValue.Make(_image_value("rgb")))
            self.DeclareAbstractInputPort(f"{cam}_depth", AbstractValue.Make(_image_value("depth")))
        self.DeclareAbstractInputPort("X_WT", AbstractValue.Make(RigidTransform()))
        self.DeclareVectorInputPort("hand_state", 4)
        start = start_keyframe_plan(X_WT_start, width_start)
        start.append(0.5, X_WT_start, width_start, "start: hold")
        self._state = self.DeclareAbstractState(AbstractValue.Make(
            _Run(keyframes=start, after="", width=width_start)))
        self.DeclarePeriodicUnrestrictedUpdateEvent(self.config.period, 0.0, self._update)
        self.DeclareAbstractOutputPort("X_WT_desired", lambda: AbstractValue.Make(RigidTransform()),
                                       self._calc_pose)
        self.DeclareVectorOutputPort("V_WT_desired", 6, lambda c, o: o.SetFromVector(self._sample(c)[1]))
        self.DeclareVectorOutputPort("A_WT_desired", 6, lambda c, o: o.SetFromVector(self._sample(c)[2]))
        self.DeclareVectorOutputPort("gripper_width", 1, lambda c, o: o.SetFromVector([self._sample(c)[3]]))
        self.DeclareAbstractOutputPort("status", lambda: AbstractValue.Make({}), self._calc_status)

    # -- outputs -----------------------------------------------------------------------------

    def run(self, context: Context) -> _Run:
        """The planner's state in `context` (read only)."""
        return context.get_abstract_state(self._state).get_value()

    def _sample(self, context: Context):
        run = self.run(context)
        if run.phase == "policy" and run.target is not None:
            return run.target, np.zeros(6), np.zeros(6), run.width
        return sample_plan(run.keyframes, context.get_time())

    def _calc_pose(self, context: Context, output: AbstractValue) -> None:
        output.set_value(self._sample(context)[0])

    def _calc_status(self, context: Context, output: AbstractValue) -> None:
        run = self.run(context)
        output.set_value({"phase": run.phase, "executed": list(run.executed), "plans": list(run.plans),
                          "replans": run.replans, "reason": run.reason})

    # -- sensing -----------------------------------------------------------------------------

    def _observe(self, context: Context, camera: str) -> Observation:
        config = self.cameras.scene if camera == "scene" else self.cameras.wrist
        if camera == "scene":
            X_WC = config.X_PC
        else:  # the wrist camera rides on the hand: X_WC = X_WT X_TH X_HC
            X_WC = self.GetInputPort("X_WT").Eval(context) @ X_HT.inverse() @ config.X_PC
        return observation_from_images(self.GetInputPort(f"{camera}_rgb").Eval(context),
                                       self.GetInputPort(f"{camera}_depth").Eval(context), config, X_WC)

    # -- the state machine -------------------------------------------------------------------

    def _update(self, context: Context, state: State) -> None:
        run = copy.copy(self.run(context))
        run.executed, run.log = list(run.executed), list(run.log)
        run.current = dict(run.current) if run.current else None
        t = context.get_time()
        X_WT = self.GetInputPort("X_WT").Eval(context)
        if run.phase == "perceive":
            self._perceive(context, run, t, X_WT)
        elif run.phase == "motion" and self._motion_done(run, t, X_WT):
            self._after_motion(context, run, t, X_WT)
        elif run.phase == "policy":
            self._policy_step(context, run, t, X_WT)
        state.get_mutable_abstract_state(self._state).set_value(run)

    def _motion_done(self, run: _Run, t: float, X_WT: RigidTransform) -> bool:
        end = run.keyframes.end_time
        if t < end:
            return False
        near = np.linalg.norm(X_WT.translation() - run.keyframes.keyframes[-1].X_WT.translation())
        return near < self.config.settle_tolerance or t > end + self.config.max_wait

    def _hold(self, run: _Run, t: float, X_WT: RigidTransform, width: float | None = None) -> KeyframePlan:
        """A new keyframe plan starting now, from the current command."""
        last = run.keyframes.keyframes[-1] if run.keyframes else None
        policy = run.phase == "policy" and run.target is not None
        X = run.target if policy else (last.X_WT if last else X_WT)
        w = width if width is not None else (run.width if policy or last is None else last.width)
        return KeyframePlan([Keyframe(t, X, w, "now")])

    def _perceive(self, context: Context, run: _Run, t: float, X_WT: RigidTransform) -> None:
        t0 = time.perf_counter()
        obs = self._observe(context, "scene")
        found = detect_gears(obs, tuple(g for g in GEAR_NAMES if g in self.domain.goal or g in run.beliefs))
        beliefs = dict(run.beliefs)
        for gear in self.domain.goal:
            if gear in beliefs and beliefs[gear].location == "inserted":
                continue
            det = found.get(gear)
            if det is None or not det.seen:
                self._fail(run, f"{gear} gear not seen by the scene camera: "
                                f"{det.reason if det else 'not searched'}")
                return
            post = estimate_pose(obs, gear, det.prior)
            if not post.informative:
                beliefs[gear] = table_belief((det.prior.x, det.prior.y, 0.0),
                                             (det.prior.half_width,) * 2 + (np.pi,))
            else:
                beliefs[gear] = table_belief(post.mean(), self._far_std(obs, post.mean(), post.std()))
            if gear in run.beliefs and run.beliefs[gear].doubted:  # still owed a close view
                beliefs[gear] = replace(beliefs[gear], doubted=True)
        run.beliefs = beliefs
        run.log.append(f"t = {t:.2f} s: perceived {sorted(beliefs)} in {time.perf_counter() - t0:.1f} s")
        self._replan(run, t, X_WT)

    def _far_std(self, obs: Observation, mean: np.ndarray, std: np.ndarray) -> np.ndarray:
        """A far posterior's std with the scene camera's extrinsic uncertainty added."""
        t_std, r_std = self.config.scene_extrinsic_std
        if t_std == 0 and r_std == 0:
            return std
        cov = extrinsic_error_on_table(obs.X_WC, np.array([mean[0], mean[1], GEAR_THICKNESS]), t_std, r_std)
        return np.sqrt(np.asarray(std) ** 2 + np.array([cov[0, 0], cov[1, 1], r_std ** 2]))

    def _draw_beliefs(self, beliefs: dict) -> None:
        """Each table gear's belief in Meshcat: the mean pose, and the 3-sigma x-y disc."""
        if self.meshcat is None:
            return
        from pydrake.geometry import Cylinder, Rgba

        for gear, b in beliefs.items():
            path = f"beliefs/{gear}"
            if b.location != "table":
                self.meshcat.Delete(path)
                continue
            r = gear_spec(gear).tip_radius
            X = RigidTransform(RotationMatrix.MakeZRotation(b.mean[2]), [b.mean[0], b.mean[1], 0.0222])
            self.meshcat.SetObject(f"{path}/mean", Cylinder(r, 0.0004), Rgba(0.1, 0.4, 1.0, 0.8))
            self.meshcat.SetTransform(f"{path}/mean", X)
            self.meshcat.SetObject(f"{path}/region", Cylinder(r + 3 * max(b.std[:2]), 0.0002),
                                   Rgba(0.1, 0.4, 1.0, 0.25))
            self.meshcat.SetTransform(f"{path}/region", X)

    def _replan(self, run: _Run, t: float, X_WT: RigidTransform) -> None:
        self._draw_beliefs(run.beliefs)
        start = BeliefState.of(run.beliefs, None)
        plan = plan_bfs(start, self.domain)
        if not plan.found:
            self._fail(run, f"no plan: {plan.reason}")
            return
        run.plans.append(plan.pairs())
        run.steps = list(plan.steps)
        self._next_step(run, t, X_WT)

    def _fail(self, run: _Run, reason: str) -> None:
        run.phase, run.reason = "failed", reason
        run.log.append(reason)

    def _next_step(self, run: _Run, t: float, X_WT: RigidTransform) -> None:
        if not run.steps:
            done = all(run.beliefs[g].location == "inserted" for g in self.domain.goal)
            run.phase = "done" if done else "failed"
            run.reason = "" if done else "the plan ended before every gear was inserted"
            return
        step = run.steps.pop(0)
        run.current = {"skill": step.skill, "gear": step.gear, "t_start": t,
                       "precondition_prob": float(step.probability)}
        c = self.config
        gear = step.gear
        belief = run.beliefs[gear]
        plan = self._hold(run, t, X_WT)
        open_w, closed_w = gripper_widths(gear, c.motion)
        if step.skill == "inspect":
            append_inspect(plan, gear, belief.mean[:2], self.cameras.wrist, c.inspect)
            run.after = "picture"
        elif step.skill == "pick":
            aim = np.asarray(self.domain.aim_xi.get(gear, (0.0, 0.0, 0.0)), float)
            # the gear repeats every tooth pitch: of the headings giving the aimed yaw, the one
            # nearest pi/2 (the fingers close along world x, as in the scripted pick)
            pitch = 2 * np.pi / gear_spec(gear).teeth
            k = np.round((np.pi / 2 - (belief.mean[2] - aim[2])) / pitch)
            tool = aim_tool(belief.mean, aim - [0.0, 0.0, k * pitch])
            heading = float(tool[2])
            run.current["tool"] = tool.tolist()
            if plan.keyframes[-1].width < open_w:
                plan.append(c.motion.gripper_time, plan.keyframes[-1].X_WT, open_w, f"{gear}: open")
            # aim the tool: the gear's believed centre shifted by the aimed grasp error
            X_WG_aim = planar_pose(tool[0], tool[1], belief.mean[2])
            append_pick(plan, gear, X_WG_aim, heading, carry_height(gear, self.X_WS[gear], c.motion), c.motion)
            run.after = "picked"
        elif step.skill == "insert":
            law = self.laws[gear]
            seated = np.asarray(law.seated)
            start = seated + [0.0, 0.0, SHAFT_HEIGHT + GearInsertionConfig().start_height, 0.0]
            carry = carry_height(gear, self.X_WS[gear], c.motion)
            append_move(plan, down_pose(np.array([start[0], start[1], carry]), start[3]), closed_w,
                        f"{gear}: transport", c.motion.speed, c.motion.min_segment)
            append_move(plan, down_pose(start[:3], start[3]), closed_w, f"{gear}: to the policy's start",
                        c.motion.insert_speed * 3, c.motion.min_segment)
            plan.append(c.motion.pause, plan.keyframes[-1].X_WT, closed_w, f"{gear}: steady")
            run.after = "policy"
        run.keyframes, run.phase = plan, "motion"

    def _after_motion(self, context: Context, run: _Run, t: float, X_WT: RigidTransform) -> None:
        gear = run.current["gear"] if run.current else None
        if run.after == "picture":
            obs = self._observe(context, "wrist")
            b = run.beliefs[gear]
            k, lo, hi = self.config.close_prior
            prior = Prior(b.mean[0], b.mean[1], float(np.clip(k * max(b.std[:2]), lo, hi)))
            post = estimate_pose(obs, gear, prior)
            if post.informative:
                run.beliefs = {**run.beliefs, gear: GearBelief("table", tuple(post.mean()), tuple(post.std()),
                                                               b.inspections + 1)}
            else:
                run.beliefs = {**run.beliefs, gear: GearBelief("table", b.mean, b.std, b.inspections + 1)}
            self._record(run, t, "informative" if post.informative else f"uninformative: {post.reason}")
            self._replan(run, t, X_WT)
        elif run.after == "picked":
            holding, width = self._holding(context, gear)
            if not holding:  # the fingers closed on nothing
                self._record(run, t, f"missed (fingers {1e3 * width:.1f} mm apart)")
                self._retry(run, t, X_WT)
                return
            b = run.beliefs[gear]
            run.beliefs = {**run.beliefs, gear: GearBelief("hand", b.mean, b.std, b.inspections,
                                                           tuple(run.current["tool"]))}
            self._record(run, t, "holding")
            self._next_step(run, t, X_WT)
        elif run.after == "policy":
            law = self.laws[gear]
            run.history = PoseHistory(law)
            run.history.reset(_pose4(X_WT))
            run.policy_end = t + self.t_max
            run.width = run.keyframes.keyframes[-1].width
            run.phase = "policy"
            self._policy_action(run, gear, X_WT)
        elif run.after == "released":
            if run.current.get("seated") and self.config.seat_check is not None:
                check = check_seat(self._observe(context, "wrist"), gear, self.X_WS[gear],
                                   self.config.seat_check)
                run.log.append(f"t = {t:.2f} s: seat check: {check.reason}")
                if check.verdict == "unseated":
                    self._record(run, t, f"unseated (wrist camera: {check.reason})")
                    self._fail(run, f"insert({gear}) left the gear on its shaft unseated ({check.reason}); "
                                    "no skill takes a gear back off its shaft")
                    return
            self._record(run, t, run.current.get("outcome", ""))
            if run.current.get("seated"):
                b = run.beliefs[gear]
                run.beliefs = {**run.beliefs, gear: GearBelief("inserted", b.mean, b.std, b.inspections)}
                self._next_step(run, t, X_WT)
            else:
                self._retry(run, t, X_WT)
        elif run.after == "reperceive":
            run.phase = "perceive"

    def _policy_action(self, run: _Run, gear: str, X_WT: RigidTransform) -> None:
        skill, law = self.skills[gear], self.laws[gear]
        pose = _pose4(X_WT)
        action = skill.act(run.history.observation())
        target = law.target(action, pose)
        run.target = down_pose(target[:3], target[3])

    def _policy_step(self, context: Context, run: _Run, t: float, X_WT: RigidTransform) -> None:
        gear = run.current["gear"]
        run.history = copy.deepcopy(run.history)
        run.history.push(_pose4(X_WT))
        if t + 1e-9 < run.policy_end:
            self._policy_action(run, gear, X_WT)
            return
        # done: seated if the tool came down to its seated height (the gear is on its shaft)
        # ... and the fingers still hold it (a dropped gear lets the tool come down too)
        dz = float(X_WT.translation()[2] - self.laws[gear].seated[2])
        holding, _ = self._holding(context, gear)
        seated = dz < self.config.seated_tolerance and holding
        run.current["seated"] = seated
        run.current["outcome"] = ("seated" if seated else "dropped" if not holding
                                  else f"unseated (tool {1e3 * dz:.1f} mm above seated; put back)")
        if seated or not holding:
            plan = self._open_and_lift(run, t, X_WT, gear, f"{gear}: release", f"{gear}: retreat")
        else:  # still in hand: put it back where it was picked, on the table the scene camera sees
            tool = run.beliefs[gear].tool
            plan = self._hold(run, t, X_WT)
            X_WT_place = grasp_tool_pose(gear, planar_pose(tool[0], tool[1], 0.0), tool[2], self.config.motion)
            append_place(plan, gear, X_WT_place, carry_height(gear, self.X_WS[gear], self.config.motion),
                         self.config.motion)
        run.keyframes, run.after, run.phase, run.target = plan, "released", "motion", None

    def _holding(self, context: Context, gear: str) -> tuple[bool, float]:
        """Whether the fingers hold `gear` (they stopped on it rather than closing past its
        diameter), and their width [m]."""
        q = self.GetInputPort("hand_state").Eval(context)
        width = float(q[0] + q[1])
        return width > 2 * gear_spec(gear).tip_radius - 0.005, width

    def _open_and_lift(self, run: _Run, t: float, X_WT: RigidTransform, gear: str, open_label: str,
                       lift_label: str) -> KeyframePlan:
        """From the current command: open the fingers for `gear`, then lift by retreat_height."""
        c = self.config.motion
        open_w, _ = gripper_widths(gear, c)
        plan = self._hold(run, t, X_WT)
        plan.append(c.gripper_time, plan.keyframes[-1].X_WT, open_w, open_label)
        up = RigidTransform(plan.keyframes[-1].X_WT.rotation(),
                            plan.keyframes[-1].X_WT.translation() + [0, 0, c.retreat_height])
        append_move(plan, up, open_w, lift_label, c.speed, c.min_segment)
        return plan

    def _record(self, run: _Run, t: float, outcome: str) -> None:
        cur = dict(run.current)
        cur.update(t_end=t, outcome=outcome)
        cur.pop("seated", None)
        run.executed.append({k: cur[k] for k in ("skill", "gear", "t_start", "t_end", "outcome",
                                                  "precondition_prob")})

    def _retry(self, run: _Run, t: float, X_WT: RigidTransform) -> None:
        if run.replans >= self.config.max_replans:
            self._fail(run, f"{run.current['skill']}({run.current['gear']}) failed and "
                            f"{run.replans} replans are spent")
            return
        run.replans += 1
        # re-perceive from a clear view: open, lift, back to the start pose (the arm out of the
        # scene camera's view), then look again; the failed gear's belief is doubted
        gear = run.current["gear"]
        b = run.beliefs[gear]
        run.beliefs = {**run.beliefs, gear: GearBelief("table", b.mean, b.std, 0, doubted=True)}
        c = self.config.motion
        plan = self._open_and_lift(run, t, X_WT, gear, "retry: open", "retry: lift")
        append_move(plan, self.X_WT_start, plan.keyframes[-1].width, "retry: clear the view", c.speed,
                    c.min_segment)
        run.keyframes, run.after, run.phase = plan, "reperceive", "motion"


def connect_planner(station: Station, planner: BeliefSpacePlanner) -> Diagram:
    """The station driven by `planner`: its cameras, measured tool pose and hand state into the
    planner, the planner's commands into the station (the ports the scripted source drives)."""
    builder = DiagramBuilder()
    builder.AddSystem(station.diagram)
    builder.AddSystem(planner)
    for name in ("scene_rgb", "scene_depth", "wrist_rgb", "wrist_depth", "X_WT", "hand_state"):
        builder.Connect(station.diagram.GetOutputPort(name), planner.GetInputPort(name))
    for name in COMMAND_PORTS:
        builder.Connect(planner.GetOutputPort(name), station.diagram.GetInputPort(name))
    builder.ExportOutput(planner.GetOutputPort("status"), "status")
    diagram = builder.Build()
    diagram.set_name("planned_station")
    return diagram


def _image_value(kind: str):
    from pydrake.systems.sensors import ImageDepth32F, ImageRgba8U
    return ImageRgba8U() if kind == "rgb" else ImageDepth32F()


__all__ = ["BeliefSpacePlanner", "PHASES", "PlannerSystemConfig", "connect_planner"]
