"""The operator's Rerun layout (`blueprint`): which views show which of the viewer's entities
(`viewer.Viewer` logs them), one unit per plot."""

from __future__ import annotations

import rerun.blueprint as rrb

from abyss.interface import keys

# the controllers' errors, one plot per quantity and unit: the group under `errors/` -> the view's name
ERROR_VIEWS = {
    "vehicle_position_m": "Vehicle position error [m]",
    "heading_deg": "Heading error [deg]",
    "tool_position_mm": "Tool position error [mm]",
    "tool_orientation_deg": "Tool orientation error [deg]",
}
# a hop's plots, one per unit: the group under `links/<hop>/` -> the view's name after the hop's
LINK_VIEWS = {
    "throughput_kbps": "throughput [kbit/s]",
    "delay_ms": "delay [ms]",
    "count": "losses and retransmissions [count]",
}
# the intervention's views: origin -> name
INTERVENTION_VIEWS = {
    "intervention/angle_deg": "Valve and lever angles [deg]",
    "intervention/grasp/opening_mm": "Grasp: gripper opening [mm]",
    "intervention/grasp/force_n": "Grasp: grip force [N]",
}
# what perception works with: the group under `perception/` -> the view's name
PERCEPTION_VIEWS = {
    "points_per_s": "Points per source [points/s]",
    "recognition_confidence": "Panel recognition confidence [0-1]",
}


def blueprint() -> rrb.Blueprint:
    """Two tabs. Operations: the 3D world large on the left; on the right the camera above the
    controllers' errors, the intervention and perception (the sonar's fan, the points per source,
    the recognition's confidence), a tab each. Links: per hop (a row each) its
    throughput, delay and counts. No plot mixes units."""
    controller = rrb.Vertical(
        *(rrb.TimeSeriesView(origin=f"errors/{group}", name=name) for group, name in ERROR_VIEWS.items()),
        name="Controller",
    )
    intervention = rrb.Vertical(
        rrb.TextLogView(origin="intervention/phase", name="Intervention phase"),
        *(rrb.TimeSeriesView(origin=origin, name=name) for origin, name in INTERVENTION_VIEWS.items()),
        name="Intervention",
    )
    perception = rrb.Vertical(
        rrb.Spatial2DView(origin="sonar", name="Sonar (from above, middle beam up)"),
        rrb.TextLogView(origin="status/perception", name="Perception"),
        *(
            rrb.TimeSeriesView(origin=f"perception/{group}", name=name)
            for group, name in PERCEPTION_VIEWS.items()
        ),
        row_shares=[3, 1, 2, 2],
        name="Perception",
    )
    links = rrb.Grid(
        *(rrb.TimeSeriesView(origin=f"links/{hop}/{group}", name=f"{hop} {name}")
          for hop in keys.HOPS for group, name in LINK_VIEWS.items()),
        grid_columns=len(LINK_VIEWS), name="Links",
    )  # fmt: skip
    operations = rrb.Horizontal(
        rrb.Spatial3DView(origin="world", name="World"),
        rrb.Vertical(
            rrb.Spatial2DView(origin="world/camera", name="Camera"),
            rrb.Tabs(controller, intervention, perception),
            row_shares=[1, 3],
        ),
        column_shares=[3, 2], name="Operations",
    )  # fmt: skip
    # the side panels collapsed, to leave the views the room; each opens with a click
    return rrb.Blueprint(rrb.Tabs(operations, links), rrb.BlueprintPanel(state="collapsed"),
                         rrb.SelectionPanel(state="collapsed"), rrb.TimePanel(state="collapsed"))  # fmt: skip
