"""Where the cameras' time goes, per frame set (the three cameras at simulation.camera_rate_hz),
stage by stage, from the default mission's start pose (the panel 4 m off) and its working pose
(its last waypoint, at arm's length from the panel), in clear water (simulation.water "none",
the default) and in Jerlov's oceanic type I (the underwater optics on):
- the simulation's sensor processes, as they run (offload._Sensor, here in this process):
  the state put into their MjData (mj_forward), update_scene, the GL render (mjr_render, timed
  to glFinish) and the read-back (mjr_readPixels, with the multisample resolve) of the RGB and
  depth passes, what else the frames go through (flips, copies, the depth's linearisation and
  conversions), the optics (formation model, marine snow, exposure and noise), JPEG and 16-bit
  PNG encoding, the pickles across the offload pipe; the sonar's ray casts and image at its rate;
- onboard (clouds_of, as frame_sets runs it: the depth cloud on each set, the stereo one on every
  onboard.stereo_every-th): decoding, stereo matching (the semi-global matcher's passes, then the
  filters), cloud building, voxel downsampling, packing; the left frame re-encoded for the vessel;
- the vessel: octree insertion of those clouds (its change tracking every
  vessel.scene_track_period_s) and the panel's recognition every vessel.recognition_period_s.
Each stage's time is its own (exclusive of the stages it calls), taken by wrapping the functions
the code calls: the median of REPEATS frame sets after one to warm up (the vessel's insertion: the
mean, its change tracking amortised); a stage's figure is per frame set (its calls per set times
its cost), with its share of all the stages. Then the whole offloaded sensor cycle as the station
runs it (Offloaded("cameras").messages: the child renders, encodes and pickles, the parent waits
on the pipe), per frame set, wall time, the median of 2 * REPEATS. The stations' configuration
(SimulationConfig(), OnboardConfig(), VesselConfig()) and their single-threaded native pools.
Run: .venv/bin/python bench/cameras.py [--samples N (simulation.camera_samples)]. Prints figures;
asserts nothing."""

from __future__ import annotations

import argparse
import dataclasses
import os
import pickle
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from abyss.launch.station import single_threaded_native_pools
from abyss.stations.simulation.rendering import choose_gl_backend

choose_gl_backend()
single_threaded_native_pools()  # as a station runs them

import cv2  # noqa: E402
import mujoco  # noqa: E402

from abyss.config.simulation import SimulationConfig  # noqa: E402
from abyss.config.stations import OnboardConfig, VesselConfig  # noqa: E402
from abyss.config.system import MissionConfig  # noqa: E402
from abyss.description.robot import robot_at  # noqa: E402
from abyss.description.site import site_at  # noqa: E402
from abyss.interface.clouds import unpack_cloud  # noqa: E402
from abyss.interface.images import decode_image, encode_jpeg  # noqa: E402
from abyss.scene import model as scene_model  # noqa: E402
from abyss.stations.onboard import perception, stereo  # noqa: E402
from abyss.stations.onboard.perception import CloudSettings, camera_in_world, clouds_of  # noqa: E402
from abyss.stations.simulation import encoding, optics, sonar  # noqa: E402
from abyss.stations.simulation.offload import Offloaded, _Sensor, state_of  # noqa: E402
from abyss.stations.simulation.world import World  # noqa: E402
from abyss.stations.vessel import recognition  # noqa: E402
from scene import timed  # noqa: E402  (bench/ is on the path when a bench runs)

ROBOT = robot_at("")  # the shipped robot package
CAMERAS = ROBOT.cameras
EVERY_SET = tuple(camera for camera in CAMERAS if camera != ROBOT.stereo_right)  # the sets without stereo

REPEATS = 5  # frame sets timed, after one to warm up; stages and cycles: their median
WATERS = ("none", "I")
SAMPLES = [SimulationConfig().camera_samples]  # the render's samples per pixel (--samples)
ARM_BODIES = ("arm_base", "arm_link1", "arm_link2", "arm_link3", "arm_link4", "arm_link5", "arm_link6")


class Stages:
    """Exclusive time and calls per stage: functions replaced by timed wrappers for a while."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self._open: list[float] = []  # the time of the stages called by each open one

    def _timed(self, original: Callable[..., Any], name: Callable[..., str], sync: Callable[[], None] | None):
        def call(*args: Any, **kwargs: Any) -> Any:
            self._open.append(0.0)
            t0 = time.perf_counter()
            try:
                result = original(*args, **kwargs)
                if sync is not None:
                    sync()
                return result
            finally:
                elapsed = time.perf_counter() - t0
                inner = self._open.pop()
                stage = name(*args, **kwargs)
                self.seconds[stage] += elapsed - inner
                self.calls[stage] += 1
                if self._open:
                    self._open[-1] += elapsed

        return call

    @contextmanager
    def wrapping(self, *wraps: tuple[Any, str, str | Callable[..., str]]) -> Iterator[Stages]:
        """(owner, attribute, stage name or a function of the call's arguments naming it)."""
        undo = []
        try:
            for owner, attribute, name in wraps:
                original = getattr(owner, attribute)
                namer = name if callable(name) else (lambda *_, n=name, **__: n)
                sync = mujoco.mjr_finish if (owner, attribute) == (mujoco, "mjr_render") else None
                setattr(owner, attribute, self._timed(original, namer, sync))
                undo.append((owner, attribute, original))
            yield self
        finally:
            for owner, attribute, original in reversed(undo):
                setattr(owner, attribute, original)

    def per_run(
        self, action: Callable[[], Any], weight: float = 1.0, statistic: Callable[..., Any] = np.median
    ) -> dict[str, tuple[float, float]]:
        """Each stage's seconds and calls per run of `action` (times `weight`): the median of
        REPEATS runs after one to warm up (a shared machine's interference lands on a few), or
        their mean where work comes in some runs only (`statistic`)."""
        action()
        runs = []
        for _ in range(REPEATS):
            self.seconds.clear()
            self.calls.clear()
            action()
            runs.append((dict(self.seconds), dict(self.calls)))
        stages = dict.fromkeys(stage for seconds, _ in runs for stage in seconds)
        return {
            s: (
                weight * float(statistic([seconds.get(s, 0.0) for seconds, _ in runs])),
                weight * float(statistic([calls.get(s, 0) for _, calls in runs])),
            )
            for s in stages
        }


def median_s(action: Callable[[], Any], repeats: int = REPEATS) -> float:
    """[s] the median of `repeats` runs of `action` after one to warm up."""
    action()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        action()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def merge(*parts: dict[str, tuple[float, float]]) -> dict[str, tuple[float, float]]:
    total: dict[str, tuple[float, float]] = {}
    for part in parts:
        for stage, (seconds, calls) in part.items():
            s, c = total.get(stage, (0.0, 0.0))
            total[stage] = (s + seconds, c + calls)
    return total


def _pass(scene: Any) -> str:
    return "depth" if scene.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] else "RGB"


def _read_back(rgb: Any, depth: Any) -> str:
    if rgb is None:
        return "depth pass: read-back"
    return "RGB pass: read-back" + (" (and its depth)" if depth is not None else "")


SIMULATION = (
    (mujoco, "mj_forward", "sim: state into the child's MjData (mj_forward)"),
    (mujoco, "mjv_updateScene", "sim: update_scene (every pass)"),
    (mujoco, "mjr_render", lambda rect, scene, con: f"sim: {_pass(scene)} pass: GL render (to glFinish)"),
    (mujoco, "mjr_readPixels", lambda rgb, depth, rect, con: f"sim: {_read_back(rgb, depth)}"),
    (optics, "range_of_depth", "sim: optics: range from depth"),
    (optics.Optics, "radiance", "sim: optics: formation model (radiance)"),
    (optics.Optics, "snow", "sim: optics: marine snow"),
    (optics.Optics, "image", "sim: optics: exposure and noise"),
    (encoding, "encode_jpeg", "sim: JPEG encoding"),
    (
        cv2,
        "imencode",
        lambda ext, *_, **__: "sim: JPEG encoding" if ext == ".jpg" else "sim: PNG-16 encoding",
    ),
    (
        encoding,
        "encode_image",
        lambda cameras, data, camera, *_: (
            "sim: depth: the rest (linearisation, flip, to mm, copies)"
            if camera == ROBOT.depth_camera
            else "sim: RGB: the rest (flip, copies, conversions)"
        ),
    ),
)
SONAR = (
    (mujoco, "mj_multiRay", "sim: sonar: ray casts"),
    (sonar.ImagingSonar, "image", "sim: sonar: echoes, speckle, dB"),
    (sonar.ImagingSonar, "message", "sim: sonar: PNG, state, message"),
    (mujoco, "mj_forward", "sim: sonar: PNG, state, message"),
)
ONBOARD = (
    (perception, "decode_image", "onboard: decoding the frames"),
    (stereo, "disparity_of", "onboard: stereo: semi-global matching (both passes)"),
    (perception, "stereo_depth", "onboard: stereo: filters, depth"),
    (perception, "voxel_downsample", "onboard: voxel downsample"),
    (perception, "pack_cloud", "onboard: packing (quantise, zlib)"),
    (perception, "world_cloud", "onboard: cloud building (points, colours, self-filter)"),
    (perception, "clouds_of", "onboard: cloud building (points, colours, self-filter)"),
)
VESSEL = (
    (scene_model, "voxel_downsample", "vessel: voxel downsample"),
    (scene_model.SceneModel, "_walk", "vessel: change tracking (walk)"),
    (scene_model.SceneModel, "insert", "vessel: octree insertion (insertPointCloud)"),
    (recognition, "by_texture", "vessel: recognition: markers (ArUco, PnP)"),
    (recognition, "by_shape", "vessel: recognition: shape (RANSAC, ICP)"),
    (recognition, "part_angles", "vessel: recognition: the parts' angles"),
    (recognition.PanelTracker, "update", "vessel: recognition: the rest (decoding, fusion)"),
)


def frame_set(
    position: tuple[float, float, float], yaw_rad: float, water: str
) -> dict[str, tuple[float, float]]:
    """Each stage's ms and calls per frame set at the pose."""
    sim = SimulationConfig(
        water=water, start_position_m_world=position, start_yaw_rad=yaw_rad, camera_samples=SAMPLES[0]
    )
    onboard, vessel = OnboardConfig(), VesselConfig()
    world = World(sim, np.random.default_rng(0))
    state = state_of(world.data)
    sonar_per_set = sim.sonar_rate_hz / sim.camera_rate_hz
    stereo_share = 1.0 / onboard.stereo_every if "stereo" in onboard.cloud_sources else 0.0
    stages = Stages()
    cameras = _Sensor("cameras", world.model, sim, [0, 1])
    pinger = _Sensor("sonar", world.model, sim, [0, 2])
    try:
        with stages.wrapping(*SIMULATION):  # cam_right on the stereo matcher's sets alone
            simulation = merge(
                stages.per_run(lambda: cameras.frames(state, set(), CAMERAS), stereo_share),
                stages.per_run(lambda: cameras.frames(state, set(), EVERY_SET), 1 - stereo_share),
            )
        with stages.wrapping(*SONAR):
            pings = stages.per_run(lambda: pinger.ping(state), sonar_per_set)
        images = cameras.frames(state, set(), CAMERAS)
    finally:
        cameras.cameras.close()
    reply = ("ok", images, 0.0)
    ping = ("ok", pinger.ping(state), 0.0)
    pipe = {
        "sim: pickles across the offload pipes": (
            timed(lambda: pickle.loads(pickle.dumps(reply, protocol=pickle.HIGHEST_PROTOCOL)), REPEATS)
            + sonar_per_set
            * timed(lambda: pickle.loads(pickle.dumps(ping, protocol=pickle.HIGHEST_PROTOCOL)))
            + (1 + sonar_per_set)
            * timed(
                lambda: pickle.loads(
                    pickle.dumps(("frames", state, set(), CAMERAS), protocol=pickle.HIGHEST_PROTOCOL)
                )
            ),
            2 + 2 * sonar_per_set,
        )
    }

    frames = {image.camera: image for image in images}
    truth = world.truth()
    pose = (truth.position_m_world, truth.orientation_wxyz_world)
    arm_m_world = np.array([world.data.body(name).xpos for name in ARM_BODIES])
    settings = CloudSettings.of(onboard)
    depth_only = tuple(s for s in onboard.cloud_sources if s != "stereo")
    image_per_set = min(1.0, onboard.image_rate_hz / sim.camera_rate_hz)
    with stages.wrapping(*ONBOARD):
        on_sets = merge(
            stages.per_run(
                lambda: clouds_of(ROBOT.spec.cameras, frames, pose, arm_m_world, depth_only, settings),
                1 - stereo_share,
            ),
            stages.per_run(
                lambda: clouds_of(
                    ROBOT.spec.cameras, frames, pose, arm_m_world, onboard.cloud_sources, settings
                ),
                stereo_share,
            ),
        )
    left = frames[ROBOT.stereo_left]
    on_image = {
        "onboard: the left frame re-encoded for the vessel": (
            image_per_set
            * timed(lambda: encode_jpeg(decode_image(left), onboard.image_jpeg_quality), REPEATS),
            2 * image_per_set,
        )
    }
    clouds = {
        cloud.source: cloud
        for cloud in clouds_of(ROBOT.spec.cameras, frames, pose, arm_m_world, onboard.cloud_sources, settings)
    }
    image = dataclasses.replace(  # as onboard sends it on (frame_sets)
        left,
        pose_frame="world",
        pose_camera=camera_in_world(left, pose),
        data=encode_jpeg(decode_image(left), onboard.image_jpeg_quality),
    )

    model = scene_model.SceneModel(
        vessel.octree_resolution_m, vessel.octree_max_range_m, track_period_s=vessel.scene_track_period_s
    )
    stamp = [0.0]

    def insert(cloud: Any) -> None:
        stamp[0] += 1.0 / sim.camera_rate_hz
        model.insert(*unpack_cloud(cloud), cloud.sensor_m_world, stamp[0])

    tracker = recognition.PanelTracker(site_at("").panel)  # the shipped site's
    points = unpack_cloud(clouds.get("depth") or clouds["stereo"])[0]
    recognised_per_set = 1.0 / (vessel.recognition_period_s * sim.camera_rate_hz)
    with stages.wrapping(*VESSEL):
        on_vessel = merge(
            *(
                stages.per_run(  # the mean: the change tracking walks once in 5 s of clouds
                    lambda c=cloud: insert(c), 1.0 if source == "depth" else stereo_share, np.mean
                )
                for source, cloud in clouds.items()
            ),
            stages.per_run(lambda: tracker.update(decode_image(image), image, points), recognised_per_set),
        )
    return {
        stage: (seconds * 1e3, calls)
        for stage, (seconds, calls) in merge(simulation, pings, pipe, on_sets, on_image, on_vessel).items()
    }


def offloaded_ms(position: tuple[float, float, float], yaw_rad: float, water: str) -> tuple[float, float]:
    """The whole offloaded cameras' cycle per frame set as the station runs it (a stereo set and
    the others in their shares) [ms]: its wall time, and its child's CPU time (Mesa's software
    rasteriser renders on several threads)."""
    sim, onboard = (
        SimulationConfig(
            water=water, start_position_m_world=position, start_yaw_rad=yaw_rad, camera_samples=SAMPLES[0]
        ),
        OnboardConfig(),
    )
    stereo_share = 1.0 / onboard.stereo_every if "stereo" in onboard.cloud_sources else 0.0
    world = World(sim, np.random.default_rng(0))
    sensor = Offloaded("cameras", world.model, sim, [0, 1])
    try:
        wall_ms, cpu_ms = 0.0, 0.0
        for cameras, share in ((CAMERAS, stereo_share), (EVERY_SET, 1.0 - stereo_share)):
            cpu0 = process_cpu_s(sensor.process.pid)
            wall_ms += (
                share
                * 1e3
                * median_s(
                    lambda c=cameras: sensor.messages(state_of(world.data), set(), c, ROBOT), 2 * REPEATS
                )
            )
            cpu_ms += share * 1e3 * (process_cpu_s(sensor.process.pid) - cpu0) / (2 * REPEATS + 1)
        return wall_ms, cpu_ms
    finally:
        sensor.close()


def process_cpu_s(pid: int) -> float:
    """[s] the user and system CPU time of process `pid`, all its threads (/proc/PID/stat)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--samples", type=int, default=SAMPLES[0], help="simulation.camera_samples")
    SAMPLES[0] = parser.parse_args().samples
    sim, onboard, vessel = SimulationConfig(camera_samples=SAMPLES[0]), OnboardConfig(), VesselConfig()
    *_, (x, y, z, yaw_rad) = MissionConfig().waypoints
    print(
        f"per frame set: {sim.camera_width_px}x{sim.camera_height_px} px at {sim.camera_samples} samples per "
        f"pixel, cam_left RGB, cam_right RGB on the stereo sets, "
        f"cam_depth depth at {sim.camera_rate_hz:g} Hz; the sonar at {sim.sonar_rate_hz:g} Hz; stereo on 1 "
        f"set in {onboard.stereo_every}; recognition every {vessel.recognition_period_s:g} s; "
        f"calls per set after each figure; the median of {REPEATS} sets after one"
    )
    for where, position, yaw in (
        ("start pose", sim.start_position_m_world, sim.start_yaw_rad),
        ("working pose (the last waypoint)", (x, y, z), yaw_rad),
    ):
        figures = {water: frame_set(position, yaw, water) for water in WATERS}
        totals = {water: sum(ms for ms, _ in figures[water].values()) for water in WATERS}
        met = dict.fromkeys(s for water in WATERS for s in figures[water])  # in the order met
        stages = sorted(met, key=lambda s: ("sim", "onboard", "vessel").index(s.split(":")[0]))
        print(f"\n{where}, {tuple(round(p, 2) for p in position)}:")
        header = "".join(f"{'water ' + w + ': ms/set':>22}{'share':>7}{'calls':>6}" for w in WATERS)
        print(f"  {'stage':<66}{header}")
        for stage in stages:
            cells = ""
            for water in WATERS:
                ms, calls = figures[water].get(stage, (0.0, 0.0))
                cells += f"{ms:>22.1f}{100 * ms / totals[water]:>6.1f}%{calls:>6.2g}"
            print(f"  {stage:<66}{cells}")
        for station in ("sim", "onboard", "vessel"):
            cells = ""
            for water in WATERS:
                ms = sum(v for s, (v, _) in figures[water].items() if s.startswith(station + ":"))
                cells += f"{ms:>22.1f}{100 * ms / totals[water]:>6.1f}%{'':>6}"
            print(f"  {'all of ' + station:<66}{cells}")
        print(f"  {'all stages':<66}" + "".join(f"{totals[w]:>22.1f}{100:>6.1f}%{'':>6}" for w in WATERS))
        whole = {water: offloaded_ms(position, yaw, water) for water in WATERS}
        sim_ms = {
            w: sum(v for s, (v, _) in figures[w].items() if s.startswith("sim:") and "sonar" not in s)
            for w in WATERS
        }
        print(
            "  the whole offloaded cameras' cycle (Offloaded.messages): "
            + ", ".join(
                f"water {w} {whole[w][0]:.1f} ms wall, {whole[w][1]:.1f} ms CPU "
                f"(its stages here {sim_ms[w]:.1f} ms)"
                for w in WATERS
            )
        )


if __name__ == "__main__":
    main()
