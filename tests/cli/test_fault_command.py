"""`abyss fault`: its choices, targets and help generated from the fault table, checked as the
simulation checks a fault (against the running system's parts: tests/bus/test_description.py
runs it against one). No Zenoh."""

from __future__ import annotations

import pytest

from abyss.cli import parser
from abyss.cli.operator import fault_control, fault_help
from abyss.common.errors import ConfigError
from abyss.description.robot import robot_at
from abyss.description.site import site_at
from abyss.interface import faults

panel = site_at("").panel  # the shipped site's

ROBOT = robot_at("")  # the shipped robot package
NAMES = faults.model_names(ROBOT.spec, panel)  # a system running the shipped pair


def test_the_choices_and_the_help_are_the_table(capsys: pytest.CaptureFixture[str]) -> None:
    args = parser().parse_args(["fault", "seize", "valve_1", "1"])
    assert (args.fault, args.target, args.value) == ("seize", "valve_1", 1.0)
    for name in faults.fault_names():
        assert parser().parse_args(["fault", name]).fault == name
    with pytest.raises(SystemExit):
        parser().parse_args(["fault", "spin"])
    assert "invalid choice: 'spin'" in capsys.readouterr().err
    text = fault_help()
    names = faults.model_names(ROBOT.spec, panel)
    for row in faults.FAULT_TABLE.values():
        assert row.line() in text and row.value_range() in text
        assert all(target in text for target in faults.targets(row.name, names))


def test_a_fault_is_checked_against_the_table_and_the_model() -> None:
    for part in (*panel.valves, *panel.levers):
        assert fault_control("seize", part, 1.0, NAMES).target == part
    assert fault_control("clear", "", 0.0, NAMES).fault == "clear"
    with pytest.raises(ConfigError, match="seize target 'thr_fl' not one of valve_0, valve_1"):
        fault_control("seize", "thr_fl", 1.0, NAMES)
    with pytest.raises(ConfigError, match=r"camera value 2 not in \[0, 1\]"):
        fault_control("camera", "cam_left", 2.0, NAMES)
    with pytest.raises(ConfigError, match="clear takes no target"):
        fault_control("clear", "thr_fl", 0.0, NAMES)
