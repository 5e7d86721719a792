"""The onboard failsafe: the vehicle holds station and the arm holds still while the vessel
is silent (its heartbeat stops: tether down, vessel dead) or, optionally, while the vessel
reports shore silent (satellite down); both resume when the link returns. It judges by the
heartbeats alone, as a real vehicle must: it cannot ask the link whether it is down. With
`nav_timeout_s` (a hybrid run's real vehicle: hybrid.nav_max_age_s), navigation that stops stops
the vehicle and the arm outright (`blind`): holding station on an estimate that no longer moves
would push the vehicle on at whatever error it last had; and joints that stop (none new, or only
ones of the wrong count, which onboard drops) stop the arm (`armless`), the vehicle flying on: an
arm commanded from its last joints while the real one moves drives on at a growing error. Each
state is logged once, as it begins and as it ends with how long it lasted."""

from __future__ import annotations

import logging

from abyss.interface.messages import Heartbeat

log = logging.getLogger(__name__)


class Failsafe:
    def __init__(self, goal_timeout_s: float, hold_on_shore_loss: bool, nav_timeout_s: float = 0.0) -> None:
        self.goal_timeout_s = goal_timeout_s
        self.hold_on_shore_loss = hold_on_shore_loss
        self.nav_timeout_s = nav_timeout_s  # 0: off (the simulation's navigation stops only with it)
        self.heard_s: float | None = None  # never heard: nothing to hold yet
        self.navigated_s: float | None = None
        self.jointed_s: float | None = None  # when the arm's joints last moved on in time
        self.blind = False  # navigation stopped: stop, rather than hold station
        self.armless = False  # the joints stopped: the arm stopped
        self.arm_reason = ""
        self._since_s: dict[str, float] = {}  # each state's reason (its kind) -> when it began
        self.shore_heard = True
        self.reason = ""
        self.events = 0

    def heard(self, now_s: float, heartbeat: Heartbeat) -> None:
        self.heard_s = now_s
        self.shore_heard = heartbeat.shore_heard

    def navigated(self, now_s: float) -> None:
        self.navigated_s = now_s

    def jointed(self, now_s: float) -> None:
        """Joints of the arm's count, newer than the last, came in at `now_s`."""
        self.jointed_s = now_s

    def arm_check(self, now_s: float) -> str:
        """Why the arm must stop now ('' when it need not): with `nav_timeout_s`, joints that
        stopped coming for longer (never heard: nothing to stop yet); counts each entry."""
        silent_s = now_s - self.jointed_s if self.jointed_s is not None else 0.0
        self.armless = self.nav_timeout_s > 0 and silent_s > self.nav_timeout_s
        reason = f"no valid joints for {silent_s:.1f} s: the arm stopped" if self.armless else ""
        if reason and not self.arm_reason:
            self.events += 1
        self._logged("arm", now_s, reason)
        self.arm_reason = reason
        return reason

    def _logged(self, kind: str, now_s: float, reason: str) -> None:
        """Log a state as it begins and as it ends, once each."""
        began_s = self._since_s.get(kind)
        if reason and began_s is None:
            self._since_s[kind] = now_s
            log.warning("failsafe: %s", reason)
        elif not reason and began_s is not None:
            del self._since_s[kind]
            log.info("failsafe over (%s) after %.1f s", kind, now_s - began_s)

    def check(self, now_s: float) -> str:
        """Why the vehicle must hold now ('' when it need not); counts each entry."""
        reason = ""
        silent_s = now_s - self.navigated_s if self.navigated_s is not None else 0.0
        self.blind = self.nav_timeout_s > 0 and silent_s > self.nav_timeout_s
        if self.blind:
            reason = f"no navigation for {silent_s:.1f} s: the vehicle and the arm stopped"
        elif self.heard_s is not None and now_s - self.heard_s > self.goal_timeout_s:
            reason = f"no heartbeat from the vessel for {now_s - self.heard_s:.1f} s"
        elif self.hold_on_shore_loss and not self.shore_heard:
            reason = "the vessel reports shore silent (satellite link lost)"
        if reason and not self.reason:
            self.events += 1
        self._logged("vehicle", now_s, reason)
        self.reason = reason
        return reason
