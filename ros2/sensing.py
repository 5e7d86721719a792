"""Conversions of what the sensors and the scene give to ROS 2: camera and sonar images, camera
info, point clouds, the octree as an Octomap, the recognised objects as markers."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from abyss.common.errors import BadInput
from abyss.interface.clouds import unpack_cloud
from abyss.interface.images import decode_image
from abyss.interface.messages import (
    Image,
    PointCloud,
    RecognisedObjects,
    SceneUpdate,
    SonarImage,
)
from abyss.ros2.msgs import (
    ROS,
    Floats,
    floats,
    header_of,
    optical_frame,
    pose_msg,
    vector_msg,
)
from abyss.ros2.session import Session


def raw_image(image: Image, head: Any, session: Session) -> Any | None:
    """A colour frame as `rgb8` pixels (image_transport's raw base topic)."""
    if image.encoding != "jpeg":
        return None
    pixels = decode_image(image)
    return ROS["sensor_msgs/msg/Image"](
        header=header_of(head, optical_frame(image.camera)),
        height=image.height_px,
        width=image.width_px,
        encoding="rgb8",
        is_bigendian=0,
        step=3 * image.width_px,
        data=np.ascontiguousarray(pixels).ravel(),
    )


def compressed_image(image: Image, head: Any, session: Session) -> Any | None:
    if image.encoding != "jpeg":
        return None
    return ROS["sensor_msgs/msg/CompressedImage"](
        header=header_of(head, optical_frame(image.camera)),
        format="jpeg",
        data=np.frombuffer(image.data, np.uint8),
    )


def sonar_image(sonar: SonarImage, head: Any, session: Session) -> Any:
    """The polar image (rows range bins, columns beams port to starboard) as the sonar sent it,
    PNG or JPEG, in the sonar's own frame; its geometry is in the abyss message (marine_acoustic_msgs,
    which carries it, is in no message store rosbags has)."""
    return ROS["sensor_msgs/msg/CompressedImage"](
        header=header_of(head, sonar.sonar),
        format="png" if sonar.encoding == "png8" else "jpeg",
        data=np.frombuffer(sonar.data, np.uint8),
    )


def depth_image(image: Image, head: Any, session: Session) -> Any | None:
    """Depth as REP 118's 16UC1 in millimetres: abyss's PNG counts, unchanged."""
    if image.encoding != "png16":
        return None
    depth_mm = cv2.imdecode(np.frombuffer(image.data, np.uint8), cv2.IMREAD_UNCHANGED)
    if depth_mm is None or depth_mm.dtype != np.uint16 or depth_mm.shape != (image.height_px, image.width_px):
        raise BadInput(
            f"{image.camera}: the depth PNG does not decode to "
            f"{image.width_px}x{image.height_px} 16-bit pixels"
        )
    return ROS["sensor_msgs/msg/Image"](
        header=header_of(head, optical_frame(image.camera)),
        height=image.height_px,
        width=image.width_px,
        encoding="16UC1",
        is_bigendian=0,
        step=2 * image.width_px,
        data=np.ascontiguousarray(depth_mm, dtype="<u2").view(np.uint8).ravel(),
    )


def camera_info(image: Image, head: Any, session: Session) -> Any:
    """The pinhole intrinsics, no distortion (the rendered cameras have none)."""
    fx, fy, cx, cy = image.fx_px, image.fy_px, image.cx_px, image.cy_px
    return ROS["sensor_msgs/msg/CameraInfo"](
        header=header_of(head, optical_frame(image.camera)),
        height=image.height_px,
        width=image.width_px,
        distortion_model="plumb_bob",
        d=np.zeros(5),
        k=floats([fx, 0, cx, 0, fy, cy, 0, 0, 1]),
        r=floats([1, 0, 0, 0, 1, 0, 0, 0, 1]),
        p=floats([fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0]),
        binning_x=0,
        binning_y=0,
        roi=ROS["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        ),
    )


CLOUD_POINT = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<u4")])


def point_cloud(cloud: PointCloud, head: Any, session: Session) -> Any:
    """x, y, z float32 [m, world] and `rgb` as PCL packs it: one float32 whose bytes are
    0x00RRGGBB (little-endian: b, g, r, 0)."""
    points_m, colors = unpack_cloud(cloud)
    records = np.empty(len(points_m), CLOUD_POINT)
    records["x"], records["y"], records["z"] = points_m.T
    rgb = colors.astype(np.uint32)
    records["rgb"] = (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]
    field = ROS["sensor_msgs/msg/PointField"]
    fields = [
        field(name=name, offset=4 * i, datatype=field.FLOAT32, count=1)
        for i, name in enumerate(("x", "y", "z", "rgb"))
    ]
    return ROS["sensor_msgs/msg/PointCloud2"](
        header=head,
        height=1,
        width=len(records),
        fields=fields,
        is_bigendian=False,
        point_step=CLOUD_POINT.itemsize,
        row_step=CLOUD_POINT.itemsize * len(records),
        data=records.view(np.uint8),
        is_dense=True,
    )


def octree_data(octree: bytes) -> bytes:
    """OctoMap's binary stream without its text header (id, size, resolution: the Octomap
    message's fields): what `writeBinaryData` writes and octomap_msgs carries."""
    head, separator, data = octree.partition(b"\ndata\n")
    if not separator or not head.startswith(b"# Octomap OcTree binary file"):
        raise BadInput("not an OctoMap binary tree")
    return data


def octree_file(data: bytes, resolution_m: float) -> bytes:
    """OctoMap's binary file of an Octomap message's data (octree_data's inverse): its header
    needs the node count, which the data holds: two bytes per inner node, whose children are two
    bits each (00 unknown, 01 free, 10 occupied, 11 inner)."""
    children = np.frombuffer(data, np.uint8)[:, None] >> np.array([0, 2, 4, 6], np.uint8) & 3
    inner = int((children == 3).sum())
    if len(data) % 2 or len(data) != 2 * (inner + 1):
        raise BadInput(
            f"{len(data)} bytes are not OctoMap's binary stream of a tree "
            f"({inner} inner children need {2 * (inner + 1)} bytes)"
        )
    size = len(data) // 2 + int(((children == 1) | (children == 2)).sum())
    head = f"# Octomap OcTree binary file\nid OcTree\nsize {size}\nres {resolution_m}\ndata\n"
    return head.encode() + data


def octomap(update: SceneUpdate, head: Any, session: Session) -> Any | None:
    """The whole map shore holds once this update is applied (binary: free or occupied, no
    colours); None after a gap, until the snapshot that ends it."""
    if session.scene.apply(update) != "applied":
        return None
    return ROS["octomap_msgs/msg/Octomap"](
        header=head,
        binary=True,
        id="OcTree",
        resolution=session.scene.resolution_m,
        data=np.frombuffer(octree_data(session.scene.binary()), np.int8),
    )


def objects(found: RecognisedObjects, head: Any, session: Session) -> Any:
    """A box per object (namespace: its name), after a DELETEALL that clears the previous ones;
    the colour goes from red to green with the confidence."""
    marker_type = ROS["visualization_msgs/msg/Marker"]

    def marker(
        action: int,
        ns: str = "",
        index: int = 0,
        pose: Any = None,
        size_m: Floats = (0, 0, 0),
        confidence: float = 0.0,
    ) -> Any:
        return marker_type(
            header=head,
            ns=ns,
            id=index,
            type=marker_type.CUBE,
            action=action,
            pose=pose or pose_msg((0, 0, 0), (1, 0, 0, 0)),
            scale=vector_msg(size_m),
            color=ROS["std_msgs/msg/ColorRGBA"](r=1.0 - confidence, g=confidence, b=0.0, a=0.6),
            lifetime=ROS["builtin_interfaces/msg/Duration"](sec=0, nanosec=0),
            frame_locked=False,
            points=[],
            colors=[],
            texture_resource="",
            texture=ROS["sensor_msgs/msg/CompressedImage"](
                header=head, format="", data=np.zeros(0, np.uint8)
            ),
            uv_coordinates=[],
            text=ns,
            mesh_resource="",
            mesh_file=ROS["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, np.uint8)),
            mesh_use_embedded_materials=False,
        )

    found_each = zip(found.names, found.poses_world, found.half_sizes_m, found.confidences, strict=True)
    boxes = [
        marker(marker_type.ADD, name, i, pose_msg(pose[:3], pose[3:]), 2 * half, float(confidence))
        for i, (name, pose, half, confidence) in enumerate(found_each)
    ]
    return ROS["visualization_msgs/msg/MarkerArray"](markers=[marker(marker_type.DELETEALL), *boxes])
