"""The simulation's fault actions (stations/simulation/faults.py): one per row of the fault table,
dispatched by World.apply_fault; a fault registered from here acts on a real World."""

from __future__ import annotations

import time
from collections.abc import Iterator

import numpy as np
import pytest

from abyss.common.errors import BadInput
from abyss.config.simulation import SimulationConfig
from abyss.interface import faults
from abyss.interface.messages import SimulationControl, decode, encode
from abyss.stations.simulation import faults as actions
from abyss.stations.simulation.faults import apply as apply_fault
from abyss.stations.simulation.world import World

KEY = "abyss/test/simulation/control"


def world() -> World:
    return World(SimulationConfig(), np.random.default_rng(0))


def sent(fault: str, target: str, value: float) -> SimulationControl:
    """The control as the simulation's station takes it: encoded, sent, decoded on its key."""
    data = encode(SimulationControl(fault, target, value), 0, time.time())
    return decode(KEY, data, SimulationControl).message


def test_the_simulation_has_an_action_for_each_fault_and_no_other() -> None:
    assert list(actions.ACTIONS) == list(faults.FAULT_TABLE)


@pytest.fixture
def drift() -> Iterator[list[str]]:
    """A new fault, `drift`: one row of the table, one action; the sensors it cleared, listed."""
    cleared: list[str] = []

    def apply(w: World, target: str, value: float, cameras: set[str]) -> None:
        w.navigation.scale[target] = 1.0 + 10.0 * value

    def clear(w: World, cameras: set[str]) -> None:
        cleared.append("drift")

    faults.register(faults.Fault("drift", "nav_sensors", "drift", 0.0, 1.0, "that sensor drifts"))
    actions.register("drift", actions.Action(apply, clear))
    yield cleared
    del faults.FAULT_TABLE["drift"], actions.ACTIONS["drift"]


def test_a_registered_fault_acts_on_a_world_and_a_bad_target_is_refused(drift: list[str]) -> None:
    w = world()
    apply_fault(w, sent("drift", "dvl", 0.5), set())
    assert w.navigation.scale["dvl"] == 6.0 and w.faults == {"drift/dvl": 0.5}
    with pytest.raises(BadInput, match=r"drift target 'cam_left' not one of usbl, depth, dvl, imu$"):
        apply_fault(w, sent("drift", "cam_left", 0.5), set())
    with pytest.raises(BadInput, match=r"drift value 2 not in \[0, 1\] \(drift\)"):
        apply_fault(w, sent("drift", "dvl", 2.0), set())
    apply_fault(w, sent("clear", "", 0.0), set())
    assert drift == ["drift"] and w.faults == {} and w.navigation.scale["dvl"] == 1.0


def test_each_fault_acts_and_clear_undoes_them_all() -> None:
    w = world()
    blackout: set[str] = set()
    valve = w.parts.index("valve_1")
    joint = w._part_joints[valve]
    free_rad = w.model.jnt_range[joint].copy()
    efficiency = w.controller.thrusters.efficiency  # the array C reads: changed in place, never rebound
    with pytest.raises(BadInput, match=r"thruster value 1.5 not in \[0, 1\]"):
        apply_fault(w, sent("thruster", "thr_fl", 1.5), blackout)
    apply_fault(w, sent("thruster", "thr_fl", 0.3), blackout)
    apply_fault(w, sent("camera", "cam_left", 0.0), blackout)
    apply_fault(w, sent("noise", "usbl", 3.0), blackout)
    apply_fault(w, sent("seize", "valve_1", 1.0), blackout)
    angle_rad = float(w.data.qpos[w._part_qpos[valve]])
    assert w.controller.thrusters.efficiency is efficiency and efficiency[0] == 0.3
    assert blackout == {"cam_left"} and w.navigation.scale["usbl"] == 3.0
    assert w.model.jnt_range[joint] == pytest.approx([angle_rad - 0.005, angle_rad + 0.005])
    assert w.faults == {
        "thruster/thr_fl": 0.3,
        "camera/cam_left": 0.0,
        "noise/usbl": 3.0,
        "seize/valve_1": 1.0,
    }
    apply_fault(w, sent("seize", "valve_1", 0.0), blackout)
    assert np.array_equal(w.model.jnt_range[joint], free_rad)
    apply_fault(w, sent("seize", "valve_1", 1.0), blackout)
    apply_fault(w, sent("clear", "", 0.0), blackout)
    assert w.faults == {} and blackout == set() and np.all(efficiency == 1.0)
    assert set(w.navigation.scale.values()) == {1.0} and np.array_equal(w.model.jnt_range[joint], free_rad)
