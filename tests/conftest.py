"""Pick an offscreen GL backend before any test imports MuJoCo's rendering; run the whole-system
tests last, and start what a test module asks to begin early (its `begin()`: UML's boot) as
collection ends, so that it runs beside the unit tests."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import settings

from abyss.stations.simulation.rendering import choose_gl_backend

# property tests judge results, not time: on this loaded 2-core machine an example's first run can
# pause for a GC or a neighbour's burst (292 ms against hypothesis's 200 ms deadline in CI)
settings.register_profile("abyss", deadline=None)
settings.load_profile("abyss")

choose_gl_backend()
E2E = Path(__file__).parent / "e2e"
# The whole-system tests that run in real time, and why each must: every other one runs on lockstep
# or simulated time, where the machine's load changes the wall time and never the verdict
# (docs/time.md). Each carries the `realtime` marker (`-m "e2e and not realtime"`: the verdicts
# that do not depend on the load). A module's name stands for all its tests.
REALTIME = {
    "test_console.py": "a browser's pacing, and the pilot's commands in wall time",
    "test_web_viewer.py": "rerun's web viewer in a browser",
    "test_operator.py": "the operator's tools act in wall time (docs/time.md)",
    "test_teleop.py": "a joystick's commands in wall time",
    "test_hybrid.py": "a real vehicle (a replayed one) keeps the wall clock",
    "test_hybrid_ros2.py": "a ROS 2 vehicle driver keeps the wall clock",
    "test_ros2_gateway.py": "a ROS 2 node keeps the wall clock",
    "test_simulation_station.py": "the physics' real-time priority and its real-time factor",
    "test_tcp_model.py": "the kernel's TCP through a real shaper",
    "test_hosts.py": "stations in network namespaces over real, shaped links",
    "test_lab.py": "real links shaped in network namespaces",
    "test_compose_up.py": "stations in containers over real links",
    "test_replay.py": "a replay paces a recording on the wall clock",
    "test_export_mcap.py": "reads the replays' recorded run (a real-time run)",
    "test_mavlink.py": "a ground station keeps the wall clock (MAVLink refuses another time mode)",
    "test_up.py": "`abyss up` as a newcomer runs it (real time) and its stop, kill and Ctrl-C in wall time",
    "test_control.py::test_failsafe_holds_station_through_a_tether_outage_and_resumes": (
        "an operator changes the link from outside, in wall time"
    ),
    "test_scenarios.py::test_an_external_station_started_by_hand": "an external station keeps the wall clock",
    "test_campaign.py::test_two_ray_nodes_share_a_campaign_and_a_dead_workers_run_is_retried_on_the_head": (
        "a Ray node's death and the retry in wall time"
    ),
}


def pytest_itemcollected(item: pytest.Item) -> None:
    """Everything under tests/e2e starts whole systems: the folder is the tier (`-m "not e2e"`);
    the real-time ones (REALTIME) carry `realtime` too."""
    if E2E in item.path.parents:
        item.add_marker(pytest.mark.e2e)
        name = getattr(item, "originalname", item.name)
        if item.path.name in REALTIME or f"{item.path.name}::{name}" in REALTIME:
            item.add_marker(pytest.mark.realtime)


@pytest.hookimpl(trylast=True)  # after -m and -k have deselected
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    items.sort(key=lambda item: item.get_closest_marker("e2e") is not None)  # stable: otherwise as found
    begun: set[object] = set()
    for item in items:
        module = getattr(item, "module", None)
        begin = getattr(module, "begin", None)
        if callable(begin) and module not in begun:
            begun.add(module)
            begin()
