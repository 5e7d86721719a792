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

from abyss.common.clouds import unpack_cloud
from abyss.common.config import Config
from abyss.common.linkprofile import profile
from abyss.common.messages import Telemetry, encode
from abyss.common.samples import Samples
from abyss.common.scene import SceneModel
from abyss.linkemu.link import Link, Offer
from abyss.stations.vessel.pacing import ScenePacer

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

    from abyss.common.models import CAMERAS
    from abyss.stations.onboard.perception import CloudSettings, clouds_of
    from abyss.stations.simulation.encoding import encode_image
    from abyss.stations.simulation.rendering import Cameras
    from abyss.stations.simulation.world import World

    sim = config.simulation
    world = World(sim, np.random.default_rng(config.seed))
    path = np.array([[*sim.start_position_m_world, sim.start_yaw_rad], *config.mission.waypoints])
    cameras = Cameras(world.model, sim.camera_width_px, sim.camera_height_px)
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
            images = {c: encode_image(cameras, world.data, c, sim.jpeg_quality) for c in CAMERAS}
            pose = (np.array([x, y, z]), np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]))
            cloud = clouds_of(images, pose, np.zeros((0, 3)), ("depth",), settings)[0]
            points, colors = unpack_cloud(cloud)
            frames.append(Frame(points, colors, cloud.sensor_m_world))
            progress(f"rendered frame {i + 1}/{count}: {len(points)} points")
    finally:
        cameras.close()
    return frames


def run_resolution(
    frames: list[Frame], resolution_m: float, config: Config, link_profile: str, duration_s: float, seed: int
) -> dict[str, Any]:
    """One resolution: frames integrated once a second, updates and telemetry over the link."""
    cfg = config.vessel
    link = Link(profile(link_profile), np.random.default_rng(seed))
    model = SceneModel(resolution_m, cfg.octree_max_range_m, cfg.scene_update_bytes, cfg.scene_track_period_s)
    pacer = ScenePacer(cfg.scene_share, cfg.satellite_capacity_bps, cfg.scene_update_bytes)
    acks: dict[int, float] = {}  # scene seq -> when shore's acknowledgement reaches the vessel [s]
    telemetry = encode(sample_telemetry(), 0, 0.0)
    latency = {"scene": Samples(), "telemetry": Samples()}
    offered = {"scene": 0, "telemetry": 0}
    delivered = {"scene": 0, "telemetry": 0}
    update_bytes: list[int] = []
    snapshot_bytes = 0
    integrate_s = 0.0
    frame_period_s = duration_s / len(frames)
    next_frame, next_telemetry_s = 0, 0.0
    for step in range(math.ceil(duration_s / STEP_S) + 1):
        now_s = step * STEP_S
        if next_frame < len(frames) and now_s >= next_frame * frame_period_s:
            frame = frames[next_frame]
            t0 = time.perf_counter()
            model.insert(frame.points_m_world, frame.colors, frame.sensor_m_world, now_s)
            integrate_s += time.perf_counter() - t0
            next_frame += 1
        model.track(now_s)
        if now_s >= next_telemetry_s:
            offered["telemetry"] += 1
            link.offer(now_s, telemetry, tag="telemetry")
            next_telemetry_s += TELEMETRY_PERIOD_S
        for seq in [seq for seq, at_s in acks.items() if at_s <= now_s]:  # shore's acks are back
            pacer.acknowledged(now_s, seq)
            del acks[seq]
        pacer.tick(now_s)
        while pacer.allows():
            update = model.next_update(now_s, pacer.update_bytes())
            if update is None:
                break
            payload = encode(update, update.scene_seq, now_s)
            if link.offer(now_s, payload, block=True, tag=("scene", update.scene_seq)) is Offer.ACCEPTED:
                offered["scene"] += 1
                update_bytes.append(len(payload))
                if update.kind == "snapshot":
                    snapshot_bytes = len(payload)
            pacer.sent(now_s, len(payload), update.scene_seq)
        for delivery in link.advance(now_s):
            name = delivery.tag if delivery.tag == "telemetry" else "scene"
            latency[name].add(delivery.delivered_s - delivery.offered_s)
            delivered[name] += 1
            if name == "scene":  # shore acknowledges it; the ack takes the link's delay back
                acks[delivery.tag[1]] = delivery.delivered_s + link.profile.delay_s
    stats = link.snapshot()
    bt_bytes = len(model.binary())
    result: dict[str, Any] = {
        "resolution_m": resolution_m,
        "updates": offered["scene"],
        "update_bytes_mean": float(np.mean(update_bytes)) if update_bytes else 0.0,
        "update_bytes_max": max(update_bytes, default=0),
        "first_update_bytes": snapshot_bytes,
        "scene_bytes_sent": int(sum(update_bytes)),
        "map_bt_bytes": bt_bytes,
        "sent_over_bt": sum(update_bytes) / bt_bytes if bt_bytes else 0.0,  # 1: the map sent once
        "pending_cells_at_end": len(model.pending),
        "throughput_bps": 8.0 * stats["bytes_delivered"] / duration_s,
        "link_rate_bps": link.profile.rate_bps,
        "capacity_estimate_bps": pacer.capacity_bps,
        "integrate_ms_per_frame": 1e3 * integrate_s / max(len(frames), 1),
        "loss_packets": stats.get("losses", 0.0) / max(stats.get("packets_sent", 1.0), 1.0),
    }
    for name in ("scene", "telemetry"):
        result[f"{name}_delivered"] = delivered[name]
        result[f"{name}_offered"] = offered[name]
        result.update(
            {f"{name}_{k}": v for k, v in latency[name].percentiles("latency", 1e3, "ms", (50, 95)).items()}
        )
    return result


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
