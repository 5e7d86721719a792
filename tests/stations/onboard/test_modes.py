"""Onboard's modes and phases as types: the same values as on the wire, every active phase with
its step, and plain strings in what goes out."""

from __future__ import annotations

import numpy as np

from abyss.config import Config
from abyss.interface.messages import (
    INTERVENTION_PHASES,
    MODES,
    OPERATOR_MODES,
    JointState,
    NavState,
    OperatorMode,
    Telemetry,
    decode,
    encode,
)
from abyss.stations.onboard.core import Onboard, OnboardInputs
from abyss.stations.onboard.intervention import InterventionRun, Phase
from abyss.stations.onboard.modes import ControlMode, Mode


def test_the_types_hold_the_values_the_wire_allows() -> None:
    assert tuple(Mode) == MODES
    assert tuple(ControlMode) == OPERATOR_MODES
    assert ("", *Phase) == INTERVENTION_PHASES


def test_every_phase_but_the_ends_has_its_step() -> None:
    assert set(InterventionRun._STEPS) == set(Phase) - {Phase.DONE, Phase.FAILED}


def test_the_operator_mode_comes_in_as_a_string_and_goes_out_as_one() -> None:
    core = Onboard(Config())
    nav = NavState(
        np.array([0.0, 0.0, -5.0]), np.array([1.0, 0, 0, 0]), np.zeros(3), np.zeros(3), 0.0, 0.0, 5.0
    )
    joints = JointState(np.zeros(6), np.zeros(6), 0.0, 0.0)
    out = core.step(OnboardInputs(commands=[OperatorMode(1, "teleop")], nav=[nav], joints=joints), 0.0)
    assert core.operator_mode is ControlMode.TELEOP and out.acks[0].accepted
    assert out.telemetry is not None
    for value in (out.telemetry.operator_mode, out.telemetry.mode, out.telemetry.arm_mode):
        assert type(value) is str  # the wire's type, not the enum
    assert (out.telemetry.operator_mode, out.telemetry.mode, out.telemetry.arm_mode) == (
        "teleop",
        "idle",
        "idle",
    )
    assert decode("k", encode(out.telemetry, 0, 0.0), Telemetry).message.operator_mode == "teleop"
