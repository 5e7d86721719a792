"""An intervention on the panel, onboard: the primitive that works one part from a goal the
vessel resolved (messages.InterventionGoal) and reports each phase in telemetry.

    approach   the tool to the pre-grasp pose, PRE_GRASP_M back along its approach, gripper open
    pre-grasp  in along the approach to the grasp pose, the fingers passing either side of the handle
    grasp      the fingers close until the opening stops: holding if they stopped on the handle,
               closed on nothing if they met short of it
    turn       the tool turns about the part's axis through its pivot (arm_control.PoseReference
               with the axis as a task of its own), the reference never more than LEAD_MAX_RAD
               ahead of where the tool is; the part not following is a stall: a lever at its
               stop is thrown, anything else does not turn
    release    the fingers open
    retreat    back out along the approach to the pre-grasp pose of the part as it now stands
    done | failed

A grasp that closes on nothing, or one lost during the turn (the opening collapses: the handle
slipped out) short of a lever's stop (past it, the stop pried the fingers off: thrown), is tried
again from the approach, twice; the third time, or a part that does not
turn, ends failed with its reason, after the release and the retreat: the arm backs off and
nothing is pushed further. Handed an intervention with the fingers already on the part (a rebooted
onboard), it lets go first and says so. The phases' clocks stop while the arm holds (failsafe, operator
hold), and the gripper keeps squeezing what it holds meanwhile."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from typing import ClassVar

import numpy as np
import pinocchio as pin

from abyss.common.geometry import rotation_about, rotation_of
from abyss.interface.messages import REFINABLE_PHASES, InterventionGoal
from abyss.stations.onboard.arm_control import PoseReference

PRE_GRASP_M = 0.10
OPEN_GAIN_PER_S = 2.0
SQUEEZE_MPS = 0.05  # the fingers close, and squeeze what they hold, at this speed [m/s]
# The openings a grip is judged by (Grip.of), from where the fingers meet the handle (its
# thickness less the fingers' gap when closed). The work-class ROV's fingers meet the valve panel's
# 40 mm handles at 16 mm, stand at 13-14 mm squeezing one (measured) and reach at 30 mm: below
# half the meeting opening they closed past where the handle would be (8 mm there), above it by
# HELD_SLACK_M they hold nothing (24 mm); reaching, they stand REACH_CLEARANCE_M wider than they
# meet it, 7 mm clear either side (30 mm); on the way in and out OPEN_SHORT_M short of their stops
HELD_SLACK_M = 0.008
REACH_CLEARANCE_M = 0.014
OPEN_SHORT_M = 0.01
NEAR_M = 0.03  # the tool this close to where the part's grasp would put it: on the handle
PRIED_M = 0.006  # the fingers forced open this far past their hold: the part resists the turn
OPENING_STILL_M = 0.0005  # the opening moved less than this over SETTLE_S: the fingers stopped
SLIDE_MPS = 0.05  # in and out along the approach [m/s]
TURN_RATE_RADPS = 0.3
LEAD_MAX_RAD = math.radians(8.0)
STALL_S = 2.0  # the tool turned less than PROGRESS_RAD in this long: the part does not turn
PROGRESS_RAD = math.radians(1.0)
TURN_TOLERANCE_RAD = math.radians(2.0)
# a lever is pushed this far past its stop, and stops there: the shaft twists in the grip, the
# part lagging the tool by 6-7 deg through a throw (measured); at 5 deg the tool's turn ended with
# the lever 3 deg short of its stop
OVERTRAVEL_RAD = math.radians(12.0)
AT_STOP_RAD = OVERTRAVEL_RAD + math.radians(3.0)  # a thrown lever that stalls this close to its stop is there
POSITION_TOLERANCE_M = 0.005
ORIENTATION_TOLERANCE_RAD = 0.03
SETTLE_S = 0.3
ATTEMPTS = 3  # a failed grasp or a slip is tried twice more
log = logging.getLogger(__name__)


class Phase(StrEnum):
    """An intervention's phases, in order (messages.INTERVENTION_PHASES, less "" for none yet)."""

    APPROACH = "approach"
    PRE_GRASP = "pre-grasp"
    GRASP = "grasp"
    TURN = "turn"
    RELEASE = "release"
    RETREAT = "retreat"
    DONE = "done"
    FAILED = "failed"


REFINABLE = frozenset(Phase(phase) for phase in REFINABLE_PHASES)
TIMEOUT_S = {
    Phase.APPROACH: 40.0,
    Phase.PRE_GRASP: 10.0,
    Phase.GRASP: 5.0,
    Phase.RELEASE: 4.0,
    Phase.RETREAT: 10.0,
}


@dataclass(frozen=True)
class Grip:
    """The gripper's openings for a robot's fingers on a site's handles [m]."""

    open_m: float  # on the way in and out
    hold_min_m: float  # closed below this: they hold nothing
    held_max_m: float  # closed on a handle, they stand below this
    reach_m: float  # opened while an arm goal is reached for, to pass either side of a handle

    @staticmethod
    def of(opening_m: float, closed_gap_m: float, handle_thickness_m: float) -> Grip:
        """From the fingers' full opening and their gap when closed (description.robot.Robot) and the
        handles' thickness (the site's panel)."""
        meet_m = handle_thickness_m - closed_gap_m
        return Grip(opening_m - OPEN_SHORT_M, meet_m / 2, meet_m + HELD_SLACK_M, meet_m + REACH_CLEARANCE_M)

    def open_mps(self, opening_m: float) -> float:
        """The fingers' speed towards `open_m` from `opening_m` [m/s]."""
        return float(np.clip(OPEN_GAIN_PER_S * (self.open_m - opening_m), -0.05, 0.05))

    def opened(self, opening_m: float) -> bool:
        return opening_m > self.open_m - 0.01


@dataclass(frozen=True)
class Command:
    """What the primitive asks of the arm this period."""

    reference: PoseReference
    gripper_mps: float


class InterventionRun:
    """One intervention, from its goal to done or failed."""

    def __init__(self, goal: InterventionGoal, grip: Grip) -> None:
        self._take(goal)
        self.grip = grip
        self.phase = Phase.APPROACH
        self.reason = ""  # why it failed, once it will
        self.retry = ""  # why the grasp is tried again, while it is
        self.attempts = 1
        self.phase_s = 0.0  # in this phase, while the arm was free
        self.settled_s = 0.0  # within tolerance for this long
        self.from_rad = 0.0  # the part's angle (from the goal's grasp) where this grasp began
        self.turned_rad = 0.0  # the tool's turn about the axis since the grasp pose, measured
        self.reference_rad = 0.0  # the turn's reference
        self.progress = (0.0, 0.0)  # (phase_s, turned_rad) when the part last moved on
        self.slide_m = 0.0  # along the approach, in the slides
        self.openings: list[tuple[float, float]] = []  # (phase_s, opening) while closing
        self.hold_opening_m = 0.0  # where the fingers stopped on the handle
        self.started = False  # the first period seen: what the arm holds is looked at then

    def _take(self, goal: InterventionGoal) -> None:
        self.goal = goal
        self.axis = np.asarray(goal.axis_world, float) / np.linalg.norm(goal.axis_world)
        self.pivot = np.asarray(goal.pivot_m_world, float)
        self.grasp_m = np.asarray(goal.grasp_m_world, float)
        self.grasp_rotation = rotation_of(goal.grasp_orientation_wxyz_world)

    def refine(self, goal: InterventionGoal) -> bool:
        """The same intervention resolved again from a newer estimate of the panel: taken whole
        until the fingers close (recognition sharpens as the vehicle closes in); after, only the
        pivot's shift, by which the part moves with the navigation's frame (its error wanders by
        millimetres a second, and the vehicle and the arm move with it: 5 mm over a 4 s turn
        pulled the fingers off the bar), while what the turn is measured from stays."""
        if goal.command_id != self.goal.command_id or not self.active:
            return False
        if self.phase in REFINABLE:
            self._take(goal)
            return True
        shift_m = np.asarray(goal.pivot_m_world, float) - self.pivot
        self.pivot, self.grasp_m = self.pivot + shift_m, self.grasp_m + shift_m
        return True

    @property
    def active(self) -> bool:
        return self.phase not in (Phase.DONE, Phase.FAILED)

    @property
    def holding(self) -> bool:
        return self.phase in (Phase.GRASP, Phase.TURN)

    # -- geometry --------------------------------------------------------------------------
    def pose_at(self, angle_rad: float, back_m: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """The tool's pose with the part turned `angle_rad` from the grasp, `back_m` out along
        the approach: position [m, world] and rotation."""
        turn = rotation_about(self.axis, angle_rad)
        rotation = turn @ self.grasp_rotation
        position = self.pivot + turn @ (self.grasp_m - self.pivot) - back_m * rotation[:, 0]
        return position, rotation

    def measure(self, tool: pin.SE3) -> float:
        """How far the tool has turned about the axis from the grasp's orientation [rad]."""
        return float(self.axis @ pin.log3(tool.rotation @ self.grasp_rotation.T))

    # -- the primitive ---------------------------------------------------------------------
    def step(self, tool: pin.SE3, opening_m: float, dt_s: float, enabled: bool) -> Command:
        """One control period: the tool's pose and the gripper's opening as measured now."""
        self.turned_rad = self.measure(tool)
        if not self.started:
            self.started = True
            self._found(tool, opening_m)
        if not self.active:  # backed off: the arm stays at the pre-grasp pose
            return Command(PoseReference(*self.pose_at(self.from_rad, PRE_GRASP_M)), 0.0)
        if not enabled:  # the arm holds: so does the primitive, and the grip
            position, rotation = self._held_pose()
            return Command(PoseReference(position, rotation), -SQUEEZE_MPS if self.holding else 0.0)
        self.phase_s += dt_s
        return self._STEPS[self.phase](self, tool, opening_m, dt_s)

    def _held_pose(self) -> tuple[np.ndarray, np.ndarray]:
        if self.phase in (Phase.GRASP, Phase.TURN, Phase.RELEASE):
            return self.pose_at(self.reference_rad if self.phase == Phase.TURN else self.turned_rad)
        back = {
            Phase.APPROACH: PRE_GRASP_M,
            Phase.PRE_GRASP: PRE_GRASP_M - self.slide_m,
            Phase.RETREAT: self.slide_m,
        }.get(self.phase, PRE_GRASP_M)
        return self.pose_at(self.from_rad, back)

    def _found(self, tool: pin.SE3, opening_m: float) -> None:
        """Handed the intervention with the fingers already closed on the part (a rebooted
        onboard's arm, as the kill left it): let go where it stands, back out, and grasp again
        from there; the target stays the goal's, which is absolute. Said as the retry's reason."""
        on_handle = float(np.linalg.norm(self.pose_at(self.turned_rad)[0] - tool.translation)) < NEAR_M
        if on_handle and self.grip.hold_min_m <= opening_m <= self.grip.held_max_m:
            self.retry = f"found holding {self.goal.target} (rebooted?): let go, to grasp it again"
            log.warning("intervention %d: %s", self.goal.command_id, self.retry)
            self._next(Phase.RELEASE)

    def _next(self, phase: Phase) -> None:
        self.phase, self.phase_s, self.settled_s, self.slide_m = phase, 0.0, 0.0, 0.0
        self.openings = []

    def _fail(self, reason: str) -> None:
        """Back off: open, retreat, then failed with `reason`."""
        self.reason = reason
        self._next(Phase.RELEASE)

    def _timed_out(self, what: str) -> bool:
        if self.phase_s < TIMEOUT_S[self.phase]:
            return False
        self._fail(f"{self.goal.target}: {what} in {TIMEOUT_S[self.phase]:g} s")
        return True

    def _settled(self, tool: pin.SE3, position: np.ndarray, rotation: np.ndarray, dt_s: float) -> bool:
        error_m = float(np.linalg.norm(position - tool.translation))
        error_rad = float(np.linalg.norm(pin.log3(rotation @ tool.rotation.T)))
        within = error_m < POSITION_TOLERANCE_M and error_rad < ORIENTATION_TOLERANCE_RAD
        self.settled_s = self.settled_s + dt_s if within else 0.0
        return self.settled_s >= SETTLE_S

    def _open(self, opening_m: float) -> float:
        return self.grip.open_mps(opening_m)

    def _approach(self, tool: pin.SE3, opening_m: float, dt_s: float) -> Command:
        position, rotation = self.pose_at(self.from_rad, PRE_GRASP_M)
        if self._settled(tool, position, rotation, dt_s) and self.grip.opened(opening_m):
            self._next(Phase.PRE_GRASP)
        else:
            self._timed_out("the pre-grasp pose not reached")
        return Command(PoseReference(position, rotation), self._open(opening_m))

    def _pre_grasp(self, tool: pin.SE3, opening_m: float, dt_s: float) -> Command:
        self.slide_m = min(PRE_GRASP_M, self.slide_m + SLIDE_MPS * dt_s)
        position, rotation = self.pose_at(self.from_rad, PRE_GRASP_M - self.slide_m)
        sliding = self.slide_m < PRE_GRASP_M
        velocity = SLIDE_MPS * rotation[:, 0] if sliding else np.zeros(3)
        if not sliding and self._settled(tool, position, rotation, dt_s):
            self._next(Phase.GRASP)
        else:
            self._timed_out("the grasp pose not reached (blocked short of the handle?)")
        return Command(PoseReference(position, rotation, velocity), self._open(opening_m))

    def _grasp(self, tool: pin.SE3, opening_m: float, dt_s: float) -> Command:
        position, rotation = self.pose_at(self.from_rad)
        self.openings.append((self.phase_s, opening_m))
        earlier = [o for t, o in self.openings if t <= self.phase_s - SETTLE_S]
        if earlier and abs(earlier[-1] - opening_m) < OPENING_STILL_M:
            if opening_m >= self.grip.hold_min_m:
                self.hold_opening_m = opening_m
                self.reference_rad = self.from_rad
                self.progress = (self.phase_s, self.turned_rad)
                self._next(Phase.TURN)
            else:
                self._again(f"the grasp closed on nothing (opening {opening_m * 1e3:.0f} mm)")
        else:
            self._timed_out("the fingers did not stop closing")
        return Command(PoseReference(position, rotation), -SQUEEZE_MPS)

    def _turn(self, tool: pin.SE3, opening_m: float, dt_s: float) -> Command:
        goal = self.goal.turn_rad
        if self.goal.to_stop:  # pushed into its stop (within LEAD_MAX_RAD of where it is)
            goal += math.copysign(OVERTRAVEL_RAD, self.goal.turn_rad)
        if opening_m < self.grip.hold_min_m:  # the handle slipped out of the fingers
            if self.goal.to_stop and self._past_the_stop():
                self._next(Phase.RELEASE)  # wrenched out by the stop it was pushed into: thrown
            else:
                self._again(f"the grasp slipped at {math.degrees(self.turned_rad):.0f} deg")
            return self._release(tool, opening_m, dt_s)
        if abs(goal - self.turned_rad) < TURN_TOLERANCE_RAD:
            self._next(Phase.RELEASE)
            return self._release(tool, opening_m, dt_s)
        direction = math.copysign(1.0, goal - self.turned_rad)
        if direction * (self.turned_rad - self.progress[1]) > PROGRESS_RAD:
            self.progress = (self.phase_s, self.turned_rad)
        elif self.phase_s - self.progress[0] > STALL_S or opening_m > self.hold_opening_m + PRIED_M:
            # the part does not follow the tool: it stopped, or it forces the fingers open
            if self.goal.to_stop and abs(self.goal.turn_rad - self.turned_rad) < AT_STOP_RAD:
                self._next(Phase.RELEASE)  # a lever at its stop
            else:
                turned_deg, goal_deg = math.degrees(self.turned_rad), math.degrees(self.goal.turn_rad)
                self._fail(
                    f"{self.goal.target} does not turn: stopped at {turned_deg:.0f} of {goal_deg:.0f} "
                    "deg (seized?)"
                )
            return self._release(tool, opening_m, dt_s)
        step = direction * TURN_RATE_RADPS * dt_s
        ahead = (self.reference_rad + step - self.turned_rad) * direction
        advancing = ahead <= LEAD_MAX_RAD and (goal - self.reference_rad) * direction > 0
        if advancing:
            self.reference_rad += step
        position, rotation = self.pose_at(self.reference_rad)
        rate = direction * TURN_RATE_RADPS if advancing else 0.0
        velocity = rate * np.cross(self.axis, position - self.pivot)
        return Command(PoseReference(position, rotation, velocity, rate * self.axis, self.axis), -SQUEEZE_MPS)

    def _past_the_stop(self) -> bool:
        """The tool turned at least as far as a lever's stop (within TURN_TOLERANCE_RAD): a lever
        moves freely short of its stop, so the fingers lose it there only to the stop's
        resistance, as the tool overtravels (the BlueROV2's jaw on the small panel's lever: the
        lever at its stop on the truth, the fingers pried off, and two regrasps where the lever
        no longer was)."""
        sign = math.copysign(1.0, self.goal.turn_rad)
        return sign * (self.turned_rad - self.goal.turn_rad) >= -TURN_TOLERANCE_RAD

    def _again(self, why: str) -> None:
        """Try the grasp once more, from where the part now stands, or fail."""
        if self.attempts >= ATTEMPTS:
            self._fail(f"{self.goal.target}: {why}, on the last of {ATTEMPTS} attempts")
            return
        self.attempts += 1
        self.retry = why
        self._next(Phase.RELEASE)

    def _release(self, tool: pin.SE3, opening_m: float, dt_s: float) -> Command:
        position, rotation = self.pose_at(self.turned_rad)
        if self.grip.opened(opening_m) or self.phase_s >= TIMEOUT_S[Phase.RELEASE]:
            self.from_rad = self.turned_rad
            self._next(Phase.RETREAT)
        return Command(PoseReference(position, rotation), self._open(opening_m))

    def _retreat(self, tool: pin.SE3, opening_m: float, dt_s: float) -> Command:
        self.slide_m = min(PRE_GRASP_M, self.slide_m + SLIDE_MPS * dt_s)
        position, rotation = self.pose_at(self.from_rad, self.slide_m)
        sliding = self.slide_m < PRE_GRASP_M
        velocity = -SLIDE_MPS * rotation[:, 0] if sliding else np.zeros(3)
        if not sliding and (
            self._settled(tool, position, rotation, dt_s) or self.phase_s >= TIMEOUT_S[Phase.RETREAT]
        ):
            if self.reason:
                self._next(Phase.FAILED)
            elif self.retry:
                self.retry = ""
                self._next(Phase.APPROACH)
            else:
                self._next(Phase.DONE)
        return Command(PoseReference(position, rotation, velocity), self._open(opening_m))

    # each phase's step, called by `step` while the intervention is active
    _STEPS: ClassVar[dict[Phase, Callable[[InterventionRun, pin.SE3, float, float], Command]]] = {
        Phase.APPROACH: _approach,
        Phase.PRE_GRASP: _pre_grasp,
        Phase.GRASP: _grasp,
        Phase.TURN: _turn,
        Phase.RELEASE: _release,
        Phase.RETREAT: _retreat,
    }
