"""Offscreen rendering of the vehicle's cameras. The GL backend is chosen before MuJoCo is
imported: MUJOCO_GL if set, else the first of EGL and OSMesa that renders a frame."""

from __future__ import annotations

import functools
import os
import subprocess
import sys
from typing import TYPE_CHECKING

import numpy as np

from abyss.common.errors import AbyssError
from abyss.common.geometry import Intrinsics

if TYPE_CHECKING:
    from abyss.stations.simulation.optics import Lamp, Optics

BACKENDS = ("egl", "osmesa")
_PROBE = (
    "import mujoco; r = mujoco.Renderer(mujoco.MjModel.from_xml_string('<mujoco/>'), 8, 8); "
    "r.render(); r.close()"
)


class RenderingUnavailable(AbyssError):
    pass


@functools.cache
def choose_gl_backend() -> str:
    """Set MUJOCO_GL to a backend that works here; call before MuJoCo's rendering is imported
    (it reads MUJOCO_GL then: imported first, it renders through GLFW, which needs a display)."""
    if os.environ.get("MUJOCO_GL"):
        return os.environ["MUJOCO_GL"]
    errors = []
    for backend in BACKENDS:
        env = dict(os.environ, MUJOCO_GL=backend, PYOPENGL_PLATFORM=backend)
        done = subprocess.run(
            [sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, timeout=60, check=False
        )
        if done.returncode == 0:
            os.environ["MUJOCO_GL"] = backend
            os.environ.setdefault("PYOPENGL_PLATFORM", backend)
            return backend
        errors.append(f"{backend}: {done.stderr.strip().splitlines()[-1] if done.stderr.strip() else '?'}")
    raise RenderingUnavailable(
        "no offscreen OpenGL backend works (" + "; ".join(errors) + "); install one with "
        "`apt-get install libegl1 libegl-mesa0` (EGL) or `apt-get install libosmesa6` (OSMesa), "
        "or set simulation.camera_rate_hz = 0 to run without cameras"
    )


class Cameras:
    """RGB for the stereo pair, depth [m along the optical axis] for the depth camera (the robot's
    `depth_camera`, which encoding.encode_image encodes as depth). With a
    `water` type (optics.WATER_TYPES), each RGB frame goes through the underwater optics, with
    its range from a depth render of the same camera, instead of MuJoCo's fog; the depth camera
    is a range sensor, which the water leaves alone.

    One renderer (one GL context) makes every pass, its offscreen buffer the frames' size rather
    than the model's offwidth x offheight (clearing and resolving that cost more than the frames'
    own pixels), with `samples` per pixel (simulation.camera_samples)."""

    def __init__(
        self,
        model: object,
        width_px: int,
        height_px: int,
        water: str = "none",
        marine_snow: float = 1.0,
        rng: np.random.Generator | None = None,
        samples: int = 4,
        *,
        depth_camera: str,
    ) -> None:
        """`depth_camera`: the robot's range camera (description.robot), rendered as depth."""
        import mujoco

        self.model = model
        self.depth_camera = depth_camera
        self.width_px, self.height_px = width_px, height_px
        visual, quality = model.vis.global_, model.vis.quality  # type: ignore[attr-defined]
        kept = visual.offwidth, visual.offheight, quality.offsamples
        # read as the renderer makes its buffer
        visual.offwidth, visual.offheight, quality.offsamples = width_px, height_px, samples
        try:
            self.renderer = mujoco.Renderer(model, height_px, width_px)
        finally:
            visual.offwidth, visual.offheight, quality.offsamples = kept
        self.renderer.scene.flags[mujoco.mjtRndFlag.mjRND_FOG] = (
            water == "none"
        )  # murky water: fog to the haze
        self.renderer.scene.flags[mujoco.mjtRndFlag.mjRND_HAZE] = water == "none"
        self.blackout: set[str] = set()
        self.scene_option = mujoco.MjvOption()
        self.water, self.marine_snow = water, marine_snow
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self._optics: dict[str, Optics] = {}

    def intrinsics(self, camera: str) -> Intrinsics:
        return Intrinsics.from_fovy(
            self.width_px,
            self.height_px,
            float(self.model.camera(camera).fovy[0]),  # type: ignore[attr-defined]
        )

    def pose_in_vehicle(self, camera: str) -> np.ndarray:
        """x, y, z [m] and quaternion w, x, y, z of the camera in its body's frame, with
        OpenCV's axes (x right, y down, z forward); MuJoCo's camera looks along -z, y up."""
        import mujoco

        cam = self.model.camera(camera)  # type: ignore[attr-defined]
        flip = np.array([0.0, 1.0, 0.0, 0.0])  # 180 degrees about x: y up -> down, -z -> z
        quat = np.empty(4)
        mujoco.mju_mulQuat(quat, cam.quat, flip)
        return np.r_[cam.pos, quat]

    def optics(self, camera: str) -> Optics | None:
        """The camera's underwater optics, made on first use; None without a water type."""
        from abyss.stations.simulation.optics import WATER_TYPES, Optics

        if self.water == "none":
            return None
        if camera not in self._optics:
            self._optics[camera] = Optics(
                WATER_TYPES[self.water],
                self.intrinsics(camera),
                lamps_of(self.model, camera),
                self.marine_snow,
            )
        return self._optics[camera]

    def plain_rgb(self, data: object, camera: str) -> np.ndarray:
        """MuJoCo's render, lit by the scene's lights, in air (or MuJoCo's fog without a water type)."""
        self.renderer.disable_depth_rendering()
        self.renderer.update_scene(data, camera=camera, scene_option=self.scene_option)
        return self.renderer.render()

    def rgb(self, data: object, camera: str) -> np.ndarray:
        if camera in self.blackout:
            return np.zeros((self.height_px, self.width_px, 3), np.uint8)
        optics = self.optics(camera)
        if optics is None:
            return self.plain_rgb(data, camera)
        from abyss.stations.simulation.optics import range_of_depth

        range_m = range_of_depth(self.depth_m(data, camera), self.intrinsics(camera))
        return optics.image(self.plain_rgb(data, camera), range_m, self.rng)

    def depth_m(self, data: object, camera: str) -> np.ndarray:
        """Depth [m along the optical axis], float32."""
        if camera in self.blackout:
            return np.zeros((self.height_px, self.width_px), np.float32)
        self.renderer.enable_depth_rendering()
        self.renderer.update_scene(data, camera=camera, scene_option=self.scene_option)
        return self.renderer.render()

    def close(self) -> None:
        self.renderer.close()


def lamps_of(model: object, camera: str) -> tuple[Lamp, ...]:
    """The spot lights on the camera's body, in the camera's frame (OpenCV axes)."""
    import mujoco

    from abyss.stations.simulation.optics import Lamp

    m = model
    cam = m.camera(camera)  # type: ignore[attr-defined]
    quat = np.empty(4)
    mujoco.mju_mulQuat(quat, cam.quat, np.array([0.0, 1.0, 0.0, 0.0]))  # as Cameras.pose_in_vehicle
    flat = np.empty(9)
    mujoco.mju_quat2Mat(flat, quat)
    rotation = flat.reshape(3, 3)  # camera axes to body axes
    lamps = []
    for i in range(m.nlight):  # type: ignore[attr-defined]
        if m.light_bodyid[i] != cam.bodyid[0] or m.light_type[i] != mujoco.mjtLightType.mjLIGHT_SPOT:  # type: ignore[attr-defined]
            continue
        lamps.append(
            Lamp(
                tuple((rotation.T @ (m.light_pos[i] - cam.pos)).tolist()),  # type: ignore[attr-defined]
                tuple((rotation.T @ m.light_dir[i]).tolist()),  # type: ignore[attr-defined]
                float(np.radians(m.light_cutoff[i])),  # type: ignore[attr-defined]
                float(m.light_exponent[i]),  # type: ignore[attr-defined]
            )
        )
    return tuple(lamps)
