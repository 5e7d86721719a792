"""Offscreen rendering of the vehicle's cameras. The GL backend is chosen before MuJoCo is
imported: MUJOCO_GL if set, else the first of EGL and OSMesa that renders a frame."""

from __future__ import annotations

import functools
import os
import subprocess
import sys
from dataclasses import dataclass

import numpy as np

from abyss.common.errors import AbyssError

BACKENDS = ("egl", "osmesa")
_PROBE = ("import mujoco; r = mujoco.Renderer(mujoco.MjModel.from_xml_string('<mujoco/>'), 8, 8); "
          "r.render(); r.close()")


class RenderingUnavailable(AbyssError):
    pass


@functools.cache
def choose_gl_backend() -> str:
    """Set MUJOCO_GL to a backend that works here; call before `import mujoco` renders."""
    if os.environ.get("MUJOCO_GL"):
        return os.environ["MUJOCO_GL"]
    errors = []
    for backend in BACKENDS:
        env = dict(os.environ, MUJOCO_GL=backend, PYOPENGL_PLATFORM=backend)
        done = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True,
                              timeout=60, check=False)
        if done.returncode == 0:
            os.environ["MUJOCO_GL"] = backend
            os.environ.setdefault("PYOPENGL_PLATFORM", backend)
            return backend
        errors.append(f"{backend}: {done.stderr.strip().splitlines()[-1] if done.stderr.strip() else '?'}")
    raise RenderingUnavailable(
        "no offscreen OpenGL backend works (" + "; ".join(errors) + "); install one with "
        "`apt-get install libegl1 libegl-mesa0` (EGL) or `apt-get install libosmesa6` (OSMesa), "
        "or set simulation.camera_rate_hz = 0 to run without cameras")


@dataclass(frozen=True)
class Intrinsics:
    width_px: int
    height_px: int
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float

    @staticmethod
    def from_fovy(width_px: int, height_px: int, fovy_deg: float) -> Intrinsics:
        """MuJoCo's cameras: vertical field of view, square pixels, centred principal point."""
        f = 0.5 * height_px / np.tan(np.radians(fovy_deg) / 2.0)
        return Intrinsics(width_px, height_px, f, f, width_px / 2.0, height_px / 2.0)

    def matrix(self) -> np.ndarray:
        return np.array([[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]])


class Cameras:
    """RGB for the stereo pair, depth [m along the optical axis] for the depth camera."""

    def __init__(self, model: object, width_px: int, height_px: int) -> None:
        import mujoco

        self.model = model
        self.renderer = mujoco.Renderer(model, height_px, width_px)
        self.depth_renderer = mujoco.Renderer(model, height_px, width_px)
        self.depth_renderer.enable_depth_rendering()
        for renderer in (self.renderer, self.depth_renderer):  # murky water: fog to the haze
            renderer.scene.flags[mujoco.mjtRndFlag.mjRND_FOG] = True
            renderer.scene.flags[mujoco.mjtRndFlag.mjRND_HAZE] = True
        self.blackout: set[str] = set()
        self.scene_option = mujoco.MjvOption()

    def intrinsics(self, camera: str) -> Intrinsics:
        return Intrinsics.from_fovy(self.renderer.width, self.renderer.height,
                                    float(self.model.camera(camera).fovy[0]))  # type: ignore[attr-defined]

    def pose_in_vehicle(self, camera: str) -> np.ndarray:
        """x, y, z [m] and quaternion w, x, y, z of the camera in its body's frame, with
        OpenCV's axes (x right, y down, z forward); MuJoCo's camera looks along -z, y up."""
        import mujoco

        cam = self.model.camera(camera)  # type: ignore[attr-defined]
        flip = np.array([0.0, 1.0, 0.0, 0.0])  # 180 degrees about x: y up -> down, -z -> z
        quat = np.empty(4)
        mujoco.mju_mulQuat(quat, cam.quat, flip)
        return np.r_[cam.pos, quat]

    def rgb(self, data: object, camera: str) -> np.ndarray:
        if camera in self.blackout:
            return np.zeros((self.renderer.height, self.renderer.width, 3), np.uint8)
        self.renderer.update_scene(data, camera=camera, scene_option=self.scene_option)
        return self.renderer.render().copy()

    def depth_m(self, data: object, camera: str) -> np.ndarray:
        if camera in self.blackout:
            return np.zeros((self.renderer.height, self.renderer.width), np.float32)
        self.depth_renderer.update_scene(data, camera=camera, scene_option=self.scene_option)
        return self.depth_renderer.render().astype(np.float32)

    def close(self) -> None:
        self.renderer.close()
        self.depth_renderer.close()
