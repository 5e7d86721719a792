"""A work site's panel as data (a site package's `[panel]`: description/site.py): the plate, its
markers, its parts (valves and levers), in the panel's frame (x out of the back of the plate,
y left, z up; origin at the plate's centre). The simulation builds the panel's bodies from the same
numbers recognition knows it by (`build`), so the two cannot differ.

The face towards the vehicle (x = -plate_half_size_m[0]) carries ArUco markers clear of the
parts, on a checkerboard that gives stereo matching texture to hold on to; `face_texture` draws
it, and the site's texture file is held equal to that by a test."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np

from abyss.common.errors import BadInput

if TYPE_CHECKING:
    import mujoco

Vector3 = tuple[float, float, float]
# the tool at the grasp, at rest: its x (the approach) into the panel, its y (the fingers' closing
# direction) up, across the bar and the shaft: a roll of 90 degrees about x
GRASP_ROTATION_PANEL = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
GRASP_ROTATION_PANEL.flags.writeable = False


def intent_of(amount: str) -> tuple[float, str]:
    """An operator's intent on a part as the messages carry it: (turn [rad], "") for an angle
    [deg] (a valve's), (0, stop) for "up" or "down" (a lever's); BadInput says what is allowed.
    Which kind the part is, the vessel checks against the panel it knows (Panel.intent)."""
    if amount in ("up", "down"):
        return 0.0, amount
    try:
        turn_deg = float(amount)
    except ValueError:
        turn_deg = float("nan")
    if not -180.0 <= turn_deg <= 180.0 or turn_deg == 0.0:
        raise BadInput(
            f"a valve is turned by an angle in [-180, 180] deg and a lever thrown up or down, not {amount!r}"
        )
    return float(np.radians(turn_deg)), ""


@dataclass(frozen=True)
class KindSection:
    """How a kind of part is worked and shaped: its axis in the panel's frame, its stops, where the
    tool point grasps it at rest from its pivot, its joint's friction, damping and armature."""

    axis_panel: Vector3
    range_deg: tuple[float, float]
    grasp_m_pivot: Vector3
    friction_n_m: float
    damping_n_m_s: float
    armature_kg_m2: float
    hub_m: tuple[float, float] = (0.0, 0.0)  # a valve's spindle hub: radius, half length [m]
    bar_m: Vector3 = (0.0, 0.0, 0.0)  # a valve's bar: centre out of the pivot, half depth, half length [m]
    length_m: float = 0.0  # a lever's shaft [m]

    @property
    def range_rad(self) -> tuple[float, float]:
        return (float(np.radians(self.range_deg[0])), float(np.radians(self.range_deg[1])))


@dataclass(frozen=True)
class PartSection:
    name: str
    kind: Literal["valve", "lever"]
    pivot_m_panel: Vector3
    rgba: tuple[float, float, float, float] = (0.8, 0.8, 0.8, 1.0)


@dataclass(frozen=True)
class Panel:
    """A site's panel: where it stands, its plate and legs, its markers, its parts."""

    position_m_world: Vector3  # the panel's frame is the world's, translated
    plate_half_size_m: Vector3
    legs_m_panel: tuple[tuple[float, float, float, float, float, float], ...]  # centre, half sizes
    face_texture: str  # the face's image, in the site package (drawn by `face_texture()`)
    texture_px_per_m: int
    marker_dictionary: str
    marker_margin_m: float
    checker_square_m: float
    markers: tuple[tuple[int, float, float, float], ...]  # id, centre y, z on the face, side [m]
    handle_thickness_m: float  # the valve's bar and the lever's shaft, across
    valve: KindSection
    lever: KindSection
    parts: tuple[PartSection, ...]

    @cached_property
    def valves(self) -> dict[str, Vector3]:
        """The valves' pivots in the panel's frame [m], by name."""
        return {p.name: p.pivot_m_panel for p in self.parts if p.kind == "valve"}

    @cached_property
    def levers(self) -> dict[str, Vector3]:
        """The levers' pivots in the panel's frame [m], by name."""
        return {p.name: p.pivot_m_panel for p in self.parts if p.kind == "lever"}

    @property
    def part_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parts)

    @cached_property
    def marker_table(self) -> dict[int, tuple[float, float, float]]:
        """marker id -> centre (y, z) on the face and side of the black square [m]"""
        return {int(i): (y, z, side) for i, y, z, side in self.markers}

    def part_kind(self, name: str) -> str:
        """ "valve" or "lever"; BadInput with the names there are for another."""
        for part in self.parts:
            if part.name == name:
                return part.kind
        raise BadInput(f"{name!r} is not a part of the panel: {', '.join(self.part_names)}")

    def kind_of(self, name: str) -> KindSection:
        return self.valve if self.part_kind(name) == "valve" else self.lever

    def intent(self, name: str, amount: str) -> tuple[float, str]:
        """`intent_of(amount)`, checked against the part's kind: BadInput says what is allowed."""
        kind = self.part_kind(name)
        if kind == "lever" and amount not in ("up", "down"):
            raise BadInput(f"{name} is a lever: it is thrown up or down, not {amount!r}")
        if kind == "valve" and amount in ("up", "down"):
            raise BadInput(f"{name} is a valve: it is turned by an angle in [-180, 180] deg, not {amount!r}")
        return intent_of(amount)

    def part_range_rad(self, name: str) -> tuple[float, float]:
        return self.kind_of(name).range_rad

    def part_geometry(self, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A part's pivot [m] and rotation axis in the panel's frame, and the tool point's grasp
        from the pivot at rest [m, panel]."""
        kind = self.kind_of(name)
        pivot = (self.valves | self.levers)[name]
        return np.array(pivot), np.array(kind.axis_panel), np.array(kind.grasp_m_pivot)

    def marker_corners_m_panel(self, marker_id: int) -> np.ndarray:
        """The marker's four corners in ArUco's order (top left, top right, bottom right, bottom
        left, as seen facing the panel) in the panel's frame [m]."""
        y, z, side = self.marker_table[marker_id]
        h = side / 2
        x = -self.plate_half_size_m[0]
        # facing the panel (looking along +x), image right is -y and image down is -z
        return np.array([[x, y + h, z + h], [x, y - h, z + h], [x, y - h, z - h], [x, y + h, z - h]])

    def face_texture_image(self) -> np.ndarray:
        """The face as a grey image, row 0 at the top (z = +half height), column 0 at y = +half width."""
        import cv2

        _, half_width_m, half_height_m = self.plate_half_size_m
        width_px = round(2 * half_width_m * self.texture_px_per_m)
        height_px = round(2 * half_height_m * self.texture_px_per_m)
        square_px = round(self.checker_square_m * self.texture_px_per_m)
        rows, cols = np.mgrid[0:height_px, 0:width_px]
        image = np.where((rows // square_px + cols // square_px) % 2 == 0, 235, 30).astype(np.uint8)
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.marker_dictionary))
        margin_px = round(self.marker_margin_m * self.texture_px_per_m)
        for marker_id, (y, z, side) in self.marker_table.items():
            side_px = round(side * self.texture_px_per_m)
            col = round((half_width_m - y) * self.texture_px_per_m) - side_px // 2
            row = round((half_height_m - z) * self.texture_px_per_m) - side_px // 2
            image[
                row - margin_px : row + side_px + margin_px, col - margin_px : col + side_px + margin_px
            ] = 255
            image[row : row + side_px, col : col + side_px] = cv2.aruco.generateImageMarker(
                dictionary, marker_id, side_px
            )
        return image

    def write_face_texture(self, path: Path) -> None:
        """The file MuJoCo reads: mirrored left to right, as MuJoCo maps a 2D texture onto a box's
        -x face seen from outside mirrored."""
        import cv2

        cv2.imwrite(str(path), np.ascontiguousarray(self.face_texture_image()[:, ::-1]))

    def build(self, spec: mujoco.MjSpec, texture_file: Path) -> None:
        """The panel's bodies added to a world's spec: the plate (its face textured from
        `texture_file`), the legs, each part on its joint (its weight compensated: a part's own
        weight does not turn it, only the arm does)."""
        import mujoco

        texture_2d = mujoco.mjtTexture.mjTEXTURE_2D
        spec.add_texture(
            name="panel_face",
            type=texture_2d,
            builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
            width=512,
            height=512,
            rgb1=[0.95, 0.95, 0.9],
            rgb2=[0.1, 0.1, 0.12],
            mark=mujoco.mjtMark.mjMARK_CROSS,
            markrgb=[0.9, 0.4, 0.1],
        )
        plate = spec.add_material(name="panel_face", specular=0.2, texrepeat=[4, 3])
        plate.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "panel_face"
        spec.add_texture(name="panel_markers", type=texture_2d, file=str(texture_file))
        face = spec.add_material(name="panel_markers", specular=0.1)
        face.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "panel_markers"
        body = spec.worldbody.add_body(name="panel", pos=self.position_m_world)
        box = mujoco.mjtGeom.mjGEOM_BOX
        hx, hy, hz = self.plate_half_size_m
        body.add_geom(name="panel_plate", type=box, size=[hx, hy, hz], material="panel_face")
        body.add_geom(
            name="panel_face", type=box, pos=[-hx - 0.0005, 0, 0], size=[0.0005, hy, hz],
            material="panel_markers", contype=0, conaffinity=0,
        )  # fmt: skip
        for side, leg in zip(("left", "right", *map(str, range(2, 99))), self.legs_m_panel, strict=False):
            body.add_geom(
                name=f"panel_leg_{side}", type=box, pos=leg[:3], size=leg[3:], rgba=[0.3, 0.3, 0.3, 1]
            )
        for part in self.parts:
            self._build_part(body, part, spec.compiler.degree)

    def _build_part(self, panel: mujoco.MjsBody, part: PartSection, degrees: bool) -> None:
        import mujoco

        kind = self.kind_of(part.name)
        range_ = kind.range_deg if degrees else kind.range_rad
        body = panel.add_body(name=part.name, pos=part.pivot_m_panel, gravcomp=1)
        body.add_joint(
            name=part.name, type=mujoco.mjtJoint.mjJNT_HINGE, axis=kind.axis_panel, range=range_,
            limited=mujoco.mjtLimited.mjLIMITED_TRUE, frictionloss=kind.friction_n_m,
            damping=kind.damping_n_m_s, armature=kind.armature_kg_m2,
        )  # fmt: skip
        half_thickness_m = self.handle_thickness_m / 2
        if part.kind == "valve":
            hub = body.add_geom(
                type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[kind.hub_m[0], kind.hub_m[1], 0], rgba=part.rgba
            )
            hub.alt.type, hub.alt.zaxis = mujoco.mjtOrientation.mjORIENTATION_ZAXIS, kind.axis_panel
            out_m, half_depth_m, half_length_m = kind.bar_m
            body.add_geom(
                type=mujoco.mjtGeom.mjGEOM_BOX, pos=[-out_m, 0, 0],
                size=[half_depth_m, half_length_m, half_thickness_m], rgba=part.rgba,
            )  # fmt: skip
        else:
            body.add_geom(
                type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=[0, 0, 0, -kind.length_m, 0, 0],
                size=[half_thickness_m, 0, 0], rgba=part.rgba,
            )  # fmt: skip
