"""The intervention from shore: the time from an operator's intent (`abyss op valve valve_1
--turn 90`, handed to the onshore station) to the valve at its target on the simulation's truth
(within 5 deg), under the nominal satellite and under the satellite-storm, and each phase's share
of it as onboard reported the phases (on its own state key, past no link).

One `abyss up` (waypoints only), the vehicle on station; then valve_1 turned +TURN_DEG and
-TURN_DEG in turn (short of the stops, which the vessel's belief of the angle, a few degrees off
the truth after a turn, would otherwise refuse), REPEATS times with the nominal satellite and
REPEATS times with the storm (the satellite hop's profile changed as the scenario runner does).
Medians. The floor to compare with: the turn alone at the primitive's rate (TURN_DEG at
TURN_RATE_RADPS) plus the satellite's and the tether's configured one-way delays down.
Run: .venv/bin/python bench/intervention.py [REPEATS] (default 5). Prints figures; asserts nothing."""

from __future__ import annotations

import math
import statistics
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import zenoh

from abyss.bus.session import client_config, message_of, open_session
from abyss.config import Config
from abyss.description.models.panel import intent_of
from abyss.interface import keys
from abyss.interface.messages import (
    CommandAck,
    Intervention,
    LinkControl,
    MissionStatus,
    PanelState,
    Telemetry,
    encode,
    new_id,
)
from abyss.launch.state import wait_for_state
from abyss.stations.onboard.intervention import TURN_RATE_RADPS

SYSTEM = "bench-intervention"
PART = "valve_1"
TOLERANCE_DEG = 5.0
TURN_DEG = 80.0
PHASES = ("approach", "pre-grasp", "grasp", "turn", "release", "retreat")


class Watch:
    """The truth of the panel, shore's mission and onboard's phases, as they come."""

    def __init__(self, session: zenoh.Session) -> None:
        self.lock = threading.Lock()
        self.angle_deg = 0.0
        self.done = False
        self.phases: list[tuple[float, int, str]] = []  # (wall s, intervention id, phase) at each change
        self.refused: dict[int, str] = {}  # command id -> why
        self.subscribers = [
            session.declare_subscriber(keys.operator_key(SYSTEM, "ack"), self._ack),
            session.declare_subscriber(keys.panel_truth_key(SYSTEM), self._panel),
            session.declare_subscriber(keys.mission_key(SYSTEM), self._mission),
            session.declare_subscriber(keys.onboard_state_key(SYSTEM), self._state),
        ]

    def _panel(self, sample: zenoh.Sample) -> None:
        m = message_of(sample, PanelState)
        if m is not None and PART in m.names:
            with self.lock:
                self.angle_deg = math.degrees(m.angles_rad[m.names.index(PART)])

    def _ack(self, sample: zenoh.Sample) -> None:
        m = message_of(sample, CommandAck)
        if m is not None and not m.accepted:
            with self.lock:
                self.refused[m.command_id] = m.reason

    def _mission(self, sample: zenoh.Sample) -> None:
        m = message_of(sample, MissionStatus)
        if m is not None:
            with self.lock:
                self.done = m.done

    def _state(self, sample: zenoh.Sample) -> None:
        m = message_of(sample, Telemetry)
        if m is not None:
            with self.lock:
                last = self.phases[-1][1:] if self.phases else None
                if (m.intervention_id, m.intervention_phase) != last:
                    self.phases.append((time.monotonic(), m.intervention_id, m.intervention_phase))

    def wait(self, holds: Callable[[Watch], bool], timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                if holds(self):
                    return True
            time.sleep(0.02)
        return False


def one_turn(session: zenoh.Session, watch: Watch, turn_deg: float) -> tuple[float, dict[str, float]] | None:
    """Send the intent; the time to the truth at target [s] and the time [s] of each phase
    within it."""
    with watch.lock:
        target_deg = watch.angle_deg + turn_deg
    command = Intervention(new_id(), PART, *intent_of(f"{turn_deg:g}"))
    t0 = time.monotonic()
    session.put(keys.operator_key(SYSTEM, "intervene"), encode(command, 0, t0))  # the shore resends
    at_target = watch.wait(
        lambda w: abs(w.angle_deg - target_deg) <= TOLERANCE_DEG or command.command_id in w.refused, 120.0
    )
    t_target = time.monotonic()
    if command.command_id in watch.refused:
        print(f"refused: {watch.refused[command.command_id]}")
        return None
    ended = watch.wait(
        lambda w: any(i == command.command_id and p in ("done", "failed") for _, i, p in w.phases), 60.0
    )
    if not at_target or not ended:
        return None
    with watch.lock:
        mine = [(t, p) for t, i, p in watch.phases if i == command.command_id]
    spans = {"down (shore to onboard's approach)": (mine[0][0] if mine else t_target) - t0}
    spans.update({p: 0.0 for p in PHASES})
    for (t, p), (t_next, _) in zip(mine, [*mine[1:], (t_target, "")], strict=True):
        if p in spans:
            spans[p] += max(0.0, min(t_next, t_target) - min(t, t_target))
    return t_target - t0, spans


def main(repeats: int) -> None:
    out = Path("runs") / SYSTEM
    up = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "abyss.cli",
            "up",
            "--keep-running",
            "--duration",
            "1200",
            "--port",
            "0",
            "--out",
            str(out),
            "--system",
            SYSTEM,
            "--viewer",
            "none",
            "--record",
            "none",
            "--set",
            "mission.interventions=[]",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.STDOUT,
    )
    try:
        state = wait_for_state(out, lambda s: s.phase == "up", 120.0, lambda: up.poll() is None)
        assert state is not None, "abyss up did not come up"
        session = open_session(client_config(state.endpoint), "bench intervention")
        watch = Watch(session)
        assert watch.wait(lambda w: w.done, 120.0), "the waypoints were not reached"
        profiles = Config().links.profiles()
        floor_s = (
            math.radians(TURN_DEG) / TURN_RATE_RADPS
            + profiles["satellite"].delay_s
            + profiles["tether"].delay_s
        )
        results: dict[str, list[tuple[float, dict[str, float]]]] = {}
        sent = 0
        for profile in ("satellite", "satellite-storm"):
            session.put(keys.link_key(SYSTEM, "satellite"), encode(LinkControl(profile, {}), 0, time.time()))
            results[profile] = []
            for k in range(repeats):
                turn_deg = TURN_DEG if (k + sent) % 2 == 0 else -TURN_DEG  # back and forth throughout
                got = one_turn(session, watch, turn_deg)
                print(
                    f"{profile}: turn {k + 1}/{repeats}: "
                    + (f"{got[0]:.1f} s to the target" if got else "did not reach the target"),
                    flush=True,
                )
                if got:
                    results[profile].append(got)
            sent += repeats
        for profile, runs in results.items():
            if not runs:
                continue
            total = statistics.median(r[0] for r in runs)
            print(
                f"\n{profile}: intent to {PART} at target (truth, +-{TOLERANCE_DEG:g} deg): "
                f"median {total:.1f} s "
                f"over {len(runs)} (min {min(r[0] for r in runs):.1f}, max {max(r[0] for r in runs):.1f}); "
                f"{total / floor_s:.2f}x the floor of {floor_s:.1f} s (the turn at the primitive's rate "
                "and the one-way delays down)"
            )
            for phase in runs[0][1]:
                median_s = statistics.median(r[1][phase] for r in runs)
                print(f"  {phase:<36} median {median_s:5.1f} s  ({median_s / total:5.1%})")
        session.close()
    finally:
        up.terminate()
        up.wait(60)


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 5)
