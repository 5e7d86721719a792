"""The operator's view of the system in Rerun: the vehicle and its arm drawn from the shared
MuJoCo model and posed from telemetry, the mission, the scene octree, the recognised objects,
the camera, the controllers' errors, the links' statistics and the intervention on the panel,
each plot in one unit. Pure logging: the caller owns the `rr.RecordingStream` and its sinks
(file, gRPC, spawned viewer) and feeds each message with the sender's wall-clock stamp from its
envelope."""

from __future__ import annotations

import ctypes
import logging
import math
import signal
import subprocess
import time
from collections import deque
from pathlib import Path
from typing import IO, Any

import mujoco
import numpy as np
import rerun as rr

from abyss.common.errors import BadInput
from abyss.common.geometry import rotation_of
from abyss.common.ports import listening
from abyss.config.stations import OnshoreConfig
from abyss.description.robot import Robot, robot_spec
from abyss.interface.messages import (
    ArmGoal,
    Image,
    LinkStats,
    PerceptionStatus,
    RecognisedObjects,
    SonarImage,
    Telemetry,
    Waypoints,
)
from abyss.stations.onshore.layout import blueprint

RECORDING_FILE = "onshore.rrd"
PATH_POINTS = 5000  # the most recent points of the path flown kept on screen
PATH_STEP_M = 0.02  # a new path point once the vehicle has moved this far [m]
GOAL_AXIS_M = 0.2  # length of the arm goal's axes [m]
LINK_DELAYS = {"p50": "delay_p50_ms", "p99": "delay_p99_ms"}  # series -> linkemu's stats key [ms]
# cumulative counters [messages or packets]: series -> linkemu's stats key
LINK_COUNTS = {
    "messages_lost": "messages_lost",
    "messages_dropped": "messages_dropped",
    "packets_lost": "losses",
    "queue_drops": "queue_drops",
    "retransmissions": "retransmissions",
}
SONAR_ARC_SPACING_M = 0.1  # the sonar's first echoes drawn as their arcs, a point this far apart
CONFIDENT_RGB = np.array([60, 220, 120])  # a recognised object's box at confidence 1
DOUBTFUL_RGB = np.array([230, 90, 60])  # ... and at confidence 0
LABEL_POINT_M = 0.01  # radius of the point that carries an object's label [m]


def web_viewer_url(web_port: int, grpc_port: int) -> str:
    """The address of rerun's web viewer showing the live recording."""
    return f"http://127.0.0.1:{web_port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc_port}%2Fproxy"


def rerun_command() -> str:
    """rerun's own executable, shipped with the SDK."""
    import rerun_cli

    return str(Path(rerun_cli.__file__).parent / "rerun")


SERVER_START_S = 60.0  # [s] for rerun's web server to listen (a loaded machine took seconds)
SERVER_LOG = "rerun-server.log"  # the web server's output, in the record directory
log = logging.getLogger(__name__)


def _die_with_parent() -> None:  # in the child, before exec: SIGTERM when its parent dies
    ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


PR_SET_PDEATHSIG = 1  # linux/prctl.h


class Sinks:
    """The recording stream and what it goes to, per `cfg.viewer`: `onshore.rrd` in
    `cfg.record_dir` (every mode but `none`), and for `web` rerun's web viewer and gRPC proxy
    (its own process, on 127.0.0.1 only, ended with shore even if shore is killed), for `spawn`
    the native viewer. The gRPC sink connects only once the server listens: a sink that finds
    nobody there gives up for good, and the browser saw the recording's properties alone. A
    viewer that goes away costs shore nothing: what it misses is in the file."""

    def __init__(self, cfg: OnshoreConfig, system: str) -> None:
        self.recording: rr.RecordingStream | None = None
        self.server: subprocess.Popen[bytes] | None = None
        if cfg.viewer == "none":
            return
        self.recording = rr.RecordingStream("abyss", recording_id=f"abyss-{system}")
        sinks: list[rr.FileSink | rr.GrpcSink] = []
        if cfg.record_dir:
            sinks.append(rr.FileSink(str(Path(cfg.record_dir) / RECORDING_FILE)))
        proxy = f"rerun+http://127.0.0.1:{cfg.viewer_grpc_port}/proxy"
        if cfg.viewer == "web" and self._serve_web(cfg):
            sinks.append(rr.GrpcSink(proxy))
        elif cfg.viewer == "spawn":
            self.recording.spawn(port=cfg.viewer_grpc_port, connect=False)
            sinks.append(rr.GrpcSink(proxy))
        self.recording.set_sinks(*sinks)

    def _serve_web(self, cfg: OnshoreConfig) -> bool:
        """Start rerun's web server and wait till it listens; False (said in the log) if it
        does not: the run goes on, recorded to the file."""
        ports = (cfg.viewer_grpc_port, cfg.viewer_web_port)
        held = [p for p in ports if listening(p)]
        if held:
            log.error("the web viewer's port %s is held by another process; no web viewer", held)
            return False
        output: IO[bytes] | int = (
            open(Path(cfg.record_dir) / SERVER_LOG, "ab") if cfg.record_dir else subprocess.DEVNULL  # noqa: SIM115
        )
        self.server = subprocess.Popen(
            [rerun_command(), "--serve-web", "--bind", "127.0.0.1", "--port", str(cfg.viewer_grpc_port),
             "--web-viewer-port", str(cfg.viewer_web_port)],
            stdout=output, stderr=subprocess.STDOUT, preexec_fn=_die_with_parent)  # fmt: skip
        if not isinstance(output, int):
            output.close()  # the server has its own
        deadline_s = time.monotonic() + SERVER_START_S
        while not all(map(listening, ports)):
            if self.server.poll() is not None or time.monotonic() > deadline_s:
                log.error("rerun's web server did not listen on %s (exit code %s); no web viewer",
                          ports, self.server.poll())  # fmt: skip
                self._stop_server()
                return False
            time.sleep(0.1)
        return True

    def close(self) -> None:
        try:
            if self.recording is not None:
                self.recording.flush()
                self.recording.disconnect()
        except Exception as exc:  # a viewer gone is no fault of the run
            log.warning("the viewer's stream ended early: %s", exc)
        finally:
            self._stop_server()

    def _stop_server(self) -> None:
        if self.server is not None:
            self.server.terminate()
            try:
                self.server.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.server.kill()
                self.server.wait()
            self.server = None


def xyzw(quat_wxyz: np.ndarray) -> rr.Quaternion:
    """A quaternion (w, x, y, z) as Rerun's (x, y, z, w)."""
    return rr.Quaternion(xyzw=np.asarray(quat_wxyz, dtype=float)[[1, 2, 3, 0]])


def geometry_of(model: mujoco.MjModel, geom: int) -> rr.AsComponents | None:
    """One MuJoCo geom as a Rerun primitive in its body's frame; None for a plane or height field."""
    kind, size = mujoco.mjtGeom(model.geom_type[geom]), model.geom_size[geom]
    position, quat_wxyz = model.geom_pos[geom], model.geom_quat[geom]
    rgba = np.round(model.geom_rgba[geom] * 255).astype(np.uint8)
    rotation: np.ndarray = np.empty(9)
    mujoco.mju_quat2Mat(rotation, quat_wxyz)
    rotation = rotation.reshape(3, 3)
    pose: dict[str, Any] = {"quaternions": [xyzw(quat_wxyz)], "colors": [rgba], "fill_mode": "solid"}
    match kind:
        case mujoco.mjtGeom.mjGEOM_BOX:
            return rr.Boxes3D(half_sizes=[size], centers=[position], **pose)
        case mujoco.mjtGeom.mjGEOM_SPHERE | mujoco.mjtGeom.mjGEOM_ELLIPSOID:
            half_sizes = size if kind == mujoco.mjtGeom.mjGEOM_ELLIPSOID else np.full(3, size[0])
            return rr.Ellipsoids3D(half_sizes=[half_sizes], centers=[position], **pose)
        case mujoco.mjtGeom.mjGEOM_CYLINDER:
            return rr.Cylinders3D(lengths=[2 * size[1]], radii=[size[0]], centers=[position], **pose)
        case mujoco.mjtGeom.mjGEOM_CAPSULE:  # Rerun's runs from its origin along +z, MuJoCo's is centred
            start = position - rotation[:, 2] * size[1]
            return rr.Capsules3D(lengths=[2 * size[1]], radii=[size[0]], translations=[start], **pose)
        case mujoco.mjtGeom.mjGEOM_MESH:
            mesh = model.geom_dataid[geom]
            vertex, face = model.mesh_vertadr[mesh], model.mesh_faceadr[mesh]
            vertices = model.mesh_vert[vertex : vertex + model.mesh_vertnum[mesh]]
            faces = model.mesh_face[face : face + model.mesh_facenum[mesh]]
            return rr.Mesh3D(
                vertex_positions=vertices @ rotation.T + position, triangle_indices=faces, albedo_factor=rgba
            )
    return None


class Viewer:
    """Logs what each message shows. Every method takes the message and `stamp_s`, the sender's
    wall clock [s since the epoch], set as the `stamp` timeline (and `sim_time` when the message
    carries the simulated time [s])."""

    def __init__(self, recording: rr.RecordingStream, robot: Robot) -> None:
        """`robot`: the robot shown (description.robot), its model posed from telemetry."""
        self.recording = recording
        self.model = robot_spec(robot).compile()
        self.data = mujoco.MjData(self.model)
        self.joint_qpos = [self.model.joint(name).qposadr[0] for name in robot.arm_joints]
        self.body_paths = ["world"]
        for body in range(1, self.model.nbody):
            parent = self.body_paths[self.model.body_parentid[body]]
            self.body_paths.append(f"{parent}/{rr.escape_entity_path_part(self.model.body(body).name)}")
        self.path_m_world: deque[np.ndarray] = deque(maxlen=PATH_POINTS)
        self.status: dict[str, str] = {}
        self.link_bytes: dict[tuple[str, str], tuple[float, float]] = {}  # -> (stamp [s], bytes)
        self.object_names: set[str] = set()
        self.intervention_phase: tuple[str, str] | None = None  # (target, phase) last logged
        recording.send_blueprint(blueprint())
        recording.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        for geom in range(self.model.ngeom):
            shape = geometry_of(self.model, geom)
            if shape is not None:
                name = self.model.geom(geom).name or f"geom{geom}"
                path = f"{self.body_paths[self.model.geom_bodyid[geom]]}/{rr.escape_entity_path_part(name)}"
                recording.log(path, shape, static=True)

    def _at(self, stamp_s: float, sim_time_s: float | None = None) -> None:
        self.recording.reset_time()
        self.recording.set_time("stamp", timestamp=stamp_s)
        if sim_time_s is not None:
            self.recording.set_time("sim_time", duration=sim_time_s)

    def _scalars(self, prefix: str, values: dict[str, float]) -> None:
        for name, value in values.items():
            self.recording.log(f"{prefix}/{name}", rr.Scalars(value))

    def _status(self, name: str, text: str, level: rr.TextLogLevel) -> None:
        """A line at `status/<name>` when `text` differs from the last one."""
        if self.status.get(name, "") != text:
            self.status[name] = text
            self.recording.log(f"status/{name}", rr.TextLog(text or "cleared", level=level))

    def telemetry(self, t: Telemetry, stamp_s: float) -> None:
        """The vehicle's pose, the arm's links, the tool, the path flown, errors and status."""
        self._at(stamp_s, t.sim_time_s)
        log = self.recording.log
        yaw_quat_wxyz = np.array([math.cos(t.yaw_rad / 2), 0.0, 0.0, math.sin(t.yaw_rad / 2)])
        log("world/vehicle", rr.Transform3D(translation=t.position_m_world, quaternion=xyzw(yaw_quat_wxyz)))
        for path, position, quat_wxyz in self.arm_poses(t.arm_positions_rad):
            log(path, rr.Transform3D(translation=position, quaternion=xyzw(quat_wxyz)))
        log("world/ee", rr.Points3D([t.ee_position_m_world], radii=0.03, colors=[(255, 40, 40)]))
        if not self.path_m_world or np.linalg.norm(t.position_m_world - self.path_m_world[-1]) >= PATH_STEP_M:
            self.path_m_world.append(t.position_m_world)
            log("world/path", rr.LineStrips3D([np.array(self.path_m_world)], colors=[(80, 200, 255)]))
        self._scalars("errors", {
            "vehicle_position_m/distance": t.position_error_m,
            "heading_deg/heading": abs(math.degrees(t.heading_error_rad)),
            "tool_position_mm/distance": float(np.linalg.norm(t.ee_position_error_m_world)) * 1e3,
            "tool_orientation_deg/angle": math.degrees(t.ee_orientation_error_rad),
        })  # fmt: skip
        self._status("failsafe", t.failsafe, rr.TextLogLevel.WARN if t.failsafe else rr.TextLogLevel.INFO)
        mode = f"operator {t.operator_mode}: vehicle {t.mode}, arm {t.arm_mode}"
        self._status("mode", mode, rr.TextLogLevel.INFO)

    def arm_poses(self, arm_positions_rad: np.ndarray) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """Each body below the vehicle: its entity path and pose in its parent's frame (position
        [m], quaternion w, x, y, z) for these joint positions [rad] (model order)."""
        qpos = self.data.qpos
        qpos[:] = self.model.qpos0
        qpos[:7] = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)  # the vehicle's free joint at the identity
        qpos[self.joint_qpos] = arm_positions_rad
        mujoco.mj_kinematics(self.model, self.data)
        poses = []
        for body in range(2, self.model.nbody):  # 0: world, 1: the vehicle
            parent = self.model.body_parentid[body]
            parent_inverse, quat_wxyz = np.empty(4), np.empty(4)
            mujoco.mju_negQuat(parent_inverse, self.data.xquat[parent])
            mujoco.mju_mulQuat(quat_wxyz, parent_inverse, self.data.xquat[body])
            offset = self.data.xpos[body] - self.data.xpos[parent]
            position = self.data.xmat[parent].reshape(3, 3).T @ offset
            poses.append((self.body_paths[body], position, quat_wxyz))
        return poses

    def waypoints(self, w: Waypoints, stamp_s: float) -> None:
        """The waypoints, labelled wp0, wp1 ..., and the route through them."""
        self._at(stamp_s)
        positions = w.waypoints[:, :3]
        self.recording.log(
            "world/mission/waypoints",
            rr.Points3D(positions, radii=0.08, labels=[f"wp{i}" for i in range(len(positions))]),
            rr.LineStrips3D([positions], colors=[(255, 200, 0)]),
        )

    def arm_goal(self, g: ArmGoal, stamp_s: float) -> None:
        """The end-effector goal as a small set of axes."""
        self._at(stamp_s)
        self.recording.log(
            "world/mission/arm_goal",
            rr.Transform3D(translation=g.position_m_world, quaternion=xyzw(g.orientation_wxyz_world)),
            rr.TransformAxes3D(GOAL_AXIS_M),
        )

    def scene(self, centres_m_world: np.ndarray, colors_rgb: np.ndarray, resolution_m: float, stamp_s: float,
              sim_time_s: float) -> None:  # fmt: skip
        """The occupied octree cells [m, world], coloured, as solid voxels of `resolution_m` [m]."""
        self._at(stamp_s, sim_time_s)
        half_sizes = np.full((len(centres_m_world), 3), resolution_m / 2)
        self.recording.log(
            "world/scene/octree",
            rr.Boxes3D(centers=centres_m_world, half_sizes=half_sizes, colors=colors_rgb, fill_mode="solid"),
        )

    def scene_update(
        self, centres_m_world: np.ndarray, colors_rgb: np.ndarray, stamp_s: float, sim_time_s: float
    ) -> None:
        """The cells [m, world] that the latest scene update changed."""
        self._at(stamp_s, sim_time_s)
        self.recording.log("world/scene/latest_update", rr.Points3D(centres_m_world, colors=colors_rgb))

    def objects(self, o: RecognisedObjects, stamp_s: float) -> None:
        """Each recognised object as a box coloured from red (confidence 0) to green (1), with its
        confidence (shown when selected), labelled with its name alone on a point at the top of
        the box: the panel's label above its valves' and levers'. Objects no longer recognised
        are cleared."""
        self._at(stamp_s, o.sim_time_s)
        names = set(o.names)
        for name in self.object_names - names:
            self.recording.log(f"world/objects/{rr.escape_entity_path_part(name)}", rr.Clear(recursive=True))
        self.object_names = names
        for name, pose, half_sizes, confidence in zip(
            o.names, o.poses_world, o.half_sizes_m, o.confidences, strict=True
        ):
            path = f"world/objects/{rr.escape_entity_path_part(name)}"
            rgb = np.round(DOUBTFUL_RGB + np.clip(confidence, 0.0, 1.0) * (CONFIDENT_RGB - DOUBTFUL_RGB))
            rgb = rgb.astype(np.uint8)
            box = rr.Boxes3D(half_sizes=[half_sizes], centers=[pose[:3]], quaternions=[xyzw(pose[3:])],
                             colors=[rgb])  # fmt: skip
            self.recording.log(path, box, rr.AnyValues(confidence=float(confidence)))
            half_height_m = np.abs(rotation_of(pose[3:])[2]) @ half_sizes  # the box's extent along z
            top_m_world = pose[:3] + np.array([0.0, 0.0, half_height_m])
            self.recording.log(f"{path}/label", rr.Points3D([top_m_world], radii=LABEL_POINT_M, colors=[rgb],
                                                             labels=[name], show_labels=True))  # fmt: skip

    def image(self, img: Image, stamp_s: float) -> None:
        """A JPEG frame posed in the world, with its pinhole; other frames are not shown."""
        if img.encoding != "jpeg" or img.pose_frame != "world":
            return
        self._at(stamp_s, img.sim_time_s)
        pose = rr.Transform3D(translation=img.pose_camera[:3], quaternion=xyzw(img.pose_camera[3:]))
        pinhole = rr.Pinhole(focal_length=[img.fx_px, img.fy_px], principal_point=[img.cx_px, img.cy_px],
                             resolution=[img.width_px, img.height_px],
                             camera_xyz=rr.ViewCoordinates.RDF)  # fmt: skip  # OpenCV's axes, as Image's pose
        self.recording.log("world/camera", pose, pinhole)
        self.recording.log("world/camera/image", rr.EncodedImage(contents=img.data, media_type="image/jpeg"))

    def sonar(self, frame: SonarImage, stamp_s: float) -> None:
        """The sonar's fan seen from above, and its first echoes in the world as the arcs they may
        lie on (the sonar measures no elevation); a frame that does not decode is not shown."""
        from abyss.interface.sonar_frames import ECHO_RGB, decode_polar, echo_arcs, fan

        try:
            polar = decode_polar(frame)
            echoes, _ = echo_arcs(frame, SONAR_ARC_SPACING_M)
        except BadInput:
            return
        self._at(stamp_s, frame.sim_time_s)
        self.recording.log("sonar/fan", rr.Image(fan(frame, polar), color_model="L"))
        self.recording.log("world/sonar", rr.Points3D(echoes, radii=0.02, colors=[ECHO_RGB]))

    def perception(self, p: PerceptionStatus, stamp_s: float) -> None:
        """Points per source, the recognition's confidence, and a line when the scene model's
        source changes (the sonar taking over from the cameras)."""
        self._at(stamp_s, p.sim_time_s)
        self._scalars("perception/points_per_s", p.points_per_s)
        self._scalars("perception", {"recognition_confidence": p.recognition_confidence})
        level = rr.TextLogLevel.INFO if p.scene_source == "cameras" else rr.TextLogLevel.WARN
        self._status("perception", f"the scene is mapped from {p.scene_source or 'nothing yet'}", level)

    def link_stats(self, s: LinkStats, stamp_s: float) -> None:
        """Under `links/<hop>/`, per direction: the throughput [kbit/s] since the direction's
        previous report, the delay percentiles [ms] and the cumulative counts of messages lost
        and dropped and packets lost, dropped from the queue and retransmitted."""
        self._at(stamp_s)
        sender, _, receiver = s.direction.partition("->")
        direction = rr.escape_entity_path_part(f"{sender}_to_{receiver}")
        prefix = f"links/{rr.escape_entity_path_part(s.hop)}"
        delivered_bytes = s.stats.get("bytes_delivered")
        previous = self.link_bytes.get((s.hop, s.direction))
        if delivered_bytes is not None:
            self.link_bytes[s.hop, s.direction] = (stamp_s, delivered_bytes)
            if previous is not None and stamp_s > previous[0] and delivered_bytes >= previous[1]:
                throughput_kbps = (delivered_bytes - previous[1]) * 8e-3 / (stamp_s - previous[0])
                self._scalars(f"{prefix}/throughput_kbps", {direction: throughput_kbps})
        for group, series in (("delay_ms", LINK_DELAYS), ("count", LINK_COUNTS)):
            values = {name: s.stats[key] for name, key in series.items() if key in s.stats}
            self._scalars(f"{prefix}/{group}/{direction}", values)

    def intervention(
        self, stamp_s: float, sim_time_s: float, target: str, phase: str, reason: str, turned_deg: float,
        goal_deg: float, opening_mm: float, force_n: float,
    ) -> None:  # fmt: skip
        """The intervention on `target` (a valve or lever): a line at `intervention/phase` when
        the target or its phase changes (a warning for "failed"), with `reason` when given; the
        angle turned and the goal [deg] at `intervention/angle_deg/<target>/`; the gripper's
        opening [mm] and grip force [N] under `intervention/grasp/`."""
        self._at(stamp_s, sim_time_s)
        if self.intervention_phase != (target, phase):
            self.intervention_phase = (target, phase)
            level = rr.TextLogLevel.WARN if phase == "failed" else rr.TextLogLevel.INFO
            text = f"{target}: {phase}" + (f" ({reason})" if reason else "")
            self.recording.log("intervention/phase", rr.TextLog(text, level=level))
        self._scalars(f"intervention/angle_deg/{rr.escape_entity_path_part(target)}",
                      {"turned": turned_deg, "goal": goal_deg})  # fmt: skip
        self._scalars("intervention/grasp", {"opening_mm": opening_mm, "force_n": force_n})
