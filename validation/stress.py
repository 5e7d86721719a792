"""`abyss stress satellite`: what scene data at which octree resolution the satellite link
carries beside the telemetry, the evaluation the original project made before its sea trial.

Scene data is real: the depth and left cameras rendered (MuJoCo) along the default mission's
path, one frame per second, fused into clouds (onboard's code) and integrated into an octree per
resolution (the vessel's code), whose updates are paced for the link (the vessel's pacer). The
link is the emulator itself (linkemu) in virtual time with the satellite profile, carrying a
2 Hz telemetry message beside the scene updates; every figure comes from what it delivered."""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from abyss.common.samples import Samples
from abyss.config import Config
from abyss.config.linkprofile import profile
from abyss.interface.clouds import unpack_cloud
from abyss.interface.messages import Telemetry, encode
from abyss.linkemu.link import Link, Offer
from abyss.scene.model import SceneModel
from abyss.scene.pacing import ScenePacer

STEP_S = 0.05
TELEMETRY_PERIOD_S = 0.5


@dataclass(frozen=True)
class Frame:
    points_m_world: np.ndarray
    colors: np.ndarray
    sensor_m_world: np.ndarray


def mission_frames(config: Config, count: int, progress: Callable[[str], None]) -> list[Frame]:
    """Depth clouds along the path start -> waypoints, `count` frames evenly spaced."""
    from abyss.stations.simulation.rendering import choose_gl_backend

    choose_gl_backend()  # before MuJoCo is imported
    import mujoco

    from abyss.config import robot_of
    from abyss.stations.onboard.perception import CloudSettings, clouds_of
    from abyss.stations.simulation.encoding import encode_image
    from abyss.stations.simulation.rendering import Cameras
    from abyss.stations.simulation.world import World

    sim = config.simulation
    world = World(sim, np.random.default_rng(config.seed))
    path = np.array([[*sim.start_position_m_world, sim.start_yaw_rad], *config.mission.waypoints])
    robot = robot_of(config)
    cameras = Cameras(
        world.model,
        sim.camera_width_px,
        sim.camera_height_px,
        samples=sim.camera_samples,
        depth_camera=robot.depth_camera,
    )
    settings = CloudSettings(config.onboard.cloud_voxel_m, config.onboard.cloud_max_range_m)
    frames = []
    p = world.plant.qpos
    try:
        for i, f in enumerate(np.linspace(0.0, len(path) - 1, count)):
            j = min(int(f), len(path) - 2)
            x, y, z, yaw = path[j] + (f - j) * (path[j + 1] - path[j])
            world.data.qpos[p : p + 3] = x, y, z
            world.data.qpos[p + 3 : p + 7] = np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)
            mujoco.mj_forward(world.model, world.data)
            images = {c: encode_image(cameras, world.data, c, sim.jpeg_quality) for c in robot.cameras}
            pose = (np.array([x, y, z]), np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]))
            cloud = clouds_of(robot.spec.cameras, images, pose, np.zeros((0, 3)), ("depth",), settings)[0]
            points, colors = unpack_cloud(cloud)
            frames.append(Frame(points, colors, cloud.sensor_m_world))
            progress(f"rendered frame {i + 1}/{count}: {len(points)} points")
    finally:
        cameras.close()
    return frames


class ResolutionRun:
    """One resolution's run in virtual time: the octree, its pacer and the link, with the
    figures counted as it goes."""

    def __init__(self, resolution_m: float, config: Config, link_profile: str, seed: int) -> None:
        cfg = config.vessel
        self.resolution_m = resolution_m
        self.link = Link(profile(link_profile), np.random.default_rng(seed))
        self.model = SceneModel(
            resolution_m, cfg.octree_max_range_m, cfg.scene_update_bytes, cfg.scene_track_period_s
        )
        self.pacer = ScenePacer(cfg.scene_share, cfg.satellite_capacity_bps, cfg.scene_update_bytes)
        self.acks: dict[int, float] = {}  # scene seq -> when shore's acknowledgement reaches the vessel [s]
        self.telemetry = encode(sample_telemetry(), 0, 0.0)
        self.latency = {"scene": Samples(), "telemetry": Samples()}
        self.offered = {"scene": 0, "telemetry": 0}
        self.delivered = {"scene": 0, "telemetry": 0}
        self.update_bytes: list[int] = []
        self.snapshot_bytes = 0
        self.integrate_s = 0.0  # [s] of the process's time, inserting frames

    def integrate(self, frame: Frame, now_s: float) -> None:
        t0 = time.perf_counter()
        self.model.insert(frame.points_m_world, frame.colors, frame.sensor_m_world, now_s)
        self.integrate_s += time.perf_counter() - t0

    def offer_telemetry(self, now_s: float) -> None:
        self.offered["telemetry"] += 1
        self.link.offer(now_s, self.telemetry, tag="telemetry")

    def send_scene(self, now_s: float) -> None:
        """Shore's acknowledgements that are back, then the updates the pacer allows now."""
        for seq in [seq for seq, at_s in self.acks.items() if at_s <= now_s]:
            self.pacer.acknowledged(now_s, seq)
            del self.acks[seq]
        self.pacer.tick(now_s)
        while self.pacer.allows():
            update = self.model.next_update(now_s, self.pacer.update_bytes())
            if update is None:
                break
            payload = encode(update, update.scene_seq, now_s)
            if self.link.offer(now_s, payload, block=True, tag=("scene", update.scene_seq)) is Offer.ACCEPTED:
                self.offered["scene"] += 1
                self.update_bytes.append(len(payload))
                if update.kind == "snapshot":
                    self.snapshot_bytes = len(payload)
            self.pacer.sent(now_s, len(payload), update.scene_seq)

    def deliver(self, now_s: float) -> None:
        for delivery in self.link.advance(now_s):
            name = delivery.tag if delivery.tag == "telemetry" else "scene"
            self.latency[name].add(delivery.delivered_s - delivery.offered_s)
            self.delivered[name] += 1
            if name == "scene":  # shore acknowledges it; the ack takes the link's delay back
                self.acks[delivery.tag[1]] = delivery.delivered_s + self.link.profile.delay_s

    def result(self, frames: int, duration_s: float) -> dict[str, Any]:
        stats = self.link.snapshot()
        bt_bytes = len(self.model.binary())
        sent_bytes = sum(self.update_bytes)
        result: dict[str, Any] = {
            "resolution_m": self.resolution_m,
            "updates": self.offered["scene"],
            "update_bytes_mean": float(np.mean(self.update_bytes)) if self.update_bytes else 0.0,
            "update_bytes_max": max(self.update_bytes, default=0),
            "first_update_bytes": self.snapshot_bytes,
            "scene_bytes_sent": int(sent_bytes),
            "map_bt_bytes": bt_bytes,
            "sent_over_bt": sent_bytes / bt_bytes if bt_bytes else 0.0,  # 1: the map sent once
            "pending_cells_at_end": len(self.model.pending),
            "throughput_bps": 8.0 * stats["bytes_delivered"] / duration_s,
            "link_rate_bps": self.link.profile.rate_bps,
            "capacity_estimate_bps": self.pacer.capacity_bps,
            "integrate_ms_per_frame": 1e3 * self.integrate_s / max(frames, 1),
            "loss_packets": stats.get("losses", 0.0) / max(stats.get("packets_sent", 1.0), 1.0),
        }
        for name in ("scene", "telemetry"):
            result[f"{name}_delivered"] = self.delivered[name]
            result[f"{name}_offered"] = self.offered[name]
            percentiles = self.latency[name].percentiles("latency", 1e3, "ms", (50, 95))
            result.update({f"{name}_{k}": v for k, v in percentiles.items()})
        return result


def run_resolution(
    frames: list[Frame], resolution_m: float, config: Config, link_profile: str, duration_s: float, seed: int
) -> dict[str, Any]:
    """One resolution: frames integrated once a second, updates and telemetry over the link."""
    run = ResolutionRun(resolution_m, config, link_profile, seed)
    frame_period_s = duration_s / len(frames)
    next_frame, next_telemetry_s = 0, 0.0
    for step in range(math.ceil(duration_s / STEP_S) + 1):
        now_s = step * STEP_S
        if next_frame < len(frames) and now_s >= next_frame * frame_period_s:
            run.integrate(frames[next_frame], now_s)
            next_frame += 1
        run.model.track(now_s)
        if now_s >= next_telemetry_s:
            run.offer_telemetry(now_s)
            next_telemetry_s += TELEMETRY_PERIOD_S
        run.send_scene(now_s)
        run.deliver(now_s)
    return run.result(len(frames), duration_s)


def sample_telemetry() -> Telemetry:
    zero3 = np.zeros(3)
    return Telemetry(
        position_m_world=zero3,
        yaw_rad=0.0,
        mode="moving",
        command_id=1,
        waypoint_index=0,
        waypoints_total=3,
        position_error_m_world=zero3,
        heading_error_rad=0.0,
        arm_mode="idle",
        arm_command_id=-1,
        ee_position_error_m_world=zero3,
        ee_orientation_error_rad=0.0,
        ee_position_m_world=zero3,
        ee_orientation_wxyz_world=np.array([1.0, 0, 0, 0]),
        arm_positions_rad=np.zeros(6),
        failsafe="",
        failsafe_events=0,
        sim_time_s=0.0,
    )


def table(results: list[dict[str, Any]], budget_ms: float) -> str:
    lines = [
        f"{'res m':>6} {'updates':>8} {'B/update':>9} {'map .bt B':>10} {'sent B':>9} {'sent/.bt':>9} "
        f"{'kbit/s':>8} "
        f"{'scene p50/p95 ms':>17} {'telem p50/p95 ms':>17} {'loss':>6}"
    ]
    for r in results:
        lines.append(
            f"{r['resolution_m']:>6g} {r['updates']:>8} {r['update_bytes_mean']:>9.0f} "
            f"{r['map_bt_bytes']:>10} "
            f"{r['scene_bytes_sent']:>9} {r['sent_over_bt']:>9.2f} {r['throughput_bps'] / 1e3:>8.1f} "
            f"{r.get('scene_latency_p50_ms', 0):>8.0f}/{r.get('scene_latency_p95_ms', 0):<8.0f} "
            f"{r.get('telemetry_latency_p50_ms', 0):>8.0f}/{r.get('telemetry_latency_p95_ms', 0):<8.0f} "
            f"{r['loss_packets']:>6.1%}"
        )
    finest = finest_within(results, budget_ms)
    lines.append(
        f"finest resolution with scene and telemetry p95 under {budget_ms:g} ms: "
        + (f"{finest:g} m" if finest is not None else "none")
    )
    return "\n".join(lines)


def finest_within(results: list[dict[str, Any]], budget_ms: float) -> float | None:
    fits = [
        r["resolution_m"]
        for r in results
        if r.get("scene_latency_p95_ms", math.inf) <= budget_ms
        and r.get("telemetry_latency_p95_ms", math.inf) <= budget_ms
        and r["pending_cells_at_end"] == 0
    ]
    return min(fits) if fits else None


def plot(results: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    res = [r["resolution_m"] for r in results]
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4))
    a.plot(res, [r["update_bytes_mean"] for r in results], "o-", label="per update (mean)")
    a.plot(res, [r["map_bt_bytes"] for r in results], "s--", label="whole map as .bt")
    a.plot(res, [r["scene_bytes_sent"] for r in results], "^-", label="sent in the run")
    a.set(xscale="log", yscale="log", xlabel="octree resolution [m]", ylabel="bytes", title="scene data")
    a.legend()
    for name, marker in (("scene", "o"), ("telemetry", "s")):
        b.plot(
            res, [r.get(f"{name}_latency_p50_ms", np.nan) for r in results], marker + "-", label=f"{name} p50"
        )
        b.plot(
            res,
            [r.get(f"{name}_latency_p95_ms", np.nan) for r in results],
            marker + "--",
            label=f"{name} p95",
        )
    b.set(
        xscale="log", xlabel="octree resolution [m]", ylabel="latency [ms]", title="over the satellite link"
    )
    b.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def stress_satellite(
    config: Config,
    resolutions: list[float],
    duration_s: float,
    out_dir: Path,
    budget_ms: float,
    link_profile: str = "satellite",
    echo: Callable[[str], None] = print,
) -> list[dict[str, Any]]:
    frames = mission_frames(config, max(2, int(duration_s)), echo)
    results = []
    for resolution_m in resolutions:
        echo(f"resolution {resolution_m:g} m: integrating and sending over {link_profile} ...")
        results.append(run_resolution(frames, resolution_m, config, link_profile, duration_s, config.seed))
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "stress_satellite.json").write_text(
        json.dumps(
            {
                "profile": link_profile,
                "duration_s": duration_s,
                "budget_ms": budget_ms,
                "finest_within_budget_m": finest_within(results, budget_ms),
                "results": results,
            },
            indent=2,
        )
    )
    plot(results, out_dir / "stress_satellite.png")
    echo(table(results, budget_ms))
    echo(f"wrote {out_dir / 'stress_satellite.json'} and {out_dir / 'stress_satellite.png'}")
    return results
