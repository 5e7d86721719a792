"""The simulation's side of the fault table (interface/faults.py): what each fault does to the World,
and how it is undone. `apply` checks a fault against the table and the world's model,
then dispatches through `ACTIONS`; a new fault is one row there and one entry here (`register`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from abyss.common.errors import BadInput
from abyss.interface.faults import check
from abyss.stations.simulation.lowlevel import Dynamic

if TYPE_CHECKING:
    from abyss.interface.messages import SimulationControl
    from abyss.stations.simulation.world import World

SEIZED_PLAY_RAD = 0.005  # a seized valve or lever moves no further than this either way

Apply = Callable[["World", str, float, set[str]], None]  # (world, target, value, blacked-out cameras)
Clear = Callable[["World", set[str]], None]  # (world, blacked-out cameras): back to nominal


@dataclass(frozen=True)
class Action:
    """A fault's effect on the World, and its undoing (what `clear` does for it)."""

    apply: Apply
    clear: Clear


def _thruster(world: World, target: str, efficiency: float, cameras: set[str]) -> None:
    if isinstance(world.controller, Dynamic):  # in place: the physics in C reads the array
        world.controller.thrusters.efficiency[world.vehicle.thrusters.names.index(target)] = efficiency


def _thrusters_healthy(world: World, cameras: set[str]) -> None:
    if isinstance(world.controller, Dynamic):
        world.controller.thrusters.efficiency[:] = 1.0


def _camera(world: World, target: str, on: float, cameras: set[str]) -> None:
    (cameras.add if on == 0.0 else cameras.discard)(target)


def _cameras_on(world: World, cameras: set[str]) -> None:
    cameras.clear()


def _noise(world: World, target: str, scale: float, cameras: set[str]) -> None:
    world.navigation.scale[target] = scale


def _noise_nominal(world: World, cameras: set[str]) -> None:
    world.navigation.scale = dict.fromkeys(world.navigation.scale, 1.0)


def _seize(world: World, target: str, seized: float, cameras: set[str]) -> None:
    """Stuck where it stands: its stops close in on its angle; freed, its own stops again."""
    i = world.parts.index(target)
    angle_rad = float(world.data.qpos[world._part_qpos[i]])
    stops_rad = (angle_rad - SEIZED_PLAY_RAD, angle_rad + SEIZED_PLAY_RAD)
    world.model.jnt_range[world._part_joints[i]] = stops_rad if seized else world._part_range_rad[i]


def _parts_free(world: World, cameras: set[str]) -> None:
    world.model.jnt_range[world._part_joints] = world._part_range_rad


def _clear(world: World, target: str, value: float, cameras: set[str]) -> None:
    """Every fault undone, the faults reported emptied."""
    for action in ACTIONS.values():
        action.clear(world, cameras)
    world.faults.clear()


def _nothing(world: World, cameras: set[str]) -> None:
    pass


ACTIONS: dict[str, Action] = {
    "thruster": Action(_thruster, _thrusters_healthy),
    "camera": Action(_camera, _cameras_on),
    "noise": Action(_noise, _noise_nominal),
    "seize": Action(_seize, _parts_free),
    "clear": Action(_clear, _nothing),
}


def register(name: str, action: Action) -> Action:
    """Add the simulation's side of fault `name` (its row registered in interface.faults)."""
    if name in ACTIONS:
        raise BadInput(f"fault {name!r} already has an action")
    ACTIONS[name] = action
    return action


def apply(world: World, fault: SimulationControl, cameras: set[str]) -> None:
    """Apply a row of the fault table to `world` through the simulation's action for it;
    `cameras`: the blacked-out ones. Raises BadInput with the allowed targets for an unknown
    one, or with the range for a value outside its fault's."""
    check(fault.fault, fault.target, fault.value, world.model_names())
    if fault.fault not in ACTIONS:
        raise BadInput(f"fault {fault.fault!r} has no action in the simulation")
    world.faults[f"{fault.fault}/{fault.target}"] = fault.value  # clear's action empties it
    ACTIONS[fault.fault].apply(world, fault.target, fault.value, cameras)
