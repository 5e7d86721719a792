"""What the cameras' rendering costs on this machine's GL backend: the render passes the simulation
makes per frame set (simulation.offload._Sensor through stations.simulation.encoding: RGB of
cam_left and cam_right, the depth of cam_depth; clear water, simulation.water "none", so no depth
pass for the optics), with rendering.Cameras as the sensor process builds it (the default
SimulationConfig: frame size, water, marine snow) for simulation.camera_samples 4 (the default) and
0, from the start pose (World's: SimulationConfig's start position and yaw, the arm stowed). Per
set: the wall time and the process's CPU time (time.process_time: every thread of it, a software
rasteriser's or a GL driver's included), the mean of SETS sets after WARMUP. JPEG/PNG encoding and
the state's mj_forward are left out: they cost the same on any GL backend.

Self-contained, for a machine where abyss is not installed: it imports numpy, mujoco (and PyOpenGL,
which mujoco's EGL and OSMesa contexts use, for the GL vendor string), cv2 (Cameras.rgb imports
stations/simulation/optics.py, even in clear water) and, of abyss, only stations/simulation/
rendering.py and optics.py, config/simulation.py (errors.py, fields.py) and description/models;
the packages' __init__ modules (the station, the bus: zenoh, msgpack, zstandard, cryptography)
are not run.
Where `abyss` is not importable as this checkout, a temporary folder with a link abyss -> the
repository goes first on sys.path.
Run: MUJOCO_GL=egl python3 bench/render_gpu.py [--sets N] [--warmup N] (MUJOCO_GL unset: the
simulation's own choice, rendering.choose_gl_backend). Prints one table; asserts nothing."""

from __future__ import annotations

import argparse
import atexit
import importlib.machinery
import importlib.util
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent


def _abyss_is_this_checkout() -> bool:
    try:
        import abyss
    except ImportError:
        return False
    return abyss.__file__ is not None and Path(abyss.__file__).resolve().parent == REPO


def _use_this_checkout() -> None:
    """`import abyss` as this repository (the packaging maps abyss to the repository's root)."""
    if os.environ.get("ABYSS_BENCH_LINK") != "1" and _abyss_is_this_checkout():
        return
    for name in [n for n in sys.modules if n == "abyss" or n.startswith("abyss.")]:
        del sys.modules[name]
    folder = tempfile.mkdtemp(prefix="abyss-path-")
    os.symlink(REPO, os.path.join(folder, "abyss"))
    atexit.register(shutil.rmtree, folder, True)  # the link itself, not the repository
    sys.path.insert(0, folder)
    import abyss

    assert Path(abyss.__file__).resolve().parent == REPO, abyss.__file__


def _bare_package(name: str, folder: Path) -> None:
    """The package's modules importable without running its __init__ (which pulls in the rest)."""
    if name in sys.modules:
        return
    spec = importlib.machinery.ModuleSpec(name, None, is_package=True)
    spec.submodule_search_locations = [str(folder)]
    sys.modules[name] = importlib.util.module_from_spec(spec)


_use_this_checkout()
_bare_package("abyss.stations", REPO / "stations")
_bare_package("abyss.stations.simulation", REPO / "stations" / "simulation")
_bare_package("abyss.config", REPO / "config")

from abyss.stations.simulation.rendering import Cameras, choose_gl_backend  # noqa: E402

BACKEND = choose_gl_backend()  # MUJOCO_GL, else the simulation's choice; before mujoco is imported

import mujoco  # noqa: E402

from abyss.config.simulation import SimulationConfig  # noqa: E402
from abyss.description.robot import place_at_start, robot_at  # noqa: E402
from abyss.description.site import site_at, world_model  # noqa: E402

ROBOT = robot_at("")  # the shipped robot package
CAMERAS = ROBOT.cameras
DEPTH_CAMERA = ROBOT.depth_camera  # encoding.encode_image: its depth; the others' RGB


def start_pose(model: mujoco.MjModel, sim: SimulationConfig) -> mujoco.MjData:
    """World's initial state (description.models.place_at_start)."""
    data = mujoco.MjData(model)
    place_at_start(model, data.qpos, ROBOT, sim.start_position_m_world, sim.start_yaw_rad)
    mujoco.mj_forward(model, data)
    return data


def frame_set(cameras: Cameras, data: mujoco.MjData) -> None:
    for camera in CAMERAS:
        if camera == DEPTH_CAMERA:
            cameras.depth_m(data, camera)
        else:
            cameras.rgb(data, camera)


def gl_strings() -> str:
    """The current context's GL_VENDOR / GL_RENDERER (PyOpenGL), or '?'."""
    try:
        from OpenGL import GL

        vendor, renderer = GL.glGetString(GL.GL_VENDOR), GL.glGetString(GL.GL_RENDERER)
        return f"{vendor.decode()} / {renderer.decode()}"
    except Exception as exc:  # a figure without its label beats none
        return f"? ({type(exc).__name__})"


def measure(
    model: mujoco.MjModel, data: mujoco.MjData, sim: SimulationConfig, samples: int, sets: int, warmup: int
):
    cameras = Cameras(
        model,
        sim.camera_width_px,
        sim.camera_height_px,
        sim.water,
        sim.marine_snow,
        np.random.default_rng(0),
        samples,
        depth_camera=DEPTH_CAMERA,
    )
    try:
        for _ in range(warmup):
            frame_set(cameras, data)
        gl = gl_strings()  # the renderer's context is current after a render
        wall, cpu = np.empty(sets), np.empty(sets)
        for i in range(sets):
            w0, c0 = time.perf_counter(), time.process_time()
            frame_set(cameras, data)
            wall[i], cpu[i] = time.perf_counter() - w0, time.process_time() - c0
    finally:
        cameras.close()
    return gl, wall, cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sets", type=int, default=50)
    parser.add_argument("--warmup", type=int, default=5)
    args = parser.parse_args()
    sim = SimulationConfig()
    model = world_model(ROBOT, site_at(""))
    data = start_pose(model, sim)
    print(
        f"python {platform.python_version()}, mujoco {mujoco.__version__}, MUJOCO_GL={BACKEND}, "
        f"{sim.camera_width_px}x{sim.camera_height_px}, water {sim.water}, start pose; a set: "
        + ", ".join(f"{'depth' if c == DEPTH_CAMERA else 'rgb'} {c}" for c in CAMERAS)
        + f"; {args.sets} sets after {args.warmup}"
    )
    rows = []
    for samples in dict.fromkeys((sim.camera_samples, 0)):
        gl, wall, cpu = measure(model, data, sim, samples, args.sets, args.warmup)
        rows.append((BACKEND, gl, samples, wall, cpu))
    width = max(len(r[1]) for r in rows)
    print(
        f"{'backend':8} {'GL vendor / renderer':{width}} {'samples':>7} {'wall ms/set':>11} {'p50':>7} "
        f"{'max':>7} {'CPU ms/set':>10}"
    )
    for backend, gl, samples, wall, cpu in rows:
        print(
            f"{backend:8} {gl:{width}} {samples:7d} {1e3 * wall.mean():11.2f} {1e3 * np.median(wall):7.2f} "
            f"{1e3 * wall.max():7.2f} {1e3 * cpu.mean():10.2f}"
        )


if __name__ == "__main__":
    main()
