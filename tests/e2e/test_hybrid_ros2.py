"""A real vehicle's ROS 2 driver in a hybrid run (`abyss up --ros2 simulation`): the contract node
(rosvehicle.py on rosnode.py, rmw_zenoh's wire contract alone) plays a recorded run's fused
navigation as nav_msgs/Odometry and its joints as sensor_msgs/JointState through the gateway,
which puts them on the simulation's keys; the twin renders the cameras at that pose, onboard
steers the vehicle by it (the node counts the velocity commands), and the vessel maps and
recognises the site as the all-simulated run did."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import pytest
from conftest import RECORDED_MISSION, Up
from maps import agreement, occupied
from rosnode import RosNode, gateway_graph
from rosvehicle import VehicleDriver, joint_state, odometry
from vehicle import recorded

from abyss.common.ports import free_port
from abyss.description.robot import robot_at
from abyss.interface.messages import JointState, NavState

pytestmark = pytest.mark.timeout(300)
CELL_M = 0.1  # the vessel's octree resolution
GATEWAY = "abyss_simulation_gateway"


def ros_samples(run_dir: Path) -> list[tuple[float, str, object]]:
    """The recording's truth (a fused navigation) and joints as the vehicle's driver publishes them."""
    robot = robot_at("")
    out: list[tuple[float, str, object]] = []
    for sim_s, topic, m in recorded(run_dir, ["nav", "joints"], "truth"):
        if isinstance(m, NavState):
            ros = odometry(
                sim_s,
                m.position_m_world,
                m.orientation_wxyz_world,
                m.velocity_mps_body,
                m.angular_velocity_radps_body,
            )
        else:
            assert isinstance(m, JointState)
            ros = joint_state(
                sim_s,
                robot.arm_joints,
                robot.gripper_joints,
                m.positions_rad,
                m.velocities_radps,
                m.gripper_opening_m,
            )
        out.append((sim_s, topic, ros))
    return out


def test_a_ros2_vehicle_driver_provides_the_twin_s_pose_and_the_vessel_maps_as_before(
    tmp_path: Path, recorded_run: Path
) -> None:
    samples = ros_samples(recorded_run)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    up = Up(
        tmp_path / "run",
        *("--ros2", "simulation", "--set", f'ros2.listen=["{endpoint}"]'),
        *RECORDED_MISSION,
        *("--viewer", "save", "--record", "none"),
    )
    up.wait_for(r"simulation is a ROS 2 gateway")
    node = RosNode(endpoint, name="team_vehicle_driver")
    stop, player = threading.Event(), None
    try:
        graph = gateway_graph(
            node,
            GATEWAY,
            {
                ("MS", "/abyss/simulation/nav"),
                ("MS", "/abyss/simulation/joints"),
                ("MP", "/abyss/onboard/cmd/vehicle_velocity"),
                ("MP", "/abyss/onboard/cmd/arm_velocity"),
            },
        )
        mine = {(t.kind, t.topic) for t in graph if t.node == GATEWAY}
        # the driver keeps its own time and frames; it is handed no camera (the twin's are onboard's)
        assert not mine & {("MP", "/clock"), ("MP", "/tf_static"), ("MP", "/abyss/simulation/nav")}, mine
        driver = VehicleDriver(node, samples)
        up.wait_up()  # the twin up, rendering nothing yet
        player = threading.Thread(target=driver.play, args=(stop,), daemon=True)
        player.start()
        assert up.wait(120) == 0, up.output()
    finally:
        stop.set()
        if player is not None:
            player.join()  # no publish in flight while the node's entities go
        node.close()
    summary, recorded_summary = up.summary(), json.loads((recorded_run / "summary.json").read_text())
    simulation = summary["stations"]["simulation"]
    hybrid, twin = summary["hybrid"], simulation["twin"]
    assert hybrid["vehicle_via"] == "ros2" and hybrid["providers"]["nav"] == "vehicle", hybrid
    # what the node published went out on the simulation's keys, none refused
    sent = simulation["sent"]
    assert sent["abyss/default/simulation/nav"] > 0.8 * driver.sent["nav"], (sent, driver.sent)
    assert sent["abyss/default/simulation/joints"] > 0.8 * driver.sent["joints"], (sent, driver.sent)
    assert not simulation["rejected"], simulation["rejected"]
    # onboard commanded the vehicle through the gateway, stamped in the vehicle's own time
    assert len(driver.velocity) > 100 and driver.arm > 100, (len(driver.velocity), driver.arm)
    last = driver.velocity[-1].header
    assert last.frame_id == "base_link" and 1.0 < last.stamp.sec + last.stamp.nanosec * 1e-9 <= samples[-1][0]
    assert twin["frames"] > 0, twin
    # what the vessel mapped and recognised from the twin's frames is what it did in the recorded run
    theirs, mine_cells = occupied(recorded_run), occupied(tmp_path / "run")
    precision, recall = agreement(mine_cells, theirs), agreement(theirs, mine_cells)
    print(
        f"octree against the all-simulated run's: precision {precision:.3f}, recall {recall:.3f} "
        f"({len(mine_cells)} cells against {len(theirs)}); {twin['frames']} frames, navigation to "
        f"frame p50 {twin['nav_to_frame_p50_ms']:.0f} ms, p95 {twin['nav_to_frame_p95_ms']:.0f} ms; "
        f"the driver played {driver.played_s:.1f} s, sent {driver.sent}, got {len(driver.velocity)} "
        f"velocity and {driver.arm} arm commands; the simulation station's cores "
        f"{simulation['cpu']['cores']:.3f} as gateway and twin, "
        f"{recorded_summary['stations']['simulation']['cpu']['cores']:.3f} whole"
    )
    assert precision >= 0.8 and recall >= 0.8, (precision, recall)
    assert "panel" in summary["scene"]["objects"], summary["scene"]
