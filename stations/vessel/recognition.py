"""Recognition of the valve panel, by texture and by shape, fused into one pose.

- texture: the ArUco markers on the panel's face found in the camera image, the panel's pose
  from all their corners at once by PnP (OpenCV's SQPnP, refined by Levenberg-Marquardt),
  placed in the world with the camera's pose; confidence from the reprojection error, the
  markers seen and their distance;
- shape: the cloud near the expected panel cut to its dominant plane (Open3D RANSAC), then
  point-to-plane ICP of the panel model (points sampled on its face, valves and levers) against
  it, started from the texture pose, or the plane's if no marker was seen; confidence from
  ICP's fitness and residual;
- fusion: each where it is strong: the plane's normal and distance from the shape, the position
  in the plane and the rotation about the normal from the markers (or, with none in view, from
  the estimate so far); then a running average over frames that forgets at the rate the
  navigation's error wanders (PanelTracker), with a confidence that follows the recent frames'.
The valves and levers follow from the panel's pose and the model (description/models/panel.py).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from abyss.common.geometry import quat_wxyz_of, rotation_about, rotation_of
from abyss.config.hybrid import HybridConfig
from abyss.description.models.panel import Panel
from abyss.interface.messages import Image, RecognisedObjects

log = logging.getLogger(__name__)
MIN_PLANE_POINTS = 200
NEAR_M = 1.5  # [m] markers nearer than this are seen as well as it gets


@dataclass(frozen=True)
class Pose:
    rotation: np.ndarray  # panel axes to world axes
    position_m_world: np.ndarray
    confidence: float  # [0, 1]

    def as_vector(self) -> np.ndarray:
        return np.r_[self.position_m_world, quat_wxyz_of(self.rotation)]


def rotation_error_rad(a: np.ndarray, b: np.ndarray) -> float:
    cos = (np.trace(a.T @ b) - 1.0) / 2.0
    return float(np.arccos(np.clip(cos, -1.0, 1.0)))


def by_texture(
    panel: Panel, rgb: np.ndarray, camera_matrix: np.ndarray, pose_camera_in_world: np.ndarray
) -> Pose | None:
    """The panel's pose from its markers, or None with fewer than two markers in view."""
    parameters = cv2.aruco.DetectorParameters()
    parameters.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.ArucoDetector(
        cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, panel.marker_dictionary)), parameters
    )
    corners, ids, _ = detector.detectMarkers(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY))
    if ids is None:
        return None
    seen = [
        (int(i), c.reshape(4, 2))
        for i, c in zip(ids.ravel(), corners, strict=True)
        if int(i) in panel.marker_table
    ]
    if len(seen) < 2:
        return None
    object_points = np.vstack([panel.marker_corners_m_panel(i) for i, _ in seen])
    image_points = np.vstack([c for _, c in seen]).astype(np.float64)
    ok, rvec, tvec = cv2.solvePnP(object_points, image_points, camera_matrix, None, flags=cv2.SOLVEPNP_SQPNP)
    if not ok:
        return None
    rvec, tvec = cv2.solvePnPRefineLM(object_points, image_points, camera_matrix, None, rvec, tvec)
    projected, _ = cv2.projectPoints(object_points, rvec, tvec, camera_matrix, None)
    error_px = float(np.sqrt(np.mean(np.sum((projected.reshape(-1, 2) - image_points) ** 2, axis=1))))
    rotation_in_camera = cv2.Rodrigues(rvec)[0]
    camera_rotation = rotation_of(pose_camera_in_world[3:])
    rotation = camera_rotation @ rotation_in_camera
    position = camera_rotation @ tvec.ravel() + pose_camera_in_world[:3]
    # a pixel is 2 mm at arm's length and 8 mm from 3 m, and PnP's error along the view grows
    # with the distance squared: frames weigh as an inverse variance, by the distance's 4th power
    distance_m = float(np.linalg.norm(tvec))
    confidence = min(1.0, len(seen) / 4) / (1.0 + error_px) * min(1.0, (NEAR_M / distance_m) ** 4)
    return Pose(rotation, position, float(np.clip(confidence, 0.0, 1.0)))


def model_points(panel: Panel, spacing_m: float = 0.02) -> np.ndarray:
    """Points on the panel's face and its valves' and levers' fronts, in the panel's frame."""
    hx, hy, hz = panel.plate_half_size_m
    ys, zs = np.meshgrid(np.arange(-hy, hy + 1e-9, spacing_m), np.arange(-hz, hz + 1e-9, spacing_m))
    face = np.stack((np.full(ys.size, -hx), ys.ravel(), zs.ravel()), axis=1)
    parts = [face]
    for x, y, z in (*panel.valves.values(), *panel.levers.values()):
        offsets = np.arange(-0.04, 0.04 + 1e-9, spacing_m)
        gy, gz = np.meshgrid(offsets, offsets)
        parts.append(np.stack((np.full(gy.size, x - 0.02), y + gy.ravel(), z + gz.ravel()), axis=1))
    return np.vstack(parts)


ICP_DIGITS = 9  # the pose ICP finds, rounded (by_shape)


def by_shape(panel: Panel, points_m_world: np.ndarray, guess: Pose, rng_seed: int = 0) -> Pose | None:
    """The panel's pose from a cloud near the guess: plane segmentation, then ICP of the model."""
    import open3d as o3d

    near = np.linalg.norm(points_m_world - guess.position_m_world, axis=1) < 1.2
    if near.sum() < MIN_PLANE_POINTS:
        return None
    # one thread: Open3D's RANSAC draws per thread (a seed repeats nothing across two), and its
    # threads' sums end in any order; the fit is a few milliseconds (lockstep repeats bit for bit)
    o3d.utility.set_max_threads(1)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points_m_world[near])).voxel_down_sample(0.03)
    o3d.utility.random.seed(rng_seed)
    plane, inliers = cloud.segment_plane(distance_threshold=0.03, ransac_n=3, num_iterations=200)
    if len(inliers) < MIN_PLANE_POINTS:
        return None
    normal = np.asarray(plane[:3]) / np.linalg.norm(plane[:3])
    if abs(normal @ guess.rotation[:, 0]) < np.cos(np.radians(30)):
        return None  # the dominant plane is not the panel's face (the seabed, say)
    # the face and what stands on it (valves, levers), within 0.15 m in front of the plane
    distance = np.asarray(cloud.points) @ normal + plane[3]
    sign = 1.0 if normal @ guess.rotation[:, 0] < 0 else -1.0  # towards the viewer
    near_face = (sign * distance > -0.03) & (sign * distance < 0.15)
    target = cloud.select_by_index(np.flatnonzero(near_face).tolist())
    target.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.08, max_nn=30))
    source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(model_points(panel, 0.03)))
    initial = np.eye(4)
    initial[:3, :3], initial[:3, 3] = guess.rotation, guess.position_m_world
    result = o3d.pipelines.registration.registration_icp(
        source,
        target,
        0.1,
        initial,
        o3d.pipelines.registration.TransformationEstimationPointToPlane(),
        o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=20),
    )
    result = o3d.pipelines.registration.registration_icp(
        source,
        target,
        0.03,
        result.transformation,
        o3d.pipelines.registration.TransformationEstimationPointToPlane(),
        o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=50),
    )
    if result.fitness < 0.2:
        return None
    # rounded to a nanometre and a nanoradian, far below what recognition resolves: a last bit
    # that a native library's sums could still change does not reach the mission
    confidence = round(result.fitness / (1.0 + result.inlier_rmse / 0.01), ICP_DIGITS)
    transform = np.round(np.asarray(result.transformation), ICP_DIGITS)
    return Pose(transform[:3, :3].copy(), transform[:3, 3].copy(), float(np.clip(confidence, 0.0, 1.0)))


def by_plane(
    points_m_world: np.ndarray, expected_m_world: np.ndarray, expected_rotation: np.ndarray | None = None
) -> Pose | None:
    """A first guess with no marker in view: the panel upright at the expected place, facing as
    expected (`expected_rotation`, panel axes to world axes; None: the world's)."""
    near = np.linalg.norm(points_m_world - expected_m_world, axis=1) < 1.5
    if near.sum() < MIN_PLANE_POINTS:
        return None
    rotation = np.eye(3) if expected_rotation is None else expected_rotation
    return Pose(rotation, points_m_world[near].mean(axis=0), 0.1)


def expected_pose(panel: Panel, hybrid: HybridConfig) -> tuple[np.ndarray, np.ndarray]:
    """Where the vessel first looks for the panel, in its world (the vehicle's navigation frame):
    the site package's pose (the panel's frame the site's, translated), and in a hybrid run where
    the registration puts it (`hybrid.nav_pose`: moved to the site's origin, turned by its
    heading). Position [m] and rotation (panel axes to world axes); with no registration, the
    site package's position untouched and the identity."""
    position, orientation = hybrid.nav_pose(np.array(panel.position_m_world), np.array([1.0, 0.0, 0.0, 0.0]))
    return np.array(position), rotation_of(orientation)


def fuse_texture_shape(texture: Pose, shape: Pose) -> Pose:
    """Each method where it is strong: the shape's plane fixes the face's normal and its
    distance along it (thousands of points, millimetre depth), the markers fix the position in
    the plane and the rotation about the normal (ICP slides along a flat face)."""
    normal = shape.rotation[:, 0]
    position = (
        texture.position_m_world + ((shape.position_m_world - texture.position_m_world) @ normal) * normal
    )
    x = texture.rotation[:, 0]
    axis = np.cross(x, normal)
    angle = np.arctan2(np.linalg.norm(axis), float(x @ normal))
    tilt = (
        cv2.Rodrigues(axis / np.linalg.norm(axis) * angle)[0] if np.linalg.norm(axis) > 1e-12 else np.eye(3)
    )
    confidence = 1.0 - (1.0 - texture.confidence) * (1.0 - shape.confidence)
    return Pose(tilt @ texture.rotation, position, float(confidence))


def fuse(poses: list[Pose]) -> Pose:
    """Confidence-weighted mean of poses (quaternions averaged as the principal eigenvector)."""
    weights = np.array([p.confidence for p in poses])
    weights = weights / weights.sum() if weights.sum() > 0 else np.full(len(poses), 1.0 / len(poses))
    position = sum(w * p.position_m_world for w, p in zip(weights, poses, strict=True))
    quats = np.array([quat_wxyz_of(p.rotation) for p in poses])
    accumulator = sum(w * np.outer(q, q) for w, q in zip(weights, quats, strict=True))
    mean_quat = np.linalg.eigh(accumulator)[1][:, -1]
    confidence = 1.0 - np.prod([1.0 - p.confidence for p in poses])
    return Pose(rotation_of(mean_quat / np.linalg.norm(mean_quat)), np.asarray(position), float(confidence))


# -- the parts' angles, from the image: each part's handle is one colour (its hub's), drawn on
# the panel's face; candidate angles are projected into the image through the panel's pose and
# scored by how much of the handle they find in that colour
def handle_samples_m(panel: Panel, valve: bool) -> tuple[np.ndarray, np.ndarray]:
    """Along a handle from its pivot [m]: on it, then past its end, where it must not be (a lever's
    candidate angles project into one line seen from in front: only its end tells them apart).
    On the shipped panel, a valve's bar: 0.06-0.11 m (clear of its 0.04 m hub, 0.12 m long), past
    at 0.135 and 0.15 m; a lever's shaft: 0.08-0.19 m, past its end (0.22 m) at 0.235 and 0.25 m."""
    if valve:
        end_m = panel.valve.bar_m[2]
        return np.linspace(panel.valve.hub_m[0] + 0.02, end_m - 0.01, 6), end_m + np.array([0.015, 0.03])
    length_m = panel.lever.length_m
    end_m = length_m + panel.handle_thickness_m / 2
    return np.linspace(0.4 * length_m, length_m - 0.01, 8), end_m + np.array([0.015, 0.03])


SWATCH_M = 0.025  # the part's own colour, sampled within this of its pivot (hub, shaft root)
ANGLE_STEP_RAD = np.radians(0.5)
MIN_CONTRAST = 0.25  # a peak that stands less above the other angles' scores is no measurement


@dataclass(frozen=True)
class PartAngle:
    """A part's angle measured in one image [rad, about its axis, from rest] and its confidence."""

    angle_rad: float
    confidence: float


def _seen(
    rgb: np.ndarray, camera_matrix: np.ndarray, pose_camera_in_world: np.ndarray, points_m_world: np.ndarray
) -> np.ndarray:
    """The image's colours where the points project (nearest pixel), NaN outside the image."""
    in_camera = (points_m_world - pose_camera_in_world[:3]) @ rotation_of(pose_camera_in_world[3:])
    uvw = in_camera @ camera_matrix.T
    uv = np.round(uvw[..., :2] / np.maximum(uvw[..., 2:], 1e-6)).astype(int)
    h, w = rgb.shape[:2]
    inside = (uv[..., 0] >= 0) & (uv[..., 0] < w) & (uv[..., 1] >= 0) & (uv[..., 1] < h) & (uvw[..., 2] > 0)
    out = np.full((*uv.shape[:-1], 3), np.nan)
    out[inside] = rgb[uv[..., 1][inside], uv[..., 0][inside]]
    return out


def _lobe(above: np.ndarray, peak: int, period: int | None) -> np.ndarray:
    """The indices of the run of `above` that holds `peak` (wrapping round with a period)."""
    n, run = len(above), [peak]
    for step in (-1, 1):
        k = peak + step
        while len(run) < n and (0 <= k < n or period) and above[k % n]:
            run.append(k % n)
            k += step
    return np.array(sorted(set(run)))


def _handle_points(
    panel: Panel, valve: bool, angles: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each candidate angle, the points along the handle from the pivot [m, panel] (on it,
    then past its end) with their signs in the score, and the swatch of the part's own colour."""
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    on, past = handle_samples_m(panel, valve)
    r = np.r_[on, past]
    sign = np.r_[np.full(len(on), 1.0 / len(on)), np.full(len(past), -1.0 / len(past))]
    if not valve:  # the shaft out of the face, thrown about the panel's y (positive: up)
        offsets = np.stack(np.broadcast_arrays(-r * c, 0 * r, r * s), axis=-1)
        return offsets, np.array([[-x, 0.0, 0.0] for x in np.linspace(0.005, 0.02, 5)]), sign  # at any throw
    # the bar across the spindle, both arms, on its front face
    bar_front_m = panel.valve.bar_m[0] + panel.valve.bar_m[1]
    r, sign = np.r_[r, -r], np.r_[sign, sign] / 2
    offsets = np.stack(np.broadcast_arrays(-bar_front_m + 0 * r, r * c, r * s), axis=-1)
    grid = np.linspace(-SWATCH_M, SWATCH_M, 5)
    swatch = np.stack([np.full(25, -bar_front_m), *(g.ravel() for g in np.meshgrid(grid, grid))], axis=1)
    return offsets, swatch, sign


def part_angles(
    panel: Panel,
    rgb: np.ndarray,
    camera_matrix: np.ndarray,
    pose_camera_in_world: np.ndarray,
    panel_pose: Pose,
) -> dict[str, PartAngle]:
    """Each valve's bar and each lever's shaft found in the image, where the panel's pose puts
    them: candidate angles over the part's range are projected, and the one whose handle's
    pixels are most like the part's own colour (sampled around its pivot), and the pixels past
    its end least, wins; refined as the score-weighted mean of its lobe (the handle is as wide
    as several candidates). A part out of view, hidden (the arm in front of it) or
    not standing out of its background is left out."""
    found = {}
    for name in (*panel.valves, *panel.levers):
        pivot = np.asarray(panel.valves.get(name) or panel.levers[name])
        valve = panel.part_kind(name) == "valve"
        lo, hi = panel.valve.range_rad if valve else panel.lever.range_rad
        margin = 0.0 if valve else np.radians(5.0)
        angles = np.arange(lo - margin, hi + margin + 1e-9, ANGLE_STEP_RAD)
        offsets, swatch, sign = _handle_points(panel, valve, angles)
        colours, own = (
            _seen(
                rgb,
                camera_matrix,
                pose_camera_in_world,
                (pivot + q) @ panel_pose.rotation.T + panel_pose.position_m_world,
            )
            for q in (offsets, swatch)
        )
        if np.isnan(colours).any() or np.isnan(own).any():
            continue  # not all in view
        reference = np.median(own, axis=0)
        spread = max(20.0, float(np.median(np.linalg.norm(own - reference, axis=1))) * 3)
        likeness = np.exp(-0.5 * (np.linalg.norm(colours - reference, axis=-1) / spread) ** 2)
        score = likeness @ sign
        best, floor = int(np.argmax(score)), float(np.median(score))
        contrast = float(score[best]) - floor
        if contrast < MIN_CONTRAST:
            continue
        # the handle is as wide as a few degrees of candidates: its lobe's centre, not its peak
        period = len(angles) if valve else None  # a bar's angles wrap at half a turn
        lobe = _lobe(score > floor + contrast / 2, best, period)
        weights = score[lobe] - floor
        if valve:  # a circular mean of the doubled angles (the bar at a and a + 180 deg is one)
            doubled = weights @ np.exp(2j * angles[lobe])
            angle = float(np.angle(doubled) / 2)
        else:
            angle = float(weights @ angles[lobe] / weights.sum())
        angle = float(np.clip(angle, lo, hi))
        pivot_m_world = panel_pose.rotation @ pivot + panel_pose.position_m_world
        distance_m = float(np.linalg.norm(pivot_m_world - pose_camera_in_world[:3]))
        handle_m = panel.valve.bar_m[2] if valve else panel.lever.length_m
        found[name] = PartAngle(angle, angle_confidence(contrast, distance_m, handle_m, valve))
    return found


# a handle of the shipped valve panel's (its valves' 0.12 m bars, its levers' 0.2 m shafts) is read
# as well as it gets from NEAR_M, another in proportion to its length [m]
HANDLE_M = {True: 0.12, False: 0.2}


def angle_confidence(contrast: float, distance_m: float, handle_m: float, valve: bool) -> float:
    """A handle's angle's confidence, from its score's contrast: a pixel is an angle that grows
    with the distance and shrinks with the handle's length, weighed as an inverse variance (seen
    from 4 m as the mission's intent is resolved, the shipped panel's bar was 4.5 deg off, and the
    grasp made on it turned the valve to 82 deg; the small panel's half-length bar, 6.3 deg off
    from 1.3 m, to 83.7)."""
    near_m = NEAR_M * handle_m / HANDLE_M[valve]
    return float(min(1.0, contrast) * min(1.0, (near_m / distance_m) ** 2))


def seen_angles(panel: Panel, objects: RecognisedObjects) -> dict[str, PartAngle]:
    """The parts' angles measured in the image, as RecognisedObjects carries them (each part's
    rotation from the panel's, about its axis), those measured only."""
    panel_rotation = rotation_of(objects.poses_world[objects.names.index("panel"), 3:])
    found = {}
    for name, pose, confidence in zip(objects.names, objects.poses_world, objects.confidences, strict=True):
        if name == "panel" or confidence <= 0.0:
            continue
        axis = np.asarray(
            panel.valve.axis_panel if panel.part_kind(name) == "valve" else panel.lever.axis_panel
        )
        turn = panel_rotation.T @ rotation_of(pose[3:])
        found[name] = PartAngle(float(axis @ cv2.Rodrigues(turn)[0].ravel()), float(confidence))
    return found


CONFIDENCE_GAIN = 0.3  # of each frame's confidence in the tracker's: the last few frames' say
# The panel does not move, but the frame its estimates are placed in does: each frame is placed
# with the camera's pose from onboard's navigation, whose error wanders (dead reckoning between
# USBL fixes) by millimetres a second, and the arm reaches for the panel with the same
# navigation. What a grasp needs is the panel where the navigation places it now. Measured on the
# default mission (seed 2): frames at working distance 1-2 mm apart once the navigation's error
# at their moment is taken out, that error moving 10-15 mm in 10 s; an average with a fixed
# memory of some 40 frames put the grasp 9-15 mm off the handle, and the fingers slipped off the
# bar and closed on nothing. So the average's weight (the confidences summed, an inverse
# variance) forgets as a random walk: its variance grows by this much per second of frames.
NAV_DRIFT_PER_S = 10.0


class PanelTracker:
    """The panel's pose over frames: each frame's fused estimate joins a running
    confidence-weighted average that forgets at NAV_DRIFT_PER_S, so that close in it follows
    the navigation's frame. Its confidence follows the recent frames' (an exponential average),
    and fades while frames find nothing: what murk or a lost camera does shows."""

    def __init__(
        self,
        panel: Panel,
        expected_m_world: np.ndarray | None = None,
        bias_m_world: tuple[float, float, float] = (0.0, 0.0, 0.0),
        expected_rotation: np.ndarray | None = None,
    ) -> None:
        self.panel = panel
        # where a shape with no marker in view is first looked for (by_plane), and how it faces
        # there: the site package's pose unless told (`expected_pose`, in a hybrid run)
        self.expected_m_world = np.array(
            self.panel.position_m_world if expected_m_world is None else expected_m_world
        )
        self.expected_rotation = None if expected_rotation is None else np.array(expected_rotation, float)
        if self.expected_rotation is not None:
            self.expected_rotation.setflags(write=False)
        self.bias_m_world = np.asarray(bias_m_world, float)  # a fault: added to what is reported
        self.estimate: Pose | None = None
        self.weight = 0.0
        self.anchored = False  # the estimate has seen markers: the shape alone slides along the face
        self.method = ""
        self.frame_s: float | None = None  # the sim time of the last image in the average
        self.angles: dict[str, PartAngle] = {}  # the parts' angles the last frame with markers measured

    def update(
        self, rgb: np.ndarray | None, image: Image | None, points_m_world: np.ndarray | None
    ) -> Pose | None:
        """One frame: the image (with its camera's pose in the world) and the latest cloud."""
        texture = shape = None
        if rgb is not None and image is not None:
            matrix = np.array([[image.fx_px, 0, image.cx_px], [0, image.fy_px, image.cy_px], [0, 0, 1.0]])
            texture = by_texture(self.panel, rgb, matrix, image.pose_camera)
        if points_m_world is not None and len(points_m_world):
            guess = (
                texture
                or self.estimate
                or by_plane(points_m_world, self.expected_m_world, self.expected_rotation)
            )
            if guess is not None:
                shape = by_shape(self.panel, points_m_world, guess)
        if texture is not None and shape is not None:
            frame = fuse_texture_shape(texture, shape)
        elif texture is not None:
            frame = texture
        elif shape is not None and self.estimate is not None:
            # ICP slides along the face: the shape alone corrects the normal and the depth only
            so_far = Pose(self.estimate.rotation, self.estimate.position_m_world, 0.0)
            frame = fuse_texture_shape(so_far, shape)
        elif shape is not None:
            frame = shape
        else:  # nothing seen: the estimate stands, believed less
            if self.estimate is not None:
                self.estimate = Pose(
                    self.estimate.rotation,
                    self.estimate.position_m_world,
                    (1.0 - CONFIDENCE_GAIN) * self.estimate.confidence,
                )
            return self.estimate
        self.method = "+".join(name for name, p in (("texture", texture), ("shape", shape)) if p is not None)
        forget_s = 0.0
        if image is not None:
            forget_s = max(0.0, image.sim_time_s - (self.frame_s or image.sim_time_s))
            self.frame_s = max(self.frame_s or 0.0, image.sim_time_s)
        if self.estimate is None or (texture is not None and not self.anchored):
            self.anchored = texture is not None
            self.estimate, self.weight = frame, frame.confidence
        else:
            kept = 1.0 / (1.0 / max(self.weight, 1e-9) + NAV_DRIFT_PER_S * forget_s)
            total = kept + frame.confidence
            blended = fuse(
                [
                    Pose(self.estimate.rotation, self.estimate.position_m_world, kept / total),
                    Pose(frame.rotation, frame.position_m_world, frame.confidence / total),
                ]
            )
            before = self.estimate.confidence
            confidence = before + CONFIDENCE_GAIN * (frame.confidence - before)
            self.estimate = Pose(blended.rotation, blended.position_m_world, confidence)
            self.weight = total
        if texture is not None and rgb is not None and image is not None:
            self.angles = part_angles(self.panel, rgb, matrix, image.pose_camera, self.estimate)
        else:  # the parts are placed by the markers: none seen, none measured
            self.angles = {}
        return self.estimate

    def objects(self, sim_time_s: float) -> RecognisedObjects | None:
        """The panel, its valves and its levers as recognised objects."""
        if self.estimate is None:
            return None
        pose = Pose(
            self.estimate.rotation,
            self.estimate.position_m_world + self.bias_m_world,
            self.estimate.confidence,
        )
        names, poses, sizes = ["panel"], [pose.as_vector()], [self.panel.plate_half_size_m]
        half_thickness_m = self.panel.handle_thickness_m / 2
        confidences = [pose.confidence]
        for name, pivot in (*self.panel.valves.items(), *self.panel.levers.items()):
            # a valve's box holds its handle at any angle; a lever's is its shaft at rest, turned
            # with it about the pivot by the angle measured (at rest, confidence 0: not measured)
            valve = self.panel.part_kind(name) == "valve"
            measured = self.angles.get(name, PartAngle(0.0, 0.0))
            turn = rotation_about(
                np.asarray(self.panel.valve.axis_panel if valve else self.panel.lever.axis_panel),
                measured.angle_rad,
            )
            if valve:
                centre, half_size = np.asarray(pivot), (0.04, 0.12, 0.12)
            else:
                centre = np.asarray(pivot) - turn @ (self.panel.lever.length_m / 2, 0.0, 0.0)
                half_size = (
                    self.panel.lever.length_m / 2 + half_thickness_m,
                    half_thickness_m,
                    half_thickness_m,
                )
            names.append(name)
            rotation = pose.rotation @ turn
            poses.append(np.r_[pose.rotation @ centre + pose.position_m_world, quat_wxyz_of(rotation)])
            sizes.append(half_size)
            confidences.append(measured.confidence)
        return RecognisedObjects(
            names=tuple(names),
            poses_world=np.array(poses),
            half_sizes_m=np.array(sizes),
            confidences=np.array(confidences),
            method=self.method,
            sim_time_s=sim_time_s,
        )
