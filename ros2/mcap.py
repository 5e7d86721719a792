"""A run's recording as one MCAP file in the ROS 2 profile (`abyss export mcap`), by the table
of `ros2.types`: what ROS 2 tools (Foxglove, rerun, `ros2 bag`) open as a rosbag2 recording.

Each schema is `ros2msg` (the message definition with those it uses), each channel `cdr` with
its `offered_qos_profiles` as rosbag2 (Jazzy) writes them. What goes in: each data message once,
as its publisher sent it (`Recording.published()`), and the testbed's observation keys of
`types.OBSERVED`; /tf_static once, first.

Times: `log_time` is when the message was recorded (the publisher's wall clock at its egress,
the testbed's for observation keys), `publish_time` the sender's stamp, both in ns since the
epoch; header stamps are simulated time (see `ros2.types`): a message without its own
`sim_time_s` is stamped with its sender's stamp mapped to simulated time by `SimClock`.
"""

from __future__ import annotations

import json
import logging
import time
from collections import Counter
from collections.abc import Callable, Iterable
from io import StringIO
from pathlib import Path
from typing import Any

import numpy as np
from mcap.writer import CompressionType, Writer
from rosbags.interfaces import Qos
from rosbags.rosbag2.metadata import dump_qos_v9
from ruamel.yaml import YAML

from abyss.common.errors import AbyssError, BadInput
from abyss.description.robot import Robot, robot_at
from abyss.interface.messages import NavState
from abyss.recording.reader import Record, Recording, open_recording
from abyss.ros2 import motion, msgs, types
from abyss.ros2.session import Session

log = logging.getLogger(__name__)

DEFAULT_NAME = "run.mcap"  # in the run directory
PROGRESS_PERIOD_S = 2.0  # at most one progress report per this many seconds
Progress = Callable[[int, int], None]  # (records done, records in all)


class SimClock:
    """Wall-clock stamps [s] to simulated time [s], from the simulation's NavState messages (each
    carries both its sender's stamp and its simulated time): linear between them, at real-time
    rate before the first and after the last; the wall clock itself if there are none."""

    def __init__(self, pairs: Iterable[tuple[float, float]]) -> None:
        wall_sim = np.array(sorted(pairs), float).reshape(-1, 2)
        self.wall_s, self.sim_s = wall_sim[:, 0], wall_sim[:, 1]

    def __call__(self, wall_s: float) -> float:
        if not len(self.wall_s):
            return wall_s
        if wall_s < self.wall_s[0]:
            return float(self.sim_s[0] - (self.wall_s[0] - wall_s))
        if wall_s > self.wall_s[-1]:
            return float(self.sim_s[-1] + (wall_s - self.wall_s[-1]))
        return float(np.interp(wall_s, self.wall_s, self.sim_s))


def qos_yaml(qos: Qos) -> str:
    """`offered_qos_profiles` as rosbag2 (format 9) writes it in its MCAP channels' metadata."""
    stream = StringIO()
    yaml = YAML(typ="safe")
    yaml.default_flow_style = False
    yaml.dump(dump_qos_v9([qos]), stream)
    return stream.getvalue().strip()


def _ns(t_s: float) -> int:
    return max(0, round(t_s * 1e9))


class _Channels:
    """The MCAP schemas and channels, one channel per ROS 2 topic, with a message count each."""

    def __init__(self, writer: Writer) -> None:
        self.writer = writer
        self.schemas: dict[str, int] = {}
        self.ids: dict[str, int] = {}
        self.counts: Counter[str] = Counter()

    def add(self, topic: str, type_name: str, qos: Qos) -> None:
        if topic in self.ids:
            return
        if type_name not in self.schemas:
            self.schemas[type_name] = self.writer.register_schema(
                type_name, "ros2msg", msgs.msgdef(type_name).encode()
            )
        self.ids[topic] = self.writer.register_channel(
            topic, "cdr", self.schemas[type_name], {"offered_qos_profiles": qos_yaml(qos)}
        )
        self.counts[topic] = 0

    def write(self, topic: str, message: Any, log_time_s: float, publish_time_s: float) -> None:
        self.writer.add_message(
            self.ids[topic],
            log_time=_ns(log_time_s),
            data=msgs.serialize(message),
            publish_time=_ns(publish_time_s),
            sequence=self.counts[topic] % 2**32,
        )
        self.counts[topic] += 1


def _exported(recording: Recording) -> list[tuple[Record, types.KeyMap]]:
    """Every record the table maps, in the order they were recorded."""
    chosen = [(r, m) for r in recording.published() + recording.observed() if (m := types.key_map(r.topic))]
    return sorted(chosen, key=lambda rm: rm[0].recorded_s)


def sensor_mounts(recording: Recording) -> dict[str, np.ndarray]:
    """Each sensor's frame and its pose on the vehicle (x, y, z, w, x, y, z: a camera's optical
    axes, the sonar's own), from its first message as the simulation sent it (motion.sensor_mount)."""
    mounts: dict[str, np.ndarray] = {}
    sent = [r for r in recording.published(("simulation",)) if r.message in ("Image", "SonarImage")]
    for _, message in recording.messages(sent):
        if (mount := motion.sensor_mount(message)) is not None:
            mounts.setdefault(*mount)
    return mounts


def sim_clock(recording: Recording) -> SimClock:
    navigation = [
        r
        for r in recording.published(("simulation",)) + recording.observed()
        if r.topic in ("simulation/nav", "simulation/truth")
    ]
    return SimClock(
        (r.sent_s, m.sim_time_s) for r, m in recording.messages(navigation) if isinstance(m, NavState)
    )


def _robot_of_run(run_dir: Path) -> Robot:
    """The robot the run flew: its configuration's (config.json, `simulation.robot`), else the
    shipped one (a run from before robot packages, or one without its configuration)."""
    try:
        package = json.loads((run_dir / "config.json").read_text()).get("simulation", {}).get("robot", "")
    except (OSError, ValueError, AttributeError):
        package = ""
    return robot_at(package if isinstance(package, str) else "")


def export_mcap(run_dir: Path, out: Path, progress: Progress | None = None) -> dict[str, Any]:
    """Write the recording of `run_dir` to `out` (through `out`.part, so that a failed export leaves
    no half file); `progress` is told how far it got, every PROGRESS_PERIOD_S at most. Returns
    what it wrote: topics and their counts, the run's and the export's durations [s], the bytes."""
    started_s = time.perf_counter()
    recording = open_recording(run_dir)
    exported = _exported(recording)
    clock, session = sim_clock(recording), Session(_robot_of_run(run_dir))
    part = out.with_name(out.name + ".part")
    skipped: Counter[str] = Counter()
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        with part.open("wb") as f:
            writer = Writer(f, compression=CompressionType.ZSTD)
            writer.start(profile="ros2", library="abyss export")
            channels = _Channels(writer)
            for r, m in exported:  # every topic first, even one whose messages all fail to convert
                for t in m.exported:
                    channels.add(t.topic(r.topic), t.type, m.qos(t))
            channels.add(types.TF_STATIC, types.TF_MESSAGE, msgs.TF_STATIC_QOS)
            first_s = exported[0][0].recorded_s if exported else time.time()
            static = motion.static_tf(session, clock(first_s), sensor_mounts(recording))
            channels.write(types.TF_STATIC, static, first_s, first_s)
            reported_s = time.monotonic()
            for done, (r, m) in enumerate(exported, 1):
                _write_record(channels, session, clock, r, m, skipped)
                if progress is not None and time.monotonic() - reported_s >= PROGRESS_PERIOD_S:
                    progress(done, len(exported))
                    reported_s = time.monotonic()
            writer.finish()
        part.replace(out)
    except OSError as exc:
        raise AbyssError(
            f"{out}: cannot write the export ({exc.strerror or exc}); give -o a writable path"
        ) from None
    finally:
        part.unlink(missing_ok=True)  # left only by an export that failed
    stamps = [r.recorded_s for r, _ in exported]
    return {
        "file": str(out),
        "topics": dict(sorted(channels.counts.items())),
        "messages": sum(channels.counts.values()),
        "skipped": dict(skipped),
        "run_s": max(stamps) - min(stamps) if stamps else 0.0,
        "export_s": time.perf_counter() - started_s,
        "bytes": out.stat().st_size,
    }


def _write_record(
    channels: _Channels,
    session: Session,
    clock: SimClock,
    r: Record,
    m: types.KeyMap,
    skipped: Counter[str],
) -> None:
    """One recorded message on each of its key's topics; one that does not convert is logged and
    counted in `skipped`."""
    try:
        message = r.decode().message
        if m.message != message.TYPE:
            raise BadInput(f"a {message.TYPE}, the table maps {m.message}")
        stamp_s = types.stamp_of(message, clock(r.sent_s))
        for t in m.exported:
            converted = t.convert(message, msgs.header(stamp_s, t.frame_id), session)
            if converted is not None:
                channels.write(t.topic(r.topic), converted, r.recorded_s, r.sent_s)
    except AbyssError as exc:
        log.warning("%s at %.3f: not exported: %s", r.topic, r.recorded_s, exc)
        skipped[r.topic] += 1
