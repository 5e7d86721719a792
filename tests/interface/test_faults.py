"""The fault table (interface/faults.py) and everything generated from it: the message's choices and
docstring, the key table's note, the docs' section; the targets looked up from the model's names."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from abyss.common.errors import BadInput
from abyss.description.robot import robot_at
from abyss.description.site import site_at
from abyss.interface import faults, keys
from abyss.interface.messages import FAULTS, SimulationControl

panel = site_at("").panel  # the shipped site's

ROBOT = robot_at("")  # the shipped robot package


ROOT = Path(__file__).resolve().parents[2]
OTHER_ROBOT = faults.ModelNames(("t0", "t1"), ("eye",), ("gps",), ("tap",))  # no name of abyss's own


def test_docs_faults_table_is_the_generated_one() -> None:
    page = (ROOT / "docs" / "commands.md").read_text()
    assert faults.faults_table() in page


def test_the_message_the_keys_and_faults_are_the_table() -> None:
    names = tuple(faults.FAULT_TABLE)
    assert names == ("thruster", "camera", "noise", "seize", "clear")
    assert FAULTS == faults.fault_names() == names
    (meta,) = [f.metadata for f in dataclasses.fields(SimulationControl) if f.name == "fault"]
    assert tuple(meta["choices"]) == names
    for name in names:
        assert SimulationControl(name, "", 0.0).fault == name
    with pytest.raises(BadInput, match="'spin' not one of"):
        SimulationControl("spin", "", 0.0)
    doc = SimulationControl.__doc__ or ""
    assert [line.strip() for line in doc.splitlines()[-len(names) :]] == faults.doc_lines().splitlines()
    (note,) = [n for k, _, _, n in keys.CONTROL_KEYS if k == "abyss/<system>/simulation/control"]
    assert note == faults.key_note() == f"faults: {', '.join(names)}"


def test_targets_are_the_models_names_by_kind() -> None:
    assert faults.targets("thruster", faults.model_names(ROBOT.spec, panel)) == ROBOT.thrusters
    assert faults.targets("camera", faults.model_names(ROBOT.spec, panel)) == ROBOT.cameras
    assert faults.targets("seize", OTHER_ROBOT) == ("tap",)
    assert faults.targets("noise", OTHER_ROBOT) == ("gps",)
    assert faults.targets("clear", OTHER_ROBOT) == ()


def test_check_refuses_a_target_or_value_outside_the_row() -> None:
    assert faults.check("thruster", "t1", 0.5, OTHER_ROBOT).name == "thruster"
    with pytest.raises(BadInput, match=r"thruster target 'thr_fl' not one of t0, t1$"):
        faults.check("thruster", "thr_fl", 0.5, OTHER_ROBOT)
    with pytest.raises(BadInput, match=r"thruster value 1.5 not in \[0, 1\] \(efficiency\)"):
        faults.check("thruster", "t0", 1.5, OTHER_ROBOT)
    with pytest.raises(BadInput, match="'spin' not one of thruster, camera"):
        faults.check("spin", "t0", 0.0, OTHER_ROBOT)
    assert faults.check("clear", "anything", 7.0, OTHER_ROBOT).name == "clear"  # takes no target


def test_a_row_is_checked_and_a_name_registered_once() -> None:
    with pytest.raises(BadInput, match="targets 'motors' not one of thrusters, cameras"):
        faults.Fault("spin", "motors", "rate", 0.0, 1.0, "spins")
    with pytest.raises(BadInput, match="value range"):
        faults.Fault("spin", "thrusters", "rate", 0.0, 1e3, "spins")
    with pytest.raises(BadInput, match="already in the table"):
        faults.register(faults.Fault("camera", "cameras", "0: off", 0.0, 1.0, "again"))
