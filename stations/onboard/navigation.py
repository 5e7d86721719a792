"""The navigation estimate from a vehicle's sensors (`simulation/nav`): onboard steers by it, and a
hybrid run's twin (stations/simulation/twin.py) renders from it, so that both place what the
cameras see alike. Horizontally, the DVL's velocity is integrated in the world
frame (dead reckoning) and each USBL fix corrects it as a Kalman filter weighs the two: the
fix's noise against what the integration has gathered since. A fix arrives a fraction of a
second after it was taken: it is compared with the estimate of that moment, kept in a short
history, and the correction is applied now (`delay_compensation`; without it the fix is read
as if taken now, and a moving vehicle's estimate trails by its speed times the delay). A fix
too far off for the uncertainty (the innovation gate) is rejected and counted; an estimate not
yet settled (one fix, which may have been the outlier) starts afresh from it instead. Without bottom
lock the DVL's last velocity fades out and the uncertainty grows (coasting). The output takes
each correction up over a couple of seconds (BLEND_S) rather than in one step. Depth is the
pressure sensor's, and attitude the IMU's, each smoothed by integrating the DVL's heave and the
gyro's rates with one time constant. A pure core: messages (with their simulated time) in,
the estimate out."""

from __future__ import annotations

import itertools
import logging
import math
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from abyss.common.geometry import quat_multiply, rotation_of, small_rotation_wxyz
from abyss.config.stations import OnboardConfig
from abyss.interface.messages import NavState

MAX_GAP_S = 1.0  # a longer gap between messages (a simulation restarted) starts the estimate afresh
HISTORY_S = 5.0  # [s] of estimates kept, for fixes that come late
COAST_FADE_S = 2.0  # [s] without bottom lock, the last velocity fades with this time constant
COAST_SIGMA_MPS = 0.1  # [m/s per sqrt(s)] the position's uncertainty grows so while coasting
BIAS_WALK_MPS = 1e-5  # [m/s per sqrt(s)] how fast the DVL's bias (in the world frame) may wander
BIAS_SIGMA_MPS = 0.005  # [m/s] the DVL's bias, as first assumed
# fixes rejected in a row: the estimate, not the fixes, is wrong; start afresh. An estimate not yet
# settled starts afresh at its first rejection: its start is one fix, and that fix may have been the
# outlier (a restarted onboard started 3 m off on one, then rejected five good fixes in a row while
# an intervention ran on the shifted frame)
RESET_AFTER_REJECTED = 5
# fixes that agree in a row (the first one included) before an estimate started afresh is trusted
# to place what onboard sees and to steer the arm by: one fix alone may be an outlier (a rebooted
# onboard started 0.34 m off on one, and its clouds laid a ghost of the panel's face that held the
# vessel's estimate 20 cm short for 20 s)
SETTLE_FIXES = 3
# [m/s] the arm steers by the estimate only once its velocity bias is known this well: one learned
# from a few fixes carries the estimate off at millimetres a second (a rebooted onboard's swung
# 4 cm in 5 s, 2.5 s into a lever's pre-grasp, and the fingers met the handle); a fresh estimate
# gets there about 17 s after its first fix
ARM_BIAS_SIGMA_MPS = 0.001
# [s] each fix's correction reaches the output over this time constant, not in one step: an arm
# holding a valve's handle through the output would be jerked by millimetres at every fix
BLEND_S = 2.0
log = logging.getLogger(__name__)


class NavFilter:
    """Horizontally a Kalman filter on position and the DVL's velocity bias (x and y alike, so
    one 2 x 2 covariance serves both); depth and attitude complementary filters."""

    def __init__(self, cfg: OnboardConfig) -> None:
        self.time_constant_s = cfg.nav_time_constant_s
        self.fix_variance_m2 = cfg.nav_usbl_sigma_m**2
        self.dvl_sigma_mps = cfg.nav_dvl_sigma_mps
        self.gate_sigmas = cfg.nav_gate_sigmas
        self.delay_compensation = cfg.nav_delay_compensation
        self.accepted = 0
        self.rejected = 0
        self.restart()

    def restart(self) -> None:
        """Forget the estimate; the next fix starts it."""
        self.position_m_world: np.ndarray | None = None
        self.orientation_wxyz_world = np.array([1.0, 0.0, 0.0, 0.0])
        self.bias_mps_world = np.zeros(2)  # what the DVL reads over the truth, x and y
        self.covariance = np.diag([math.inf, BIAS_SIGMA_MPS**2])  # position [m^2], bias [(m/s)^2]
        self.velocity_mps_world = np.zeros(3)  # the latest used: the DVL's, or fading while coasting
        self.history: deque[tuple[float, np.ndarray]] = deque()  # (sim time [s], x and y [m, world])
        self.pending_m = np.zeros(2)  # of the corrections, what the output has not taken up yet
        self._rejected_in_a_row = 0
        self._agreed = 0  # fixes in a row that agreed with the estimate since it started
        self.settled = False  # SETTLE_FIXES agreed since it started (until it starts afresh)
        self._fix_s = -1.0  # when the latest fix used was taken
        self._stamp_s: float | None = None

    @property
    def steady(self) -> bool:
        """Settled, and its drift known well enough for the arm's millimetres (ARM_BIAS_SIGMA_MPS)."""
        return self.settled and float(self.covariance[1, 1]) <= ARM_BIAS_SIGMA_MPS**2

    def update(self, nav: NavState) -> tuple[np.ndarray | None, np.ndarray]:
        """The estimate after one message: position [m, world] (None before the first fix),
        orientation (w, x, y, z)."""
        dt = 0.0 if self._stamp_s is None else nav.sim_time_s - self._stamp_s
        if not 0.0 <= dt <= MAX_GAP_S:  # the vehicle's navigation (or the simulation) restarted
            log.warning(
                "navigation %s: the estimate starts afresh (docs/hybrid.md, the message's time)",
                f"went back {-dt:.2f} s" if dt < 0 else f"was silent {dt:.2f} s",
            )
            self.restart()
            dt = 0.0
        if self._stamp_s is None:
            self.orientation_wxyz_world = np.array(nav.orientation_wxyz_world)
        self._stamp_s = nav.sim_time_s
        self._attitude(nav, dt)
        if self.position_m_world is not None:
            self._dead_reckon(nav, dt)
        if nav.usbl_time_s > self._fix_s:
            self._fix_s = nav.usbl_time_s
            self._fix(nav)
        if self.position_m_world is None:
            return None, self.orientation_wxyz_world
        self.pending_m *= math.exp(-dt / BLEND_S)
        return np.r_[
            self.position_m_world[:2] - self.pending_m, self.position_m_world[2]
        ], self.orientation_wxyz_world

    def _gain(self, dt: float) -> float:
        return 1.0 if self.time_constant_s == 0 else dt / (self.time_constant_s + dt)

    def _attitude(self, nav: NavState, dt: float) -> None:
        rotated = small_rotation_wxyz(nav.angular_velocity_radps_body * dt)  # body rates: right product
        turned = quat_multiply(self.orientation_wxyz_world, rotated)
        self.orientation_wxyz_world = nlerp(turned, nav.orientation_wxyz_world, self._gain(dt))

    def _dead_reckon(self, nav: NavState, dt: float) -> None:
        assert self.position_m_world is not None
        if nav.dvl_valid:
            self.velocity_mps_world = rotation_of(self.orientation_wxyz_world) @ nav.velocity_mps_body
            self.velocity_mps_world[:2] -= self.bias_mps_world
            noise_m2 = (self.dvl_sigma_mps * dt) ** 2
        else:
            self.velocity_mps_world = self.velocity_mps_world * math.exp(-dt / COAST_FADE_S)
            noise_m2 = COAST_SIGMA_MPS**2 * dt
        predicted = self.position_m_world + self.velocity_mps_world * dt
        predicted[2] += self._gain(dt) * (-nav.depth_m - predicted[2])
        self.position_m_world = predicted
        moved = np.array([[1.0, -dt], [0.0, 1.0]]) if nav.dvl_valid else np.eye(2)
        self.covariance = moved @ self.covariance @ moved.T + np.diag([noise_m2, BIAS_WALK_MPS**2 * dt])
        self.history.append((nav.sim_time_s, predicted[:2].copy()))
        while self.history and self.history[0][0] < nav.sim_time_s - HISTORY_S:
            self.history.popleft()

    def _fix(self, nav: NavState) -> None:
        fix = np.asarray(nav.position_m_world[:2])
        if self.position_m_world is None:
            self._start(nav)
            return
        then = self._estimate_at(nav.usbl_time_s) if self.delay_compensation else None
        innovation = fix - (self.position_m_world[:2] if then is None else then)
        spread_m2 = float(self.covariance[0, 0]) + self.fix_variance_m2
        if float(innovation @ innovation) > self.gate_sigmas**2 * spread_m2:
            self.rejected += 1
            self._rejected_in_a_row += 1
            log.info(
                "USBL fix taken at %.2f s rejected: %.2f m off the estimate (gate %.2f m); %d so far",
                nav.usbl_time_s,
                float(np.linalg.norm(innovation)),
                self.gate_sigmas * math.sqrt(spread_m2),
                self.rejected,
            )
            self._agreed = 0
            if not self.settled:  # a start that no second fix confirmed may be the outlier
                log.info("the unsettled estimate starts afresh from the fix taken at %.2f s", nav.usbl_time_s)
                self._start(nav)
            elif self._rejected_in_a_row >= RESET_AFTER_REJECTED:
                log.warning(
                    "%d USBL fixes rejected in a row: the estimate starts afresh from the fix",
                    self._rejected_in_a_row,
                )
                self._start(nav)
            return
        self._rejected_in_a_row = 0
        self._agree()
        self.accepted += 1
        gain = self.covariance[:, 0] / spread_m2  # position's, bias's
        correction = gain[0] * innovation
        self.pending_m += correction
        self.position_m_world = np.r_[self.position_m_world[:2] + correction, self.position_m_world[2]]
        self.bias_mps_world += gain[1] * innovation
        self.covariance = self.covariance - np.outer(gain, self.covariance[0])
        for t_s, xy in self.history:  # the estimates since the fix was taken, as corrected
            if t_s >= nav.usbl_time_s:
                xy += correction

    def _estimate_at(self, t_s: float) -> np.ndarray | None:
        """The horizontal estimate at `t_s` [s], interpolated in the history; None beyond it."""
        if not self.history or t_s < self.history[0][0]:
            return None
        before = self.history[0]
        for after in self.history:
            if after[0] >= t_s:
                span_s = after[0] - before[0]
                fraction = 0.0 if span_s <= 0 else (t_s - before[0]) / span_s
                return before[1] + fraction * (after[1] - before[1])
            before = after
        return None

    def _start(self, nav: NavState) -> None:
        self.position_m_world = np.r_[nav.position_m_world[:2], -nav.depth_m]
        self.pending_m = np.zeros(2)
        self.covariance = np.diag([self.fix_variance_m2, BIAS_SIGMA_MPS**2])
        self.bias_mps_world = np.zeros(2)
        self.history.clear()
        self._rejected_in_a_row = 0
        self._agreed, self.settled = 0, False
        self._agree()

    def _agree(self) -> None:
        self._agreed += 1
        self.settled = self.settled or self._agreed >= SETTLE_FIXES


def nlerp(a_wxyz: np.ndarray, b_wxyz: np.ndarray, fraction: float) -> np.ndarray:
    """The unit quaternion `fraction` of the way from a to b (the short way); for small steps."""
    if float(a_wxyz @ b_wxyz) < 0.0:
        b_wxyz = -b_wxyz
    q = (1.0 - fraction) * a_wxyz + fraction * b_wxyz
    return q / np.linalg.norm(q)


Pose = tuple[float, np.ndarray, np.ndarray]  # sim time [s], position [m, world], orientation (w, x, y, z)


def _read_only(array: np.ndarray) -> np.ndarray:
    array = np.array(array, dtype=float)
    array.flags.writeable = False
    return array


@dataclass(frozen=True)
class PoseHistory:
    """The navigation estimate over the last `span_s` [s], looked up at a frame's time. Never
    changed once made (`added` returns a new one), so the control loop can hand it whole to the
    threads that place frames (common.shared.Latest)."""

    poses: tuple[Pose, ...] = ()
    span_s: float = 5.0

    def added(self, poses: Iterable[Pose]) -> PoseHistory:
        """This history with `poses` (oldest first) added, those older than `span_s` before each
        let go."""
        kept = deque(self.poses)
        for sim_time_s, position_m_world, orientation_wxyz_world in poses:
            kept.append((sim_time_s, _read_only(position_m_world), _read_only(orientation_wxyz_world)))
            while kept and kept[0][0] < sim_time_s - self.span_s:
                kept.popleft()
        return PoseHistory(tuple(kept), self.span_s)

    def at(self, sim_time_s: float, tolerance_s: float = 0.2) -> tuple[np.ndarray, np.ndarray] | None:
        """Position [m, world] and orientation (w, x, y, z) interpolated at `sim_time_s` [s]; None
        if no estimate lies within `tolerance_s` [s] of it."""
        for (t0, p0, q0), (t1, p1, q1) in itertools.pairwise(self.poses):
            if t0 <= sim_time_s <= t1:
                f = (sim_time_s - t0) / (t1 - t0) if t1 > t0 else 0.0
                return p0 + f * (p1 - p0), nlerp(q0, q1, f)
        if self.poses:
            t, p, q = min(self.poses, key=lambda pose: abs(pose[0] - sim_time_s))
            if abs(t - sim_time_s) <= tolerance_s:
                return p, q
        return None
