"""Every sensor's frame in the TF tree: the navigation sensors' from their sites on the robot's
model (fixed, on /tf_static), the cameras' and the sonar's from their messages' mountings."""

from __future__ import annotations

import numpy as np

from abyss.description.robot import robot_at, robot_spec
from abyss.interface.messages import SonarImage
from abyss.ros2 import motion
from abyss.ros2.session import ArmFrames


def test_the_navigation_sensors_sites_are_fixed_frames_on_base_link() -> None:
    robot = robot_at("bluerov2_heavy_alpha5")  # its model places its USBL, depth, IMU and DVL
    fixed = {
        child: (parent, xyz)
        for parent, child, xyz, _ in ArmFrames(robot).transforms(np.zeros(len(robot.arm_joints)), 0.0, False)
    }
    model = robot_spec(robot).compile()
    for name in robot.nav_sensor_names:
        parent, xyz = fixed[name]
        assert parent == "base_link"
        np.testing.assert_allclose(xyz, model.site(name).pos, atol=1e-9)  # on the hull body itself


def test_the_sonars_frame_is_its_mounting_named_as_its_images_headers_name_it() -> None:
    pose = np.array([0.3, 0.0, 0.1, 1.0, 0.0, 0.0, 0.0])
    ping = SonarImage(
        sonar="fls", encoding="png8", pose_frame="vehicle", beams=4, bins=4, range_max_m=10.0,
        horizontal_fov_rad=1.0, vertical_aperture_rad=0.2, dynamic_range_db=40.0, pose_sonar=pose,
        data=b"", sim_time_s=1.0,
    )  # fmt: skip
    frame, mount = motion.sensor_mount(ping) or ("", None)
    assert frame == "fls" and mount is not None and np.array_equal(mount, pose)
    assert (
        motion.sensor_mount(SonarImage(**{**vars(ping), "pose_frame": "world"})) is None
    )  # onboard's, placed
