"""The valve panel as recognition knows it: the plate, its markers, its valves and levers, in
the panel's frame (x out of the back of the plate, y left, z up; origin at the plate's centre).
world.xml places the same panel; tests/test_model.py checks that the two agree, and that the
face texture in `panel_face.png` is the one `face_texture()` draws.

The face towards the vehicle (x = -PLATE_HALF_SIZE_M[0]) carries ArUco markers (DICT_4X4_50)
clear of the valves and levers, on a checkerboard that gives stereo matching texture to hold on
to: four large ones in its corners (ids 0-3), seen from metres away, and two small ones between
the valves (ids 4, 5), which stay in the cameras' view from where the arm works the panel (the
corners are then at the image's edges or beyond)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from abyss.common.errors import BadInput
from abyss.common.models import MODELS_DIR

PANEL_POSITION_M_WORLD = (5.0, 0.0, -8.6)  # the panel's frame is the world's, translated
PLATE_HALF_SIZE_M = (0.05, 0.8, 0.6)
FACE_TEXTURE_FILE = MODELS_DIR / "panel_face.png"
TEXTURE_PX_PER_M = 400
MARKER_DICTIONARY = "DICT_4X4_50"
MARKER_MARGIN_M = 0.015  # white quiet zone around each
CHECKER_SQUARE_M = 0.2
# marker id -> centre (y, z) on the face and side of the black square [m]
MARKERS: dict[int, tuple[float, float, float]] = {
    0: (0.635, 0.445, 0.27),
    1: (-0.635, 0.445, 0.27),
    2: (-0.635, -0.445, 0.27),
    3: (0.635, -0.445, 0.27),
    4: (0.25, 0.47, 0.14),
    5: (-0.25, 0.47, 0.14),
}
# the parts an operator works, their centres in the panel's frame [m]
VALVES: dict[str, tuple[float, float, float]] = {
    "valve_0": (-0.07, 0.5, 0.25),
    "valve_1": (-0.07, 0.0, 0.25),
    "valve_2": (-0.07, -0.5, 0.25),
}
LEVERS: dict[str, tuple[float, float, float]] = {  # the pivot
    "lever_0": (-0.07, 0.3, -0.3),
    "lever_1": (-0.07, -0.3, -0.3),
}

# -- how the parts are worked (world.xml's joints; tests/common/test_model.py holds the two equal)
# A valve is a quarter-turn valve: a bar handle across its spindle, turned about the panel's x
# (positive: right-handed about x, i.e. anticlockwise as the vehicle sees it) between stops at
# +-90 degrees. A lever is a shaft standing straight out of the face, thrown about the panel's y
# between stops at +-45 degrees (positive: up), and resting in the middle, as a directional
# control valve's does. Both start at 0.
VALVE_AXIS_PANEL = (1.0, 0.0, 0.0)
LEVER_AXIS_PANEL = (0.0, 1.0, 0.0)
VALVE_RANGE_RAD = (-np.pi / 2, np.pi / 2)
LEVER_RANGE_RAD = (-np.pi / 4, np.pi / 4)
LEVER_LENGTH_M = 0.2
HANDLE_THICKNESS_M = 0.04  # the valve's bar and the lever's shaft, across: what the fingers close on
# where the tool point grasps each, at rest, from its pivot: the fingers (0.08 m long, their tips
# 0.02 m beyond the tool point, the palm behind them) reach 12.5 mm over the bar (its front 30 mm
# deep, 15 to 45 mm out of the pivot) and stop 12.5 mm short of the spindle's hub (20 mm out),
# the middle of what the depth may be off either way: at 5 mm short, and at 10 mm under the
# satellite storm's late refinements, they caught the hub's 80 mm when the recognition and the
# navigation were 1-2 cm off; at 10 mm over, the fingers slid off the bar as the navigation's
# frame moved 5 mm out during a turn (seed 2); on a lever they hold the shaft's outer part, the
# palm clear beyond its end
VALVE_GRASP_M_PIVOT = (-0.0525, 0.0, 0.0)
LEVER_GRASP_M_PIVOT = (-0.175, 0.0, 0.0)
# the tool at the grasp, at rest: its x (the approach) into the panel, its y (the fingers' closing
# direction) up, across the bar and the shaft: a roll of 90 degrees about x
GRASP_ROTATION_PANEL = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def part_kind(name: str) -> str:
    """ "valve" or "lever"; ValueError with the names there are for another."""
    if name in VALVES:
        return "valve"
    if name in LEVERS:
        return "lever"
    raise BadInput(f"{name!r} is not a part of the panel: {', '.join((*VALVES, *LEVERS))}")


def intent(name: str, amount: str) -> tuple[float, str]:
    """An operator's intent on a part as the messages carry it: (turn [rad], "") for a valve
    and an angle [deg], (0, stop) for a lever and "up" or "down"; BadInput says what is allowed."""
    if part_kind(name) == "lever":
        if amount not in ("up", "down"):
            raise BadInput(f"{name} is a lever: it is thrown up or down, not {amount!r}")
        return 0.0, amount
    try:
        turn_deg = float(amount)
    except ValueError:
        turn_deg = float("nan")
    if not -180.0 <= turn_deg <= 180.0 or turn_deg == 0.0:
        raise BadInput(f"{name} is a valve: it is turned by an angle in [-180, 180] deg, not {amount!r}")
    return float(np.radians(turn_deg)), ""


def part_range_rad(name: str) -> tuple[float, float]:
    return VALVE_RANGE_RAD if part_kind(name) == "valve" else LEVER_RANGE_RAD


def part_geometry(name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A part's pivot [m] and rotation axis in the panel's frame, and the tool point's grasp
    from the pivot at rest [m, panel]."""
    if part_kind(name) == "valve":
        return np.array(VALVES[name]), np.array(VALVE_AXIS_PANEL), np.array(VALVE_GRASP_M_PIVOT)
    return np.array(LEVERS[name]), np.array(LEVER_AXIS_PANEL), np.array(LEVER_GRASP_M_PIVOT)


def marker_corners_m_panel(marker_id: int) -> np.ndarray:
    """The marker's four corners in ArUco's order (top left, top right, bottom right, bottom
    left, as seen facing the panel) in the panel's frame [m]."""
    y, z, side = MARKERS[marker_id]
    h = side / 2
    x = -PLATE_HALF_SIZE_M[0]
    # facing the panel (looking along +x), image right is -y and image down is -z
    return np.array([[x, y + h, z + h], [x, y - h, z + h], [x, y - h, z - h], [x, y + h, z - h]])


def face_texture() -> np.ndarray:
    """The face as a grey image, row 0 at the top (z = +half height), column 0 at y = +half width."""
    import cv2

    width_px = round(2 * PLATE_HALF_SIZE_M[1] * TEXTURE_PX_PER_M)
    height_px = round(2 * PLATE_HALF_SIZE_M[2] * TEXTURE_PX_PER_M)
    square_px = round(CHECKER_SQUARE_M * TEXTURE_PX_PER_M)
    rows, cols = np.mgrid[0:height_px, 0:width_px]
    image = np.where((rows // square_px + cols // square_px) % 2 == 0, 235, 30).astype(np.uint8)
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, MARKER_DICTIONARY))
    margin_px = round(MARKER_MARGIN_M * TEXTURE_PX_PER_M)
    for marker_id, (y, z, side) in MARKERS.items():
        side_px = round(side * TEXTURE_PX_PER_M)
        col = round((PLATE_HALF_SIZE_M[1] - y) * TEXTURE_PX_PER_M) - side_px // 2
        row = round((PLATE_HALF_SIZE_M[2] - z) * TEXTURE_PX_PER_M) - side_px // 2
        image[row - margin_px : row + side_px + margin_px, col - margin_px : col + side_px + margin_px] = 255
        image[row : row + side_px, col : col + side_px] = cv2.aruco.generateImageMarker(
            dictionary, marker_id, side_px
        )
    return image


def write_face_texture(path: Path = FACE_TEXTURE_FILE) -> None:
    """The file MuJoCo reads: mirrored left to right, as MuJoCo maps a 2D texture onto a box's
    -x face seen from outside mirrored."""
    import cv2

    cv2.imwrite(str(path), np.ascontiguousarray(face_texture()[:, ::-1]))
