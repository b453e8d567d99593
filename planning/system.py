"""planning.BeliefSpacePlanner: the belief-space planner as a Drake system in the station diagram.

Its inputs are what the robot senses: the scene and wrist cameras' RGB-D images, the measured tool
pose and the hand's state. It never reads the plant's gear poses (only the final scoring does).
Its outputs are the command ports the scripted source drives (`X_WT_desired`, `V_WT_desired`,
`A_WT_desired`, `gripper_width`), so the controller's wiring is unchanged. It is a Diagram of
three systems (the pattern of the manipulation course's clutter-clearing station, where perception
systems feed the Planner system through ports):

    PlannerPerception (planning.planner_perception): images + tool pose -> `percept`, the beliefs
        of the look the state machine's `request` port asks for;
    PlannerStateMachine (here): the decisions; a periodic unrestricted update (every `period`,
        the insertion policy's control period) steps the state machine, whose whole state is one
        typed, immutable `PlannerState` in the system's abstract state (a new value each step);
    BeliefDrawer (planning.belief_drawing, only with a Meshcat): the beliefs drawn as they change.

The state machine (`Phase`):

    PERCEIVE (scene camera: detection, a far posterior per gear) -> plan (Algorithm 2)
    -> per step, a MOTION then what ends it: inspect (close view, belief update, replan) | pick (a
       miss, read off the fingers' width, re-perceives) | insert (transport to the policy's start,
       POLICY: the learned policy closed loop at its control rate, release, and a look at the
       seated face with the wrist camera; unseated with the gear in hand puts it back and
       re-perceives, unseated on the shaft fails with the reason). A gear whose pick or insert
       failed is doubted (planning.domain.GearBelief) until a close view of it: the plan inspects
       it before picking it again rather than retry from the same, possibly biased, far view.
    -> DONE, or FAILED with the reason.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from enum import Enum, StrEnum
from types import MappingProxyType
from typing import Any

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import Meshcat
from pydrake.math import RigidTransform
from pydrake.systems.framework import Context, Diagram, DiagramBuilder, LeafSystem, State

from assembly.cameras import CamerasConfig
from assembly.envs.gear_insertion import GearInsertionConfig
from assembly.gearset import SHAFT_HEIGHT, gear_spec
from assembly.inspection import InspectConfig, append_inspect
from assembly.insertion_law import InsertionLaw, PoseHistory
from assembly.scripted_motion import (
    Keyframe,
    KeyframePlan,
    ScriptedInsertionConfig,
    append_move,
    append_pick,
    append_place,
    carry_height,
    down_pose,
    grasp_tool_pose,
    gripper_widths,
    sample_plan,
    start_keyframe_plan,
)
from assembly.station import COMMAND_PORTS, Station
from assembly.world import nominal_grasp, planar_pose
from perception.seat_check import SeatCheckConfig
from planning.belief_drawing import BeliefDrawer
from planning.bfs import Step
from planning.domain import AssemblyDomain, BeliefState, GearBelief
from planning.grasp import aim_tool
from planning.pick import PickReachConfig, plate_pose_from_shaft, reachable_pick
from planning.planner_perception import IMAGE_PORTS, Look, LookRequest, Percept, PlannerPerception


class Phase(StrEnum):
    """The state machine's phase (its value is what `status` and `goflow demo` report)."""

    PERCEIVE = "perceive"  # look with the scene camera at this update, then plan
    MOTION = "motion"  # a keyframe motion; `PlannerState.then` says what ends it
    POLICY = "policy"  # the learned insertion policy, closed loop
    DONE = "done"  # every goal gear inserted
    FAILED = "failed"  # `PlannerState.reason` says why


class Then(Enum):
    """What the planner does when the current motion ends."""

    NOTHING = "nothing"  # the start: hold
    PICTURE = "picture"  # inspect: the close view
    PICKED = "picked"  # pick: are the fingers holding the gear?
    POLICY = "policy"  # insert: start the policy
    RELEASED = "released"  # insert: the seat check, then the next step or a retry
    REPERCEIVE = "reperceive"  # a retry: look again


@dataclass(frozen=True)
class SkillRun:
    """The skill being executed: which, on which gear, since when, with the precondition
    probability it was planned with; `tool` the tool pose a pick aimed at (x, y, heading), and
    after an insert's policy whether it ended `seated` and its `outcome`."""

    skill: str
    gear: str
    t_start: float
    precondition_prob: float
    tool: tuple[float, float, float] | None = None
    seated: bool = False
    outcome: str = ""

    def record(self, t_end: float, outcome: str) -> dict[str, Any]:
        """The executed skill as `goflow demo` reports it: {"skill", "gear", "t_start", "t_end",
        "outcome", "precondition_prob"}."""
        return {
            "skill": self.skill,
            "gear": self.gear,
            "t_start": self.t_start,
            "t_end": t_end,
            "outcome": outcome,
            "precondition_prob": self.precondition_prob,
        }


@dataclass(frozen=True)
class PlannerState:
    """The planner's whole state (its system's abstract state; each update stores a new value):
    `phase`; `beliefs` (gear -> GearBelief); the remaining planned `steps`; every plan made
    (`plans`, [[skill, gear], ...] each); the `executed` skills (SkillRun.record's); the `current`
    skill; the commanded `keyframes` and what ends them (`then`); in POLICY the policy's last
    `target`, the fingers' `width`, the observation `history` and when it ends (`policy_end`);
    the `replans` spent; the failure's `reason`; and a `log` of lines for people."""

    phase: Phase = Phase.PERCEIVE
    beliefs: Mapping[str, GearBelief] = field(default_factory=dict)
    steps: tuple[Step, ...] = ()
    plans: tuple[list[list[str]], ...] = ()
    executed: tuple[dict[str, Any], ...] = ()
    current: SkillRun | None = None
    keyframes: KeyframePlan | None = None
    then: Then = Then.NOTHING
    target: RigidTransform | None = None
    width: float = 0.08
    history: PoseHistory | None = None
    policy_end: float = 0.0
    replans: int = 0
    reason: str = ""
    log: tuple[str, ...] = ()

    @property
    def finished(self) -> bool:
        """Whether the run is over (DONE or FAILED)."""
        return self.phase in (Phase.DONE, Phase.FAILED)


@dataclass
class PlannerSystemConfig:
    """period: the state machine's and the insertion policy's period [s]; motion, inspect: the
    skills' keyframe motions; pick: how a pick's heading and descent are made reachable
    (planning.pick.reachable_pick); max_replans: re-perceptions after a failed pick or insert; close_prior:
    the close view's prior box (multiple of the belief's std, min, max half-width [m]);
    seated_tolerance: the tool within this of its seated height means the gear is on its shaft;
    settle_tolerance, max_wait: a motion ends when the tool is this close to its last keyframe, or
    this long after it; scene_extrinsic_std: how well the scene camera's extrinsics are known,
    (translation [m], rotation [rad]) std: the x-y shift it causes on the table (assembly.cameras.
    extrinsic_error_on_table) and the rotation in yaw are added to each far belief's std;
    wrist_extrinsic_std: the same of the wrist camera's hand-eye calibration, added to each close
    belief's std (at the close view's camera pose); seat_check: after an insert
    the tool says seated, the wrist camera's view from the retreat checks the gear's face
    (perception.seat_check; None: trust the tool's height alone)."""

    period: float = 0.04
    motion: ScriptedInsertionConfig = field(default_factory=ScriptedInsertionConfig)
    inspect: InspectConfig = field(default_factory=InspectConfig)
    pick: PickReachConfig = field(default_factory=PickReachConfig)
    max_replans: int = 2
    close_prior: tuple[float, float, float] = (4.0, 0.005, 0.03)
    seated_tolerance: float = 0.002
    settle_tolerance: float = 0.002
    max_wait: float = 3.0
    scene_extrinsic_std: tuple[float, float] = (0.0, 0.0)
    wrist_extrinsic_std: tuple[float, float] = (0.0, 0.0)
    seat_check: SeatCheckConfig | None = field(default_factory=SeatCheckConfig)


def _pose4(X: RigidTransform) -> np.ndarray:
    m = X.rotation().matrix()
    return np.array([*X.translation(), np.arctan2(m[1, 0], m[0, 0])])


class PlannerStateMachine(LeafSystem):
    """The planner's decisions (see the module docstring): `skills` the insert Skill per gear,
    `domain` the planning domain (planning.domain.gearbox_domain), `X_WS` each shaft's pose (from
    the plate's known pose), `cameras` the station's CamerasConfig (the inspect motion's wrist
    camera), `X_WT_start`, `width_start` the robot's start. ValueError when a goal gear has no
    skill or shaft pose.

    Inputs: percept (PlannerPerception's answer to `request`), X_WT (the measured tool pose),
    hand_state (finger positions and velocities), external_wrench (the station's estimate, read
    only while a skill that senses it runs). Outputs: the command ports (COMMAND_PORTS),
    request (the LookRequest of the state now), beliefs (the state's), status (a dict: phase,
    executed, plans, replans, reason). Every output is a function of the state and the time
    alone, so the loop through the perception has no direct feedthrough."""

    def __init__(
        self,
        skills: Mapping[str, Any],
        domain: AssemblyDomain,
        X_WS: Mapping[str, RigidTransform],
        cameras: CamerasConfig,
        X_WT_start: RigidTransform,
        width_start: float,
        config: PlannerSystemConfig | None = None,
    ) -> None:
        super().__init__()
        self.set_name("planner_state_machine")
        self.config = config or PlannerSystemConfig()
        self.skills, self.domain, self.X_WS, self.cameras = skills, domain, X_WS, cameras
        self.X_WT_start = X_WT_start
        missing = [g for g in domain.goal if g not in skills or g not in X_WS]
        if missing:
            raise ValueError(f"no insert skill or shaft pose for gear(s) {missing}")
        self.laws = {}
        for gear in domain.goal:
            c = GearInsertionConfig(gear=gear)
            seated = _pose4(X_WS[gear] @ nominal_grasp(gear).inverse())
            sensing = getattr(skills[gear], "sensing", "pose")  # the skill's observation law
            self.laws[gear] = InsertionLaw(tuple(seated), c.action_scale, c.workspace, c.history, c.control_dt, sensing)
            self.t_max = c.t_max
        self.DeclareAbstractInputPort("percept", AbstractValue.Make(Percept(LookRequest())))
        self.DeclareAbstractInputPort("X_WT", AbstractValue.Make(RigidTransform()))
        self.DeclareVectorInputPort("hand_state", 4)
        self.DeclareVectorInputPort("external_wrench", 4)  # read only by skills that sense it
        start = start_keyframe_plan(X_WT_start, width_start)
        start.append(0.5, X_WT_start, width_start, "start: hold")
        self._state = self.DeclareAbstractState(AbstractValue.Make(PlannerState(keyframes=start, width=width_start)))
        self.DeclarePeriodicUnrestrictedUpdateEvent(self.config.period, 0.0, self._update)
        now = {self.time_ticket(), self.abstract_state_ticket(self._state)}
        state_only = {self.abstract_state_ticket(self._state)}
        self.DeclareAbstractOutputPort(
            "X_WT_desired",
            lambda: AbstractValue.Make(RigidTransform()),
            lambda c, o: o.set_value(self._sample(c)[0]),
            now,
        )
        self.DeclareVectorOutputPort("V_WT_desired", 6, lambda c, o: o.SetFromVector(self._sample(c)[1]), now)
        self.DeclareVectorOutputPort("A_WT_desired", 6, lambda c, o: o.SetFromVector(self._sample(c)[2]), now)
        self.DeclareVectorOutputPort("gripper_width", 1, lambda c, o: o.SetFromVector([self._sample(c)[3]]), now)
        self.DeclareAbstractOutputPort(
            "request",
            lambda: AbstractValue.Make(LookRequest()),
            lambda c, o: o.set_value(self.request(self.state(c))),
            state_only,
        )
        self.DeclareAbstractOutputPort(
            "beliefs", lambda: AbstractValue.Make({}), lambda c, o: o.set_value(dict(self.state(c).beliefs)), state_only
        )
        self.DeclareAbstractOutputPort("status", lambda: AbstractValue.Make({}), self._calc_status, state_only)

    # -- outputs -----------------------------------------------------------------------------

    def state(self, context: Context) -> PlannerState:
        """The planner's state in `context` (this system's context)."""
        return context.get_abstract_state(self._state).get_value()

    def request(self, s: PlannerState) -> LookRequest:
        """The look state `s` needs at its next update: SCENE of the gears not inserted while
        perceiving; CLOSE of the inspected gear and SEAT of an insert's gear (when the tool said
        seated and `config.seat_check` is set) while their motions run; else NOTHING."""
        if s.phase is Phase.PERCEIVE:
            return LookRequest(
                Look.SCENE,
                gears=tuple(g for g in self.domain.goal if g not in s.beliefs or s.beliefs[g].location != "inserted"),
            )
        if s.phase is Phase.MOTION and s.then is Then.PICTURE:
            return LookRequest(Look.CLOSE, gear=s.current.gear, belief=s.beliefs[s.current.gear])
        if (
            s.phase is Phase.MOTION
            and s.then is Then.RELEASED
            and s.current.seated
            and self.config.seat_check is not None
        ):
            return LookRequest(Look.SEAT, gear=s.current.gear)
        return LookRequest()

    def _sample(self, context: Context):
        s = self.state(context)
        if s.phase is Phase.POLICY and s.target is not None:
            return s.target, np.zeros(6), np.zeros(6), s.width
        return sample_plan(s.keyframes, context.get_time())

    def _calc_status(self, context: Context, output: AbstractValue) -> None:
        s = self.state(context)
        output.set_value(
            {
                "phase": s.phase.value,
                "executed": list(s.executed),
                "plans": list(s.plans),
                "replans": s.replans,
                "reason": s.reason,
            }
        )

    # -- the state machine -------------------------------------------------------------------

    def _update(self, context: Context, state: State) -> None:
        s = self.state(context)
        t = context.get_time()
        X_WT = self.GetInputPort("X_WT").Eval(context)
        if s.phase is Phase.PERCEIVE:
            s = self._perceived(s, self._percept(context, Look.SCENE), t, X_WT)
        elif s.phase is Phase.MOTION and self._motion_done(s, t, X_WT):
            s = self._after_motion(context, s, t, X_WT)
        elif s.phase is Phase.POLICY:
            s = self._policy_step(context, s, t, X_WT)
        state.get_mutable_abstract_state(self._state).set_value(s)

    def _percept(self, context: Context, look: Look) -> Percept:
        percept = self.GetInputPort("percept").Eval(context)
        if percept.request.look is not look:
            raise RuntimeError(
                f"the perception answered a {percept.request.look.name} look; the planner asked "
                f"for {look.name}: connect its request input to the planner's request output"
            )
        return percept

    def _motion_done(self, s: PlannerState, t: float, X_WT: RigidTransform) -> bool:
        end = s.keyframes.end_time
        if t < end:
            return False
        near = np.linalg.norm(X_WT.translation() - s.keyframes.keyframes[-1].X_WT.translation())
        return near < self.config.settle_tolerance or t > end + self.config.max_wait

    def _hold(self, s: PlannerState, t: float, X_WT: RigidTransform) -> KeyframePlan:
        """A new keyframe plan starting now, from the current command."""
        last = s.keyframes.keyframes[-1] if s.keyframes else None
        policy = s.phase is Phase.POLICY and s.target is not None
        X = s.target if policy else (last.X_WT if last else X_WT)
        w = s.width if policy or last is None else last.width
        return KeyframePlan([Keyframe(t, X, w, "now")])

    def _perceived(self, s: PlannerState, percept: Percept, t: float, X_WT: RigidTransform) -> PlannerState:
        if percept.reason:  # a gear not seen
            return self._fail(s, percept.reason)
        beliefs = dict(s.beliefs)
        for gear, b in percept.beliefs.items():
            doubted = gear in s.beliefs and s.beliefs[gear].doubted  # still owed a close view
            beliefs[gear] = replace(b, doubted=True) if doubted else b
        s = replace(
            s, beliefs=beliefs, log=(*s.log, f"t = {t:.2f} s: perceived {sorted(beliefs)} in {percept.seconds:.1f} s")
        )
        return self._replan(s, t, X_WT)

    def _replan(self, s: PlannerState, t: float, X_WT: RigidTransform) -> PlannerState:
        plan = self.domain.plan(BeliefState.of(dict(s.beliefs), None))
        if not plan.found:
            return self._fail(s, f"no plan: {plan.reason}")
        s = replace(s, plans=(*s.plans, plan.pairs()), steps=tuple(plan.steps))
        return self._next_step(s, t, X_WT)

    def _fail(self, s: PlannerState, reason: str) -> PlannerState:
        return replace(s, phase=Phase.FAILED, reason=reason, log=(*s.log, reason))

    def _next_step(self, s: PlannerState, t: float, X_WT: RigidTransform) -> PlannerState:
        if not s.steps:
            done = all(s.beliefs[g].location == "inserted" for g in self.domain.goal)
            return replace(
                s,
                phase=Phase.DONE if done else Phase.FAILED,
                reason="" if done else "the plan ended before every gear was inserted",
            )
        step = s.steps[0]
        current = SkillRun(step.skill, step.gear, t, float(step.probability))
        s = replace(s, steps=s.steps[1:], current=current)
        c = self.config
        gear = step.gear
        belief = s.beliefs[gear]
        plan = self._hold(s, t, X_WT)
        open_w, closed_w = gripper_widths(gear, c.motion)
        if step.skill == "inspect":
            append_inspect(plan, gear, belief.mean[:2], self.cameras.wrist, c.inspect)
            then = Then.PICTURE
        elif step.skill == "pick":
            aim = np.asarray(self.domain.aim_xi.get(gear, (0.0, 0.0, 0.0)), float)
            # the gear repeats every tooth pitch: of the headings giving the aimed yaw, the one
            # nearest pi/2 (the fingers close along world x, as in the scripted pick)
            pitch = 2 * np.pi / gear_spec(gear).teeth
            k = np.round((np.pi / 2 - (belief.mean[2] - aim[2])) / pitch)
            tool = aim_tool(belief.mean, aim - [0.0, 0.0, k * pitch])
            # ... unless the open fingers would touch the plate or another gear there: then the same
            # grasp at the nearest heading a multiple of the pitch away that clears them; near the
            # base the pick moves slowly (planning.pick.reachable_pick; off with c.pick.enabled False)
            others = {
                g: tuple(self.X_WS[g].translation()[:2]) if b.location == "inserted" else tuple(b.mean[:2])
                for g, b in s.beliefs.items()
                if g != gear and b.location != "hand" and (b.location != "inserted" or g in self.X_WS)
            }
            tool, descend_speed = reachable_pick(
                gear,
                belief.mean,
                aim,
                tool,
                plate_pose=plate_pose_from_shaft(gear, self.X_WS[gear]),
                others=others,
                motion=c.motion,
                config=c.pick,
            )
            heading = float(tool[2])
            current = replace(current, tool=tuple(tool.tolist()))
            if plan.keyframes[-1].width < open_w:
                plan.append(c.motion.gripper_time, plan.keyframes[-1].X_WT, open_w, f"{gear}: open")
            # aim the tool: the gear's believed centre shifted by the aimed grasp error
            X_WG_aim = planar_pose(tool[0], tool[1], belief.mean[2])
            append_pick(
                plan, gear, X_WG_aim, heading, carry_height(gear, self.X_WS[gear], c.motion), c.motion, descend_speed
            )
            then = Then.PICKED
        elif step.skill == "insert":
            law = self.laws[gear]
            seated = np.asarray(law.seated)
            start = seated + [0.0, 0.0, SHAFT_HEIGHT + GearInsertionConfig().start_height, 0.0]
            carry = carry_height(gear, self.X_WS[gear], c.motion)
            append_move(
                plan,
                down_pose(np.array([start[0], start[1], carry]), start[3]),
                closed_w,
                f"{gear}: transport",
                c.motion.speed,
                c.motion.min_segment,
            )
            append_move(
                plan,
                down_pose(start[:3], start[3]),
                closed_w,
                f"{gear}: to the policy's start",
                c.motion.insert_speed * 3,
                c.motion.min_segment,
            )
            plan.append(c.motion.pause, plan.keyframes[-1].X_WT, closed_w, f"{gear}: steady")
            then = Then.POLICY
        else:
            raise ValueError(f"planned step {step.skill}({gear}); the planner runs inspect, pick and insert")
        return replace(s, current=current, keyframes=plan, then=then, phase=Phase.MOTION)

    def _after_motion(self, context: Context, s: PlannerState, t: float, X_WT: RigidTransform) -> PlannerState:
        gear = s.current.gear if s.current else None
        if s.then is Then.PICTURE:
            percept = self._percept(context, Look.CLOSE)
            b, seen = s.beliefs[gear], percept.beliefs.get(gear)
            mean, std = (seen.mean, seen.std) if seen is not None else (b.mean, b.std)
            s = replace(s, beliefs={**s.beliefs, gear: GearBelief("table", mean, std, b.inspections + 1)})
            s = self._record(s, t, "informative" if seen is not None else f"uninformative: {percept.reason}")
            return self._replan(s, t, X_WT)
        if s.then is Then.PICKED:
            holding, width = self._holding(context, gear)
            if not holding:  # the fingers closed on nothing
                s = self._record(s, t, f"missed (fingers {1e3 * width:.1f} mm apart)")
                return self._retry(s, t, X_WT)
            b = s.beliefs[gear]
            s = replace(
                s, beliefs={**s.beliefs, gear: GearBelief("hand", b.mean, b.std, b.inspections, s.current.tool)}
            )
            return self._next_step(self._record(s, t, "holding"), t, X_WT)
        if s.then is Then.POLICY:
            history = PoseHistory(self.laws[gear])
            history.reset(_pose4(X_WT), self._wrench(context, gear))  # tared in the air, holding the gear
            s = replace(
                s, history=history, policy_end=t + self.t_max, width=s.keyframes.keyframes[-1].width, phase=Phase.POLICY
            )
            return replace(s, target=self._policy_target(s, gear, X_WT))
        if s.then is Then.RELEASED:
            if s.current.seated and self.config.seat_check is not None:
                check = self._percept(context, Look.SEAT).seat
                s = replace(s, log=(*s.log, f"t = {t:.2f} s: seat check: {check.reason}"))
                if check.verdict == "unseated":
                    s = self._record(s, t, f"unseated (wrist camera: {check.reason})")
                    return self._fail(
                        s,
                        f"insert({gear}) left the gear on its shaft unseated ({check.reason}); "
                        "no skill takes a gear back off its shaft",
                    )
            s = self._record(s, t, s.current.outcome)
            if not s.current.seated:
                return self._retry(s, t, X_WT)
            b = s.beliefs[gear]
            s = replace(s, beliefs={**s.beliefs, gear: GearBelief("inserted", b.mean, b.std, b.inspections)})
            return self._next_step(s, t, X_WT)
        if s.then is Then.REPERCEIVE:
            return replace(s, phase=Phase.PERCEIVE)
        return s

    def _policy_target(self, s: PlannerState, gear: str, X_WT: RigidTransform) -> RigidTransform:
        """The policy's next tool target from the observation history of `s`."""
        action = self.skills[gear].act(s.history.observation())
        target = self.laws[gear].target(action, _pose4(X_WT))
        return down_pose(target[:3], target[3])

    def _policy_step(self, context: Context, s: PlannerState, t: float, X_WT: RigidTransform) -> PlannerState:
        gear = s.current.gear
        history = copy.deepcopy(s.history)  # the stored state is never changed in place
        history.push(_pose4(X_WT), self._wrench(context, gear))
        s = replace(s, history=history)
        if t + 1e-9 < s.policy_end:
            return replace(s, target=self._policy_target(s, gear, X_WT))
        # done: seated if the tool came down to its seated height (the gear is on its shaft)
        # ... and the fingers still hold it (a dropped gear lets the tool come down too)
        dz = float(X_WT.translation()[2] - self.laws[gear].seated[2])
        holding, _ = self._holding(context, gear)
        seated = dz < self.config.seated_tolerance and holding
        outcome = (
            "seated"
            if seated
            else "dropped"
            if not holding
            else f"unseated (tool {1e3 * dz:.1f} mm above seated; put back)"
        )
        s = replace(s, current=replace(s.current, seated=seated, outcome=outcome))
        if seated or not holding:
            plan = self._open_and_lift(s, t, X_WT, gear, f"{gear}: release", f"{gear}: retreat")
        else:  # still in hand: put it back where it was picked, on the table the scene camera sees
            tool = s.beliefs[gear].tool
            plan = self._hold(s, t, X_WT)
            X_WT_place = grasp_tool_pose(gear, planar_pose(tool[0], tool[1], 0.0), tool[2], self.config.motion)
            append_place(
                plan, gear, X_WT_place, carry_height(gear, self.X_WS[gear], self.config.motion), self.config.motion
            )
        return replace(s, keyframes=plan, then=Then.RELEASED, phase=Phase.MOTION, target=None)

    def _wrench(self, context: Context, gear: str) -> np.ndarray | None:
        """The station's external-wrench estimate now if `gear`'s skill senses it, else None."""
        if self.laws[gear].sensing != "wrench":
            return None
        return self.GetInputPort("external_wrench").Eval(context)

    def _holding(self, context: Context, gear: str) -> tuple[bool, float]:
        """Whether the fingers hold `gear` (they stopped on it rather than closing past its
        diameter), and their width [m]."""
        q = self.GetInputPort("hand_state").Eval(context)
        width = float(q[0] + q[1])
        return width > 2 * gear_spec(gear).tip_radius - 0.005, width

    def _open_and_lift(
        self, s: PlannerState, t: float, X_WT: RigidTransform, gear: str, open_label: str, lift_label: str
    ) -> KeyframePlan:
        """From the current command: open the fingers for `gear`, then lift by retreat_height."""
        c = self.config.motion
        open_w, _ = gripper_widths(gear, c)
        plan = self._hold(s, t, X_WT)
        plan.append(c.gripper_time, plan.keyframes[-1].X_WT, open_w, open_label)
        up = RigidTransform(
            plan.keyframes[-1].X_WT.rotation(), plan.keyframes[-1].X_WT.translation() + [0, 0, c.retreat_height]
        )
        append_move(plan, up, open_w, lift_label, c.speed, c.min_segment)
        return plan

    def _record(self, s: PlannerState, t: float, outcome: str) -> PlannerState:
        return replace(s, executed=(*s.executed, s.current.record(t, outcome)))

    def _retry(self, s: PlannerState, t: float, X_WT: RigidTransform) -> PlannerState:
        if s.replans >= self.config.max_replans:
            return self._fail(s, f"{s.current.skill}({s.current.gear}) failed and {s.replans} replans are spent")
        # re-perceive from a clear view: open, lift, back to the start pose (the arm out of the
        # scene camera's view), then look again; the failed gear's belief is doubted
        gear = s.current.gear
        b = s.beliefs[gear]
        s = replace(
            s, replans=s.replans + 1, beliefs={**s.beliefs, gear: GearBelief("table", b.mean, b.std, 0, doubted=True)}
        )
        c = self.config.motion
        plan = self._open_and_lift(s, t, X_WT, gear, "retry: open", "retry: lift")
        append_move(plan, self.X_WT_start, plan.keyframes[-1].width, "retry: clear the view", c.speed, c.min_segment)
        return replace(s, keyframes=plan, then=Then.REPERCEIVE, phase=Phase.MOTION)


class BeliefSpacePlanner(Diagram):
    """The planner in the station (see the module docstring): its perception, its state machine
    and, with a `meshcat`, its belief drawing, wired as one Diagram. `skills`: the insert Skill
    per gear; `domain`: the planning domain (planning.domain.gearbox_domain); `X_WS`: each
    shaft's pose (from the plate's known pose); `cameras`: the station's CamerasConfig (as
    calibrated); `X_WT_start`, `width_start`: the robot's start; `meshcat`: if given, each gear's
    belief is drawn there (planning.belief_drawing) whenever it changes. ValueError when a goal
    gear has no skill or shaft pose.

    Inputs: scene_rgb, scene_depth, wrist_rgb, wrist_depth, X_WT, hand_state, external_wrench.
    Outputs: the command ports (COMMAND_PORTS), beliefs and status."""

    def __init__(
        self,
        skills: Mapping[str, Any],
        domain: AssemblyDomain,
        X_WS: Mapping[str, RigidTransform],
        cameras: CamerasConfig,
        X_WT_start: RigidTransform,
        width_start: float,
        config: PlannerSystemConfig | None = None,
        meshcat: Meshcat | None = None,
    ) -> None:
        super().__init__()
        config = config or PlannerSystemConfig()
        builder = DiagramBuilder()
        machine = builder.AddSystem(PlannerStateMachine(skills, domain, X_WS, cameras, X_WT_start, width_start, config))
        perception = builder.AddSystem(
            PlannerPerception(
                cameras,
                tuple(domain.goal),
                X_WS,
                config.close_prior,
                config.scene_extrinsic_std,
                config.seat_check,
                config.wrist_extrinsic_std,
            )
        )
        for name in IMAGE_PORTS:
            builder.ExportInput(perception.GetInputPort(name), name)
        builder.ConnectInput(builder.ExportInput(perception.GetInputPort("X_WT"), "X_WT"), machine.GetInputPort("X_WT"))
        builder.ExportInput(machine.GetInputPort("hand_state"), "hand_state")
        builder.ExportInput(machine.GetInputPort("external_wrench"), "external_wrench")
        builder.Connect(machine.GetOutputPort("request"), perception.GetInputPort("request"))
        builder.Connect(perception.GetOutputPort("percept"), machine.GetInputPort("percept"))
        for name in (*COMMAND_PORTS, "beliefs", "status"):
            builder.ExportOutput(machine.GetOutputPort(name), name)
        if meshcat is not None:
            drawer = builder.AddSystem(BeliefDrawer(meshcat, config.period))
            builder.Connect(machine.GetOutputPort("beliefs"), drawer.GetInputPort("beliefs"))
        builder.BuildInto(self)
        self.set_name("belief_space_planner")
        self.machine, self.perception, self.config = machine, perception, config

    def run(self, context: Context) -> PlannerState:
        """The planner's state in `context` (this Diagram's context; read only)."""
        return self.machine.state(self.GetSubsystemContext(self.machine, context))

    @property
    def domain(self) -> AssemblyDomain:
        """The planning domain the planner plans in (its preconditions, eta, goal gears; as given)."""
        return self.machine.domain

    @property
    def skills(self) -> Mapping[str, Any]:
        """The insert Skill per gear the planner runs (a read-only view of the mapping given)."""
        return MappingProxyType(self.machine.skills)


def connect_planner(station: Station, planner: BeliefSpacePlanner) -> Diagram:
    """The station driven by `planner`: its cameras, measured tool pose, hand state and external
    wrench estimate into the planner, the planner's commands into the station (the ports the
    scripted source drives)."""
    builder = DiagramBuilder()
    builder.AddSystem(station.diagram)
    builder.AddSystem(planner)
    for name in ("scene_rgb", "scene_depth", "wrist_rgb", "wrist_depth", "X_WT", "hand_state", "external_wrench"):
        builder.Connect(station.diagram.GetOutputPort(name), planner.GetInputPort(name))
    for name in COMMAND_PORTS:
        builder.Connect(planner.GetOutputPort(name), station.diagram.GetInputPort(name))
    builder.ExportOutput(planner.GetOutputPort("status"), "status")
    diagram = builder.Build()
    diagram.set_name("planned_station")
    return diagram


__all__ = [
    "BeliefSpacePlanner",
    "Phase",
    "PlannerState",
    "PlannerStateMachine",
    "PlannerSystemConfig",
    "SkillRun",
    "Then",
    "connect_planner",
]
