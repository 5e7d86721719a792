"""Onboard's modes as types: what each controller is doing, and the operator's control mode. On
the wire (messages.Telemetry, messages.OperatorMode) they stay strings, their values; they are
converted at that boundary (core.Onboard)."""

from __future__ import annotations

from enum import StrEnum


class Mode(StrEnum):
    """What the vehicle's or the arm's controller is doing (messages.MODES)."""

    IDLE = "idle"  # nothing to do
    MOVING = "moving"
    REACHED = "reached"
    HOLD = "hold"  # holds still (the failsafe, the operator, or the arm waits for the vehicle)
    MISSED = "missed"  # a waypoint not reached in its time; it is held
    BLOCKED = "blocked"  # the arm's joints do not follow what it commands (a stall): it holds


class ControlMode(StrEnum):
    """The operator's control mode (messages.OPERATOR_MODES): hold, the vehicle holds station and
    the arm holds still; auto, the goals are flown, the arm once the vehicle holds its last
    waypoint; teleop, the goals are flown, the arm at once."""

    HOLD = "hold"
    AUTO = "auto"
    TELEOP = "teleop"
