"""Conversions of the stations' states to ROS 2 diagnostics, and the simulation's clock."""

from __future__ import annotations

from typing import Any

import numpy as np

from abyss.interface.messages import (
    CommandAck,
    Heartbeat,
    LinkStats,
    MissionStatus,
    PerceptionStatus,
    SimulationStatus,
    Telemetry,
)
from abyss.ros2.msgs import (
    ERROR,
    OK,
    ROS,
    WARN,
    diagnostics_msg,
)
from abyss.ros2.session import Session


def telemetry_diagnostics(t: Telemetry, head: Any, session: Session) -> Any:
    """The controllers' state: WARN while the failsafe holds the vehicle and arm, with why."""
    return diagnostics_msg(
        head,
        "abyss onboard controllers",
        WARN if t.failsafe else OK,
        f"failsafe: {t.failsafe}" if t.failsafe else f"vehicle {t.mode}, arm {t.arm_mode}",
        {
            "mode": t.mode,
            "arm_mode": t.arm_mode,
            "operator_mode": t.operator_mode,
            "failsafe": t.failsafe,
            "failsafe_events": t.failsafe_events,
            "command_id": t.command_id,
            "waypoint": f"{t.waypoint_index}/{t.waypoints_total}",
            "position_error_m": t.position_error_m,
            "heading_error_rad": t.heading_error_rad,
            "arm_command_id": t.arm_command_id,
            "ee_position_error_m": float(np.linalg.norm(t.ee_position_error_m_world)),
            "ee_orientation_error_rad": t.ee_orientation_error_rad,
            "boot_id": t.boot_id,
        },
    )


def mission_diagnostics(m: MissionStatus, head: Any, session: Session) -> Any:
    return diagnostics_msg(
        head,
        "abyss mission",
        WARN if m.failsafe else OK,
        "done" if m.done else f"failsafe: {m.failsafe}" if m.failsafe else m.mode,
        {
            "mode": m.mode,
            "arm_mode": m.arm_mode,
            "waypoint": f"{m.waypoint_index}/{m.waypoints_total}",
            "position_error_m": m.position_error_m,
            "heading_error_rad": m.heading_error_rad,
            "ee_position_error_m": m.ee_position_error_m,
            "ee_orientation_error_rad": m.ee_orientation_error_rad,
            "failsafe": m.failsafe,
            "failsafe_events": m.failsafe_events,
            "done": m.done,
        },
    )


def perception_diagnostics(p: PerceptionStatus, head: Any, session: Session) -> Any:
    level = WARN if p.scene_source != "cameras" else OK
    return diagnostics_msg(
        head,
        "abyss perception",
        level,
        f"scene from {p.scene_source or 'nothing yet'}",
        {
            **{f"{source}_points_per_s": rate for source, rate in p.points_per_s.items()},
            "recognition_confidence": p.recognition_confidence,
            "recognition_method": p.recognition_method,
            "scene_backlog_cells": p.scene_backlog_cells,
        },
    )


def link_diagnostics(stats: LinkStats, head: Any, session: Session) -> Any:
    """What a link direction measured (its stats) under its profile (its fields)."""
    return diagnostics_msg(
        head,
        f"abyss link {stats.hop} {stats.direction}",
        OK,
        f"profile {stats.profile}",
        {"profile": stats.profile, **stats.fields, **stats.stats},
    )


def heartbeat_diagnostics(beat: Heartbeat, head: Any, session: Session) -> Any:
    return diagnostics_msg(
        head,
        "abyss heartbeat",
        OK if beat.shore_heard else WARN,
        "shore heard" if beat.shore_heard else "shore lost",
        {"shore_heard": beat.shore_heard, "shore_silence_s": beat.shore_silence_s},
    )


def ack_diagnostics(ack: CommandAck, head: Any, session: Session) -> Any:
    return diagnostics_msg(
        head,
        f"abyss command {ack.command}",
        OK if ack.accepted else ERROR,
        "taken" if ack.accepted else f"refused: {ack.reason}",
        {"command": ack.command, "command_id": ack.command_id, "reason": ack.reason},
    )


def status_diagnostics(status: SimulationStatus, head: Any, session: Session) -> Any:
    """The simulation's pace and its faults (WARN while any is injected)."""
    return diagnostics_msg(
        head,
        "abyss simulation",
        WARN if status.faults else OK,
        ", ".join(f"{k} {v:g}" for k, v in status.faults.items()) or "no faults",
        {
            "sim_time_s": status.sim_time_s,
            "realtime_factor": status.realtime_factor,
            "deadlines_met": status.deadlines_met,
            **{f"fault {k}": v for k, v in status.faults.items()},
        },
    )


def clock(status: SimulationStatus | None, head: Any, session: Session) -> Any:
    return ROS["rosgraph_msgs/msg/Clock"](clock=head.stamp)
