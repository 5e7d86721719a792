"""Simulation figures: physics step time and real-time factor (headless, no cameras; the
dynamic low level with each marine model: Fossen's on the hull with the strip model on the arm (the
default) or MuJoCo's ellipsoids on the arm, and MuJoCo's ellipsoids on both, each against its floor,
a bare mj_step of the same model, in the same run), the arm's reference trajectories under the strip
model against MuJoCo's ellipsoids (tests/stations/simulation/test_arm_hydrodynamics.py's, and those
where the two differ by construction), stereo + depth rendering time at 640x480 and the camera rate
it allows, and the station loop with cameras at several rates, as the share of control deadlines met.
Run: .venv/bin/python bench/simulation.py [--physics] (--physics: the physics figures alone).
Prints figures; asserts nothing."""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import threading
import time
from pathlib import Path

import mujoco
import numpy as np
import zenoh

from abyss.stations.simulation.rendering import choose_gl_backend

choose_gl_backend()

from abyss.bus.session import open_session, zenoh_config  # noqa: E402
from abyss.config.simulation import SimulationConfig  # noqa: E402
from abyss.description.robot import robot_at  # noqa: E402
from abyss.interface import keys  # noqa: E402
from abyss.interface.messages import SimulationStatus, decode  # noqa: E402
from abyss.launch.station import free_port  # noqa: E402
from abyss.stations.simulation.encoding import encode_image  # noqa: E402
from abyss.stations.simulation.lowlevel import References  # noqa: E402
from abyss.stations.simulation.rendering import Cameras  # noqa: E402
from abyss.stations.simulation.world import World  # noqa: E402

ROBOT = robot_at("")  # the shipped robot package


def physics(
    low_level: str,
    hydrodynamics: str = "fossen",
    arm: str = "strips",
    seconds: float = 10.0,
    chunks: int = 10,
    in_c: str = "all",
) -> tuple[float, float]:
    """Wall time per physics step [s], and that of a bare mj_step of the same model (the dynamic low
    level's floor: MuJoCo alone, no Python per step): the fastest of `chunks` slices of the run (the
    least disturbed by other work), each followed by as many bare mj_step calls from the same state.
    `in_c` (stations/simulation/native.py): "all" the per-step marine terms and the low level in C
    where it is built, "steps" the per-step terms alone, "none" all in Python."""
    config = SimulationConfig(low_level=low_level, hydrodynamics=hydrodynamics, arm_hydrodynamics=arm)
    world = World(config, np.random.default_rng(0))
    if in_c != "all":
        world.native_low_level = None
    if in_c == "none":
        world.marine = None
    refs = References(np.array([0.3, 0.1, 0.0, 0.1]), np.full(6, 0.05), 0.0)
    periods = round(seconds / chunks / config.control_period_s)
    steps = periods * round(config.control_period_s / config.physics_step_s)
    bare_data = mujoco.MjData(world.model)
    step_s, bare_s = [], []
    for _ in range(chunks):
        t0 = time.perf_counter()
        for _ in range(periods):
            world.step(refs, config.control_period_s)
        step_s.append((time.perf_counter() - t0) / steps)
        mujoco.mj_copyData(bare_data, world.model, world.data)
        t0 = time.perf_counter()
        for _ in range(steps):
            mujoco.mj_step(world.model, bare_data)
        bare_s.append((time.perf_counter() - t0) / steps)
    per_step, bare = min(step_s), min(bare_s)
    dt = config.physics_step_s
    marine = f", {hydrodynamics} + {arm}" if low_level == "dynamic" else ""
    if low_level == "dynamic":
        marine += {"all": ", in C", "steps": ", per-step terms in C", "none": ", in Python"}[in_c]
    floor = (
        f"; bare mj_step {bare * 1e6:.1f} us (real-time factor {dt / bare:.1f}), ratio {per_step / bare:.2f}x"
        if low_level == "dynamic"
        else ""
    )
    print(
        f"physics, {low_level + marine:<52}: {per_step * 1e6:6.1f} us per {dt * 1e3:g} ms step, "
        f"real-time factor {dt / per_step:6.1f}{floor} (headless, no cameras)"
    )
    return per_step, bare


def arm_trajectories() -> None:
    """The arm's reference trajectories, the strip model against MuJoCo's ellipsoids: per case the
    largest difference of a joint's angle against the trajectory's range (the test's metric)."""
    path = Path(__file__).parents[1] / "tests" / "stations" / "simulation" / "test_arm_hydrodynamics.py"
    spec = importlib.util.spec_from_file_location("test_arm_hydrodynamics", path)
    assert spec is not None and spec.loader is not None
    reference = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(reference)
    for title, cases in (
        ("held to 5 % by the test", reference.REFERENCE_SET),
        ("different by construction", reference.DIFFERENT_BY_CONSTRUCTION),
    ):
        figures = []
        for name, case in cases.items():
            error = reference.differences(case)
            figures.append(f"{name} {error.max():.1%} ({ROBOT.arm_joints[int(np.argmax(error))]})")
        print(f"  arm trajectories, strips against ellipsoids, {title}: " + "; ".join(figures))


def rendering(frames: int = 20) -> float:
    world = World(SimulationConfig(), np.random.default_rng(0))
    cameras = Cameras(world.model, 640, 480, depth_camera=ROBOT.depth_camera)
    encode_image(cameras, world.data, ROBOT.stereo_left, 90)  # warm up
    per_camera = {}
    for camera in ROBOT.cameras:
        t0 = time.perf_counter()
        for _ in range(frames):
            encode_image(cameras, world.data, camera, 90)
        per_camera[camera] = (time.perf_counter() - t0) / frames
    cameras.close()
    total = sum(per_camera.values())
    print(
        "rendering 640x480 + encoding: "
        + ", ".join(f"{c} {t * 1e3:.0f} ms" for c, t in per_camera.items())
        + f"; a stereo + depth set {total * 1e3:.0f} ms: at most {1 / total:.1f} sets/s on one core"
    )
    return total


def station_loop(camera_rate_hz: float, seconds: float = 15.0) -> None:
    port = free_port()
    system = f"bench-sim-{int(camera_rate_hz * 10)}"
    station = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "abyss.cli",
            "station",
            "simulation",
            "--system",
            system,
            "--listen",
            f"tcp/127.0.0.1:{port}",
            "--set",
            f"simulation.camera_rate_hz={camera_rate_hz}",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    session = open_session(zenoh_config(connect=[f"tcp/127.0.0.1:{port}"]), "bench")  # peer: retries
    latest: list[SimulationStatus] = []
    lock = threading.Lock()

    def on_status(sample: zenoh.Sample) -> None:
        message = decode(str(sample.key_expr), sample.payload.to_bytes()).message
        if isinstance(message, SimulationStatus):
            with lock:
                latest.append(message)

    sub = session.declare_subscriber(keys.simulation_status_key(system), on_status)
    time.sleep(seconds)
    sub.undeclare()
    session.close()
    station.terminate()
    station.wait(timeout=30)
    with lock:
        if not latest:
            print(f"station loop, cameras {camera_rate_hz:g} Hz: no status received")
            return
        s = latest[-1]
        rtf = np.mean([m.realtime_factor for m in latest[2:]] or [s.realtime_factor])
    print(
        f"station loop, cameras at {camera_rate_hz:g} Hz: real-time factor {rtf:.3f}, "
        f"control deadlines met {s.deadlines_met:.1%} over {s.sim_time_s:.0f} s"
    )


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--physics", action="store_true", help="the physics figures alone")
    args = parser.parse_args()
    strips, _ = physics("dynamic", "fossen", "strips")
    steps_in_c, _ = physics("dynamic", "fossen", "strips", in_c="steps")
    strips_in_python, _ = physics("dynamic", "fossen", "strips", in_c="none")
    print(
        f"  in C a step takes {strips / strips_in_python:.2f}x its time in Python "
        f"({steps_in_c / strips_in_python:.2f}x with the per-step terms alone in C)"
    )
    ellipsoids, _ = physics("dynamic", "fossen", "ellipsoid")
    physics("dynamic", "ellipsoid", "ellipsoid")
    print(f"  the strip model on the arm costs {strips / ellipsoids:.2f}x MuJoCo's ellipsoids per step")
    physics("kinematic")
    arm_trajectories()
    if args.physics:
        sys.exit(0)
    rendering()
    for rate in (0.0, 1.0, 2.0, 5.0):
        station_loop(rate)
