"""The gateway's rmw_zenoh wire format against golden vectors: key expressions, liveliness tokens
and QoS strings copied from rmw_zenoh's docs/design.md (release 0.2.10), GIDs computed by
rmw_zenoh's own XXH3 code compiled from its source, type hashes as ROS 2 prints them
(`ros2 topic info --verbose`), CDR bytes as Fast-CDR writes them; and the conversions back from
ROS 2 messages, with the reasons they refuse one."""

from __future__ import annotations

import numpy as np
import pytest

from abyss.common.errors import BadInput
from abyss.description.robot import robot_at
from abyss.interface.clouds import pack_cloud, unpack_cloud
from abyss.interface.messages import ArmGoal, ArmVelocityRef, NavState, Waypoints
from abyss.ros2 import from_ros, motion, msgs, rmw, sensing, status
from abyss.ros2.session import Session

ROBOT = robot_at("")  # the shipped robot package


ZID = "aac3178e146ba6f1fc6e6a4085e77f21"
STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"


def test_data_keys_are_design_md_s() -> None:
    assert (
        rmw.topic_key(0, "/chatter", "std_msgs/msg/String")
        == f"0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    )
    assert (
        rmw.topic_key(0, "/robot1/chatter", "std_msgs/msg/String")
        == f"0/robot1/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    )


@pytest.mark.parametrize(
    ("type_name", "published"),
    [
        ("std_msgs/msg/String", STRING_HASH),  # design.md
        (
            "geometry_msgs/msg/Twist",
            "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a",
        ),
        ("geometry_msgs/msg/Pose", "RIHS01_d501954e9476cea2996984e812054b68026ae0bfae789d9a10b23daf35cc90fa"),
        (
            "geometry_msgs/msg/Transform",
            "RIHS01_beb83fbe698636351461f6f35d1abb20010c43d55374d81bd041f1ba2581fddc",
        ),
    ],
)
def test_type_hashes_are_the_ones_ros_prints(type_name: str, published: str) -> None:
    assert rmw.type_hash(type_name) == published


def test_liveliness_tokens_are_design_md_s() -> None:
    node = rmw.Endpoint(0, ZID, 0, 0, rmw.NODE, "/", "listener")
    assert node.token == f"@ros2_lv/0/{ZID}/0/0/NN/%/%/listener"
    subscription = rmw.Endpoint(
        0,
        ZID,
        0,
        10,
        rmw.SUBSCRIPTION,
        "/",
        "listener",
        "/chatter",
        "std_msgs/msg/String",
        msgs.RELIABLE_QOS,
    )
    assert subscription.token == (
        f"@ros2_lv/0/{ZID}/0/10/MS/%/%/listener/%chatter/"
        f"std_msgs::msg::dds_::String_/{STRING_HASH}/::,10:,:,:,,"
    )
    nested = rmw.Endpoint(5, ZID, 3, 3, rmw.NODE, "/robot1/arm", "driver")
    assert nested.token == f"@ros2_lv/5/{ZID}/3/3/NN/%/%robot1%arm/driver"


def test_qos_strings_leave_rmw_zenoh_s_defaults_empty() -> None:
    assert rmw.qos_string(msgs.RELIABLE_QOS) == "::,10:,:,:,,"  # rclcpp's default
    assert rmw.qos_string(msgs.SENSOR_QOS) == "2::,5:,:,:,,"  # SensorDataQoS
    assert rmw.qos_string(msgs.CLOCK_QOS) == "2::,1:,:,:,,"  # ClockQoS
    assert rmw.qos_string(msgs.TF_STATIC_QOS) == ":1:,1:,:,:,,"  # tf2's static broadcaster


def test_gids_are_rmw_zenoh_s_xxh3_of_the_token() -> None:
    zid = "c88f831a9a3a16ddecf065cebd5aa080"
    node = rmw.Endpoint(0, zid, 0, 0, rmw.NODE, "/", "teleop")
    publisher = rmw.Endpoint(
        0, zid, 0, 3, rmw.PUBLISHER, "/", "teleop", "/cmd_vel", "geometry_msgs/msg/Twist", msgs.RELIABLE_QOS
    )
    clock = rmw.Endpoint(
        0,
        zid,
        0,
        12,
        rmw.SUBSCRIPTION,
        "/",
        "sim_listener",
        "/clock",
        "rosgraph_msgs/msg/Clock",
        msgs.CLOCK_QOS,
    )
    assert node.gid.hex() == "c3aee7280179c53813730c7ac9dc33ff"
    assert publisher.gid.hex() == "c4051822192c37bc15f1812448d1f986"
    assert clock.gid.hex() == "b7f23239c7f9859abc1e5cca98902900"


def test_attachment_is_33_bytes_and_malformed_ones_are_named() -> None:
    gid = bytes.fromhex("c4051822192c37bc15f1812448d1f986")
    data = rmw.attachment(1, 1732400000123456789, gid)
    assert data.hex() == "010000000000000015cd3e189fb80a1810c4051822192c37bc15f1812448d1f986"
    assert rmw.parse_attachment(data) == (1, 1732400000123456789, gid)
    with pytest.raises(BadInput, match="no attachment"):
        rmw.parse_attachment(None)
    with pytest.raises(BadInput, match="attachment of 20 bytes"):
        rmw.parse_attachment(data[:20])
    with pytest.raises(BadInput, match="GID is 15 bytes"):
        rmw.parse_attachment(data[:16] + b"\x0f" + gid)
    old = bytes.fromhex("0f73657175656e63655f6e756d626572")  # the pre-0.2.4 format's first field
    with pytest.raises(BadInput):
        rmw.parse_attachment(old)


def test_cdr_is_fast_cdr_s_and_bad_bytes_are_refused() -> None:
    twist = msgs.TYPESTORE.types["geometry_msgs/msg/Twist"](
        linear=msgs.vector_msg((0.5, 0, 0)), angular=msgs.vector_msg((0, 0, 0.25))
    )
    payload = msgs.serialize(twist)
    assert payload.hex() == ("00010000000000000000e03f" + "0000000000000000" * 4 + "000000000000d03f")
    assert rmw.deserialize(payload, "geometry_msgs/msg/Twist").angular.z == 0.25
    clock = status.clock(None, msgs.header(12.5, ""), None)  # type: ignore[arg-type]
    assert msgs.serialize(clock).hex() == "000100000c0000000065cd1d"
    with pytest.raises(BadInput, match="not CDR"):
        rmw.deserialize(b"\x07\x07garbage", "geometry_msgs/msg/Twist")
    with pytest.raises(BadInput, match="does not decode"):
        rmw.deserialize(payload[:20], "geometry_msgs/msg/Twist")


def _diagnostics(**values: str) -> object:
    t = msgs.TYPESTORE.types
    return t["diagnostic_msgs/msg/DiagnosticArray"](
        header=msgs.header(1.0, ""),
        status=[
            t["diagnostic_msgs/msg/DiagnosticStatus"](
                level=0,
                name="node",
                message="",
                hardware_id="",
                values=[t["diagnostic_msgs/msg/KeyValue"](key=k, value=v) for k, v in values.items()],
            )
        ],
    )


def _nav(sim_time_s: float) -> NavState:
    return NavState(
        np.array([1.0, 0.0, -7.0]), np.array([1.0, 0, 0, 0]), np.zeros(3), np.zeros(3), sim_time_s
    )


def test_telemetry_comes_from_the_node_s_state_and_what_it_was_handed() -> None:
    session = Session(ROBOT)
    assert (
        from_ros.telemetry_in(_diagnostics(mode="moving"), session) is None
    )  # no navigation handed over yet
    session.handed(_nav(4.0))
    session.handed(Waypoints(7, np.array([[1.5, 0.0, -7.0, 0.0], [2.5, 0.8, -7.6, 0.3]])))
    session.handed(ArmGoal(9, np.array([2.0, 0.0, -7.0]), np.array([1.0, 0, 0, 0])))
    telemetry = from_ros.telemetry_in(_diagnostics(mode="moving", waypoint="1/2", arm_mode="idle"), session)
    assert telemetry is not None
    assert (telemetry.mode, telemetry.command_id, telemetry.waypoint_index, telemetry.waypoints_total) == (
        "moving",
        7,
        1,
        2,
    )
    assert np.allclose(telemetry.position_error_m_world, [1.5, 0.8, -0.6]) and telemetry.arm_command_id == 9
    assert telemetry.sim_time_s == 4.0 and telemetry.boot_id == session.boot_id
    turned = np.array([np.cos(0.2), 0.0, 0.0, np.sin(0.2)])  # 0.4 rad of yaw
    session.handed(NavState(np.zeros(3), turned, np.array([0.3, -0.1, 0.0]), np.zeros(3), 5.0))
    telemetry = from_ros.telemetry_in(_diagnostics(mode="moving"), session)
    assert telemetry is not None and np.allclose(telemetry.orientation_wxyz_world, turned)
    assert np.allclose(telemetry.velocity_mps_body, [0.3, -0.1, 0.0]) and not telemetry.effort_body.any()
    with pytest.raises(BadInput, match="not one of"):
        from_ros.telemetry_in(_diagnostics(mode="flying"), session)
    with pytest.raises(BadInput, match="waypoint 'x'"):
        from_ros.telemetry_in(_diagnostics(waypoint="x"), session)


def test_velocity_commands_parse_back_within_abyss_s_bounds() -> None:
    t = msgs.TYPESTORE.types
    twist = t["geometry_msgs/msg/TwistStamped"](
        header=msgs.header(1.0, "base_link"),
        twist=t["geometry_msgs/msg/Twist"](
            linear=msgs.vector_msg((0.2, 0, -0.1)), angular=msgs.vector_msg((0, 0, 0.3))
        ),
    )
    ref = from_ros.twist_in(twist, Session(ROBOT))
    assert np.allclose(ref.linear_mps_body, [0.2, 0, -0.1]) and ref.yaw_rate_radps == pytest.approx(0.3)
    twist.header.frame_id = "world"
    with pytest.raises(BadInput, match="frame_id 'world'"):
        from_ros.twist_in(twist, Session(ROBOT))
    session, head = Session(ROBOT), msgs.header(0, "")
    sent = motion.joint_velocities(ArmVelocityRef(np.arange(6) * 0.1, 0.02), head, session)
    command = motion.joint_velocities(from_ros.joint_velocities_in(sent, session), head, session)
    assert np.allclose(command.data, [*(np.arange(6) * 0.1), 0.02])
    command.data = np.zeros(5)
    with pytest.raises(BadInput, match="5 values, expected 7"):
        from_ros.joint_velocities_in(command, Session(ROBOT))
    command.data = np.full(7, 50.0)
    with pytest.raises(BadInput, match="joint_velocities_radps"):
        from_ros.joint_velocities_in(command, Session(ROBOT))


def test_a_node_s_cloud_parses_back_to_the_points_it_holds() -> None:
    session = Session(ROBOT)
    points_m = np.array([[4.0, 0.1, -8.5], [4.2, -0.3, -8.6], [np.nan, 0.0, 0.0]])
    colors = np.array([[255, 0, 0], [0, 128, 255], [0, 0, 0]], np.uint8)
    cloud = sensing.point_cloud(
        pack_cloud("stereo", points_m[:2], colors[:2], np.zeros(3), 0.002, 1.0),
        msgs.header(1.0, msgs.WORLD),
        session,
    )
    assert from_ros.point_cloud_in(cloud, session) is None  # no navigation yet: no sensor origin
    session.handed(_nav(1.0))
    back = from_ros.point_cloud_in(cloud, session)
    assert back is not None and back.count == 2 and np.allclose(back.sensor_m_world, [1.0, 0.0, -7.0])
    got_m, got_colors = unpack_cloud(back)
    assert np.allclose(got_m, points_m[:2], atol=0.002) and (got_colors == colors[:2]).all()
    cloud.point_step = 8
    with pytest.raises(BadInput, match="bytes for 2 points of 8"):
        from_ros.point_cloud_in(cloud, session)
    cloud.fields = cloud.fields[1:]
    with pytest.raises(BadInput, match="no float32 field 'x'"):
        from_ros.point_cloud_in(cloud, session)


def test_a_node_s_octomap_becomes_the_vessel_s_map() -> None:
    from abyss.scene.model import SceneModel
    from abyss.scene.octree import GREY, cell_keys, write_cells

    keys_m = np.array([[4.05, 0.05, -8.45], [4.35, 0.05, -8.45], [4.05, 0.35, -8.05]])
    binary = write_cells(cell_keys(keys_m, 0.1), np.array([True, True, False]), 0.1)
    data = sensing.octree_data(binary)
    octomap = msgs.TYPESTORE.types["octomap_msgs/msg/Octomap"](
        header=msgs.header(2.0, msgs.WORLD),
        binary=True,
        id="OcTree",
        resolution=0.1,
        data=np.frombuffer(data, np.int8),
    )
    snapshot = from_ros.octomap_in(octomap, Session(ROBOT))
    size = binary.split(b"\nsize ")[1].split(b"\n")[0]  # as OctoMap wrote it
    assert snapshot.octree.endswith(data) and b"\nsize " + size + b"\n" in snapshot.octree
    model = SceneModel(0.1, 10.0)
    assert model.adopt(snapshot.octree) >= 2  # leaves: OctoMap prunes
    update = model.next_update(2.0)
    assert update is not None and len(update.colors) == 2 and (update.colors == GREY).all()
    with pytest.raises(BadInput, match="not OctoMap's binary stream"):
        sensing.octree_file(data[:-2], 0.1)
    with pytest.raises(BadInput, match=r"tree resolution 0\.05"):
        SceneModel(0.1, 10.0).adopt(sensing.octree_file(data, 0.05))
