"""Imaging sonar frames (messages.SonarImage) on the wire and in space: the polar image encoded
and decoded, each beam's first echo as a range and a bearing, the arc of points in the world it
may lie on (a forward-looking sonar measures no elevation: an echo at range r comes from
somewhere on the arc of radius r across the vertical aperture, as sonar occupancy maps since
Elfes' have drawn it), and the fan in Cartesian form for a viewer."""

from __future__ import annotations

import math

import cv2
import numpy as np

from abyss.common.errors import BadInput
from abyss.common.geometry import rotation_of
from abyss.interface.messages import SonarImage

ECHO_MIN_DB = -15.0  # an echo this strong (0 dB: a wall square on) is a surface
ECHO_RGB = (255, 170, 0)  # what the sonar found, as the scene model and the viewer colour it


def encode_polar(polar: np.ndarray, encoding: str, jpeg_quality: int = 80) -> bytes:
    """A polar image (bins x beams, uint8) as PNG (lossless: what the sonar sent) or JPEG."""
    if encoding == "png8":
        ok, buffer = cv2.imencode(".png", polar)
    else:
        ok, buffer = cv2.imencode(".jpg", polar, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
    if not ok:
        raise RuntimeError(f"OpenCV could not encode a {encoding} sonar image")
    return buffer.tobytes()


def decode_polar(sonar: SonarImage) -> np.ndarray:
    """The polar image (bins x beams, uint8); BadInput if the bytes are not one of that size."""
    buffer = np.frombuffer(sonar.data, np.uint8)
    polar = cv2.imdecode(buffer, cv2.IMREAD_GRAYSCALE) if len(buffer) else None
    if polar is None or polar.shape != (sonar.bins, sonar.beams):
        got = "nothing" if polar is None else f"{polar.shape}"
        raise BadInput(
            f"{sonar.sonar}: {sonar.encoding} data decodes to {got}, expected ({sonar.bins}, {sonar.beams})"
        )
    return polar


def bearings_rad(sonar: SonarImage) -> np.ndarray:
    """Each beam's bearing from the middle beam, port (positive) to starboard."""
    half = sonar.horizontal_fov_rad / 2
    return np.linspace(half, -half, sonar.beams)


def level_of_db(sonar: SonarImage, db: float) -> int:
    """The grey level of an echo `db` decibels from a square-on wall's (0 dB)."""
    return int(np.clip(round(255.0 * (db + sonar.dynamic_range_db) / sonar.dynamic_range_db), 0, 255))


def first_echoes(sonar: SonarImage, polar: np.ndarray, min_db: float) -> tuple[np.ndarray, np.ndarray]:
    """Per beam with an echo at least `min_db` strong: its range [m] (the bin's middle) and
    bearing [rad]. The first echo is the nearest surface; what lies behind it is shadowed."""
    strong = polar >= level_of_db(sonar, min_db)
    beams = np.flatnonzero(strong.any(axis=0))
    bins = strong[:, beams].argmax(axis=0)
    return (bins + 0.5) * sonar.range_max_m / sonar.bins, bearings_rad(sonar)[beams]


def arc_points(
    sonar: SonarImage, range_m: np.ndarray, bearing_rad: np.ndarray, spacing_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """The arcs the echoes may lie on, points `spacing_m` apart across the vertical aperture, in
    the sonar's pose frame; with the sonar's position there (where every ray begins)."""
    half = sonar.vertical_aperture_rad / 2
    arcs = []
    for r, bearing in zip(range_m, bearing_rad, strict=True):
        count = max(2, math.ceil(r * sonar.vertical_aperture_rad / spacing_m) + 1)
        elevation = np.linspace(-half, half, count)
        arcs.append(
            r
            * np.column_stack(
                (
                    np.cos(elevation) * math.cos(bearing),
                    np.cos(elevation) * math.sin(bearing),
                    np.sin(elevation),
                )
            )
        )
    local = np.concatenate(arcs) if arcs else np.zeros((0, 3))
    rotation, origin = rotation_of(sonar.pose_sonar[3:]), np.array(sonar.pose_sonar[:3])
    return local @ rotation.T + origin, origin


def echo_arcs(
    sonar: SonarImage, spacing_m: float, min_db: float = ECHO_MIN_DB
) -> tuple[np.ndarray, np.ndarray]:
    """Each beam's first echo as the arc it may lie on [m, world], and the sonar's position;
    BadInput if the frame does not decode or is not placed in the world."""
    if sonar.pose_frame != "world":
        raise BadInput(f"{sonar.sonar}: pose in the {sonar.pose_frame} frame, expected the world's")
    range_m, bearing_rad = first_echoes(sonar, decode_polar(sonar), min_db)
    return arc_points(sonar, range_m, bearing_rad, spacing_m)


def fan(sonar: SonarImage, polar: np.ndarray, height_px: int = 256) -> np.ndarray:
    """The polar image drawn as the fan it covers, seen from above (uint8, the sonar at the
    bottom middle, its middle beam up, port on the left); black outside the fan."""
    half = sonar.horizontal_fov_rad / 2
    width_px = 2 * math.ceil(height_px * max(math.sin(min(half, math.pi / 2)), 0.05))
    rows, cols = np.mgrid[0:height_px, 0:width_px].astype(np.float32)
    ahead, port = (height_px - rows) / height_px, (width_px / 2 - cols) / height_px
    range_fraction = np.hypot(ahead, port)
    bearing = np.arctan2(port, ahead)
    map_y = range_fraction * sonar.bins - 0.5
    map_x = (half - bearing) / (2 * half) * (sonar.beams - 1) if sonar.beams > 1 else np.zeros_like(bearing)
    outside = (range_fraction > 1.0) | (np.abs(bearing) > half)
    map_x[outside] = map_y[outside] = -10.0
    return cv2.remap(
        polar,
        map_x.astype(np.float32),
        map_y.astype(np.float32),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0,
    )
