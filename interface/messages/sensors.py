"""What the sensors send: camera frames, sonar images, point clouds."""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass

import numpy as np

from abyss.common.errors import BadInput
from abyss.interface.messages.schema import Message, array, blob, check_unit_quaternion, scalar

IMAGE_ENCODINGS = ("jpeg", "png16")
POSE_FRAMES = ("vehicle", "world")


@dataclass(frozen=True)
class Image(Message):
    """A camera frame: RGB as JPEG, depth as 16-bit PNG in millimetres. Intrinsics of the
    pinhole model [px]; `pose_camera`: the camera's pose in `pose_frame`, x, y, z [m] and
    quaternion w, x, y, z, camera axes as OpenCV's (x right, y down, z forward). The simulation
    sends the pose in the vehicle frame (its mounting); onboard, which knows where the vehicle
    was when the frame was taken, sends it on in the world frame."""

    camera: str = scalar()
    encoding: str = scalar(choices=IMAGE_ENCODINGS)
    pose_frame: str = scalar(choices=POSE_FRAMES)
    width_px: int = scalar(1, 8192)
    height_px: int = scalar(1, 8192)
    fx_px: float = scalar(1e-3, 1e6)
    fy_px: float = scalar(1e-3, 1e6)
    cx_px: float = scalar(0.0, 8192.0)
    cy_px: float = scalar(0.0, 8192.0)
    pose_camera: np.ndarray = array("f8", (7,), -1e5, 1e5)
    data: bytes = blob(32 * 2**20)
    sim_time_s: float = scalar(0.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        check_unit_quaternion(self.pose_camera[3:])


SONAR_ENCODINGS = ("png8", "jpeg")


@dataclass(frozen=True)
class SonarImage(Message):
    """An imaging sonar's polar image, as a sonar's driver sends it: rows are `bins` range bins
    from 0 to `range_max_m` (nearest first), columns `beams` bearings evenly across
    `horizontal_fov_rad` from port to starboard; a grey level is the echo's strength in decibels,
    0 at the noise floor and 255 at `dynamic_range_db` above it. Each echo may come from anywhere
    within `vertical_aperture_rad` about the middle beam: the image holds no elevation.
    `pose_sonar`: the sonar's pose in `pose_frame`, x, y, z [m] and quaternion w, x, y, z, its axes
    x along the middle beam, y to port, z up; the simulation sends it in the vehicle frame (the
    mounting), onboard on in the world frame, as a camera's."""

    sonar: str = scalar()
    encoding: str = scalar(choices=SONAR_ENCODINGS)
    pose_frame: str = scalar(choices=POSE_FRAMES)
    beams: int = scalar(1, 4096)
    bins: int = scalar(1, 8192)
    range_max_m: float = scalar(0.1, 1000.0)
    horizontal_fov_rad: float = scalar(1e-3, 2.0 * math.pi)
    vertical_aperture_rad: float = scalar(1e-3, math.pi)
    dynamic_range_db: float = scalar(1.0, 200.0)
    pose_sonar: np.ndarray = array("f8", (7,), -1e5, 1e5)
    data: bytes = blob(8 * 2**20)
    sim_time_s: float = scalar(0.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        check_unit_quaternion(self.pose_sonar[3:])


CLOUD_SOURCES = ("depth", "stereo")
CLOUD_POINT_BYTES = 9  # x, y, z as int16 and r, g, b as uint8


@dataclass(frozen=True)
class PointCloud(Message):
    """A coloured point cloud in the world frame, quantised and compressed (interface.clouds):
    each point as three int16 multiples of `scale_m` from `origin_m_world` and an RGB colour,
    the whole zlib-compressed. `sensor_m_world`: where the rays began, for ray casting."""

    source: str = scalar(choices=CLOUD_SOURCES)
    count: int = scalar(0, 2_000_000)
    scale_m: float = scalar(1e-4, 1.0)
    origin_m_world: np.ndarray = array("f8", (3,), -1e5, 1e5)
    sensor_m_world: np.ndarray = array("f8", (3,), -1e5, 1e5)
    data: bytes = blob(32 * 2**20)
    sim_time_s: float = scalar(0.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        expected = self.count * CLOUD_POINT_BYTES
        try:
            raw = zlib.decompressobj().decompress(self.data, expected + 1)
        except zlib.error as exc:
            raise BadInput(f"data: not zlib ({exc})") from None
        if len(raw) != expected:
            raise BadInput(f"data: {len(raw)} bytes decompressed; {self.count} points need {expected}")
