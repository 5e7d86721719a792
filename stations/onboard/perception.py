"""Onboard perception: coloured point clouds in the world frame from the depth camera (coloured
by the RGB camera above it) and from the stereo pair (stereo.py), placed with
the navigation pose of the moment the frame was taken, with the arm filtered out, voxel-
downsampled and packed for the tether. A pure core: frames and poses in, messages out."""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from abyss.common.errors import BadInput
from abyss.common.geometry import quat_wxyz_of, rotation_of
from abyss.description.robot_file import CamerasSection
from abyss.interface.clouds import pack_cloud, voxel_downsample
from abyss.interface.images import decode_image
from abyss.interface.messages import Image, PointCloud
from abyss.stations.onboard.stereo import StereoFilter, stereo_depth

if TYPE_CHECKING:
    from abyss.config.stations import OnboardConfig

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Camera:
    """A pinhole camera: intrinsics [px] and its pose in the vehicle frame (OpenCV axes)."""

    matrix: np.ndarray  # 3x3
    width_px: int
    height_px: int
    rotation_in_vehicle: np.ndarray  # 3x3, camera axes to vehicle axes
    position_m_vehicle: np.ndarray

    @staticmethod
    def of(image: Image) -> Camera:
        if image.pose_frame != "vehicle":
            raise BadInput(f"{image.camera}: pose in the {image.pose_frame} frame, expected the vehicle's")
        matrix = np.array([[image.fx_px, 0.0, image.cx_px], [0.0, image.fy_px, image.cy_px], [0.0, 0.0, 1.0]])
        return Camera(
            matrix,
            image.width_px,
            image.height_px,
            rotation_of(image.pose_camera[3:]),
            np.array(image.pose_camera[:3]),
        )

    def scaled(self, scale: int) -> Camera:
        """This camera's images shrunk `scale` times by area averaging (cv2.INTER_AREA): a pixel
        is the mean of a `scale` x `scale` block, its centre at the block's."""
        if scale == 1:
            return self
        fx, fy, cx, cy = self.matrix[0, 0], self.matrix[1, 1], self.matrix[0, 2], self.matrix[1, 2]
        matrix = np.array(
            [
                [fx / scale, 0.0, (cx + 0.5) / scale - 0.5],
                [0.0, fy / scale, (cy + 0.5) / scale - 0.5],
                [0.0, 0.0, 1.0],
            ]
        )
        return Camera(
            matrix,
            self.width_px // scale,
            self.height_px // scale,
            self.rotation_in_vehicle,
            self.position_m_vehicle,
        )


def depth_to_points(depth_m: np.ndarray, camera: Camera, max_range_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Points in the camera frame [m] of the pixels with a depth in (0, max_range_m], and their
    flat pixel indices."""
    rows, cols = np.nonzero((depth_m > 0) & (depth_m <= max_range_m))
    z = depth_m[rows, cols].astype(np.float64)
    fx, fy, cx, cy = camera.matrix[0, 0], camera.matrix[1, 1], camera.matrix[0, 2], camera.matrix[1, 2]
    points = np.stack(((cols - cx) * z / fx, (rows - cy) * z / fy, z), axis=1)
    return points, rows * depth_m.shape[1] + cols


def colors_at(points_m_camera: np.ndarray, camera: Camera, rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The colour of each point seen by `camera` (points in its frame), and which it sees."""
    z = points_m_camera[:, 2]
    ok = z > 1e-6
    pixels = (camera.matrix @ points_m_camera[ok].T).T
    u = np.full(len(points_m_camera), -1)
    v = np.full(len(points_m_camera), -1)
    u[ok] = np.round(pixels[:, 0] / pixels[:, 2]).astype(int)
    v[ok] = np.round(pixels[:, 1] / pixels[:, 2]).astype(int)
    seen = ok & (u >= 0) & (u < rgb.shape[1]) & (v >= 0) & (v < rgb.shape[0])
    colors = np.zeros((len(points_m_camera), 3), np.uint8)
    colors[seen] = rgb[v[seen], u[seen]]
    return colors, seen


def segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance [m] from each point to the segment a-b."""
    ab = b - a
    f = np.clip(((points - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
    return np.linalg.norm(points - (a + f[:, None] * ab), axis=1)


@dataclass(frozen=True)
class CloudSettings:
    voxel_m: float = 0.02
    max_range_m: float = 8.0
    scale_m: float = 0.002  # quantisation step on the wire
    stereo_disparities: int = 64
    self_filter_radius_m: float = 0.15  # points this close to the arm are the arm's
    stereo_filter: StereoFilter = StereoFilter()
    stereo_mode: str = "hh"  # SGBM_MODES
    stereo_scale: int = 1  # the pair is matched this many times smaller (stereo_depth)

    @staticmethod
    def of(cfg: OnboardConfig) -> CloudSettings:
        return CloudSettings(
            cfg.cloud_voxel_m,
            cfg.cloud_max_range_m,
            cfg.cloud_scale_m,
            cfg.stereo_disparities,
            cfg.self_filter_radius_m,
            StereoFilter.of(cfg),
            cfg.stereo_mode,
            cfg.stereo_scale,
        )


def world_cloud(
    source: str,
    depth_m: np.ndarray,
    depth_camera: Camera,
    rgb: np.ndarray,
    rgb_camera: Camera,
    pose: tuple[np.ndarray, np.ndarray],
    arm_m_world: np.ndarray,
    settings: CloudSettings,
    sim_time_s: float,
) -> PointCloud:
    """The depth image as a coloured cloud in the world frame, packed. `pose`: the vehicle's
    position and orientation when the frame was taken; `arm_m_world`: points along the arm
    (joints to the tool), whose neighbourhood is cut out."""
    points_depth, _ = depth_to_points(depth_m, depth_camera, settings.max_range_m)
    position, orientation = pose
    rotation = rotation_of(orientation)
    # to the world and onto the voxel grid first: what follows works on a point per voxel (a
    # few percent of the pixels), coloured by the pixel its mean falls on
    world = points_depth @ (rotation @ depth_camera.rotation_in_vehicle).T + (
        rotation @ depth_camera.position_m_vehicle + position
    )
    world, _ = voxel_downsample(world, np.zeros((len(world), 0), np.uint8), settings.voxel_m)
    in_rgb = ((world - position) @ rotation - rgb_camera.position_m_vehicle) @ rgb_camera.rotation_in_vehicle
    colors, seen = colors_at(in_rgb, rgb_camera, rgb)
    keep = seen
    for a, b in itertools.pairwise(arm_m_world):
        keep &= segment_distance(world, a, b) > settings.self_filter_radius_m
    sensor = rotation @ depth_camera.position_m_vehicle + position
    return pack_cloud(source, world[keep], colors[keep], sensor, settings.scale_m, sim_time_s)


def mount_in_world(pose_vehicle: np.ndarray, pose: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """A sensor's pose in the world (x, y, z, w, qx, qy, qz) from its mounting on the vehicle
    (the same form) and the vehicle's position and orientation."""
    position, orientation = pose
    rotation = rotation_of(orientation)
    mount = rotation_of(pose_vehicle[3:])
    return np.r_[rotation @ pose_vehicle[:3] + position, quat_wxyz_of(rotation @ mount)]


def camera_in_world(image: Image, pose: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The camera's pose in the world from the vehicle's."""
    Camera.of(image)  # the mounting must be in the vehicle frame
    return mount_in_world(image.pose_camera, pose)


def clouds_of(
    cameras: CamerasSection,
    frames: dict[str, Image],
    pose: tuple[np.ndarray, np.ndarray],
    arm_m_world: np.ndarray,
    sources: tuple[str, ...],
    settings: CloudSettings,
) -> list[PointCloud]:
    """The clouds of one set of frames taken together, by camera (the robot's `cameras`: the stereo
    pair's left colours every cloud; the depth camera's range, the pair's matched disparities)."""
    (left_name, right_name), depth_name = cameras.stereo, cameras.depth
    left = decode_image(frames[left_name])
    left_camera = Camera.of(frames[left_name])
    sim_time_s = frames[left_name].sim_time_s
    clouds = []
    if "depth" in sources:
        depth_camera = Camera.of(frames[depth_name])
        clouds.append(
            world_cloud(
                "depth",
                decode_image(frames[depth_name]),
                depth_camera,
                left,
                left_camera,
                pose,
                arm_m_world,
                settings,
                sim_time_s,
            )
        )
    if "stereo" in sources:
        right_camera = Camera.of(frames[right_name])
        baseline_m = float(np.linalg.norm(right_camera.position_m_vehicle - left_camera.position_m_vehicle))
        depth = stereo_depth(
            left,
            decode_image(frames[right_name]),
            float(left_camera.matrix[0, 0]),
            baseline_m,
            settings.stereo_disparities,
            kept=settings.stereo_filter,
            mode=settings.stereo_mode,
            scale=settings.stereo_scale,
        )
        clouds.append(
            world_cloud(
                "stereo",
                depth,
                left_camera.scaled(settings.stereo_scale),
                left,
                left_camera,
                pose,
                arm_m_world,
                settings,
                sim_time_s,
            )
        )
    return clouds
