"""The operator's intents resolved on the vessel: a part of the panel, named, becomes a goal in
the world frame from the panel the vessel recognised (its estimate, not the simulation's truth)
and the part's angle as the vessel believes it (where the last intervention on it left it)."""

from __future__ import annotations

import math

import numpy as np

from abyss.common.errors import BadInput
from abyss.common.geometry import quat_wxyz_of, rotation_about, rotation_of
from abyss.description.models.panel import GRASP_ROTATION_PANEL, Panel
from abyss.interface.messages import Intervention, InterventionGoal, RecognisedObjects

ALREADY_RAD = math.radians(1.0)
# a turn that would end this little past a stop ends at the stop: the part's angle is believed to a
# degree or two (vision measures it, or onboard's turn), and "turn by 90" of a valve seen at 0.4 deg
# means to its stop (refused as past it, a restarted vessel's resend stopped a mission)
STOP_SLACK_RAD = math.radians(5.0)
# a new estimate of the panel that moves a grasp this far is sent down again: under a third of
# what the grasp tolerates along the approach (the fingers reach 12.5 mm over the bar) and across
# (they open 7 cm on a 4 cm handle), above the estimate's jitter at working distance (1-2 mm)
REFINE_M = 0.003
FLIP_ABOUT_X = np.diag([1.0, -1.0, -1.0])  # the tool rolled half a turn about its approach


def part_angle_rad(panel: Panel, part: str, turned_rad: float) -> float:
    """A part's angle from the tool's: the tool turns past a stop (a lever is pushed on into it,
    the shaft twisting in the grip), the part does not."""
    low, high = panel.part_range_rad(part)
    return float(np.clip(turned_rad, low, high))


def resolve(
    panel: Panel,
    intent: Intervention,
    objects: RecognisedObjects | None,
    believed_rad: float = 0.0,
    again: bool = False,
) -> tuple[InterventionGoal | None, str]:
    """The goal, or None and why it is refused; None and "" while the panel is not recognised
    yet (the intent waits). `again`: the intervention handed again (onboard rebooted during it),
    which goes down even where the part is at its target already: the rebooted onboard grasps
    it, turns it no further, lets go and backs off, and reports it done."""
    try:
        kind = panel.part_kind(intent.target)
    except BadInput as exc:
        return None, str(exc)
    if kind == "valve" and intent.to:
        return None, f"{intent.target} is a valve: it is turned by an angle, not thrown to a stop"
    if kind == "lever" and not intent.to:
        return None, f"{intent.target} is a lever: it is thrown to its stop, up or down"
    low, high = panel.part_range_rad(intent.target)
    target_rad = believed_rad + intent.turn_rad if kind == "valve" else (high if intent.to == "up" else low)
    if low - STOP_SLACK_RAD <= target_rad <= high + STOP_SLACK_RAD:
        target_rad = float(np.clip(target_rad, low, high))
    else:
        low_deg, high_deg, at_deg = math.degrees(low), math.degrees(high), math.degrees(believed_rad)
        return None, (
            f"{intent.target} turns between {low_deg:.0f} and {high_deg:.0f} deg; at {at_deg:.0f} "
            f"deg it can turn by {low_deg - at_deg:.0f} to {high_deg - at_deg:.0f} deg"
        )
    if abs(target_rad - believed_rad) < ALREADY_RAD and not again:
        return None, f"{intent.target} is at {math.degrees(believed_rad):.0f} deg already"
    turn_rad = target_rad - believed_rad
    if kind == "lever" and abs(turn_rad) < ALREADY_RAD:  # at its stop already (handed again):
        turn_rad = math.copysign(0.0, target_rad)  # the push goes on into the stop, never away
    if objects is None or "panel" not in objects.names:
        return None, ""
    pose = objects.poses_world[objects.names.index("panel")]
    panel_rotation, panel_m_world = rotation_of(pose[3:]), pose[:3]
    pivot, axis, grasp = panel.part_geometry(intent.target)
    turned = rotation_about(axis, believed_rad)
    grasp_rotation = GRASP_ROTATION_PANEL
    if kind == "valve" and target_rad > 0:  # the fingers are symmetric: the grasp that ends the
        grasp_rotation = grasp_rotation @ FLIP_ABOUT_X  # turn with the tool rolled least
    return InterventionGoal(
        command_id=intent.command_id,
        target=intent.target,
        pivot_m_world=panel_rotation @ pivot + panel_m_world,
        axis_world=panel_rotation @ axis,
        grasp_m_world=panel_rotation @ (pivot + turned @ grasp) + panel_m_world,
        grasp_orientation_wxyz_world=quat_wxyz_of(panel_rotation @ turned @ grasp_rotation),
        turn_rad=turn_rad,
        to_stop=kind == "lever",
    ), ""
