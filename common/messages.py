"""Message types and their msgpack codec, with validation on both sides.

A message on the wire is a msgpack map: `type` (name), `version` (schema version),
`seq` (per-key sequence number), `stamp_s` (sender's wall clock [s]) and `body` (the
fields). numpy arrays travel as `{dtype, shape, data}` with raw little-endian bytes. A class
with `COMPRESSED` (the scene stream, whose bytes go over the satellite) sends that map as one
zstd frame (content size and checksum in its header); `decode` takes either form, a frame
announcing more than `MAX_DECOMPRESSED_BYTES` refused before anything is allocated.
`decode()` checks the type, the version, every field's type, dtype, shape, range and
finiteness, and raises `BadMessage` with the reason; nothing malformed gets further.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import secrets
import threading
import typing
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, NamedTuple

import msgpack
import numpy as np
import zstandard

from abyss.common.errors import BadMessage

MESSAGES: dict[str, type[Message]] = {}
ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"  # a frame's first bytes; an envelope's first is a msgpack map's (0x85)
ZSTD_LEVEL = 19  # the satellite's bytes are dearer than the vessel's milliseconds (a 16 kB update: ~10 ms)
MAX_DECOMPRESSED_BYTES = 64 * 2**20
_zstd = threading.local()  # a compressor and a decompressor per thread: zstd's contexts are not shared
# What every compressed message repeats, given to zstd as a raw-content dictionary: the envelope's
# and the scene update's names and OctoMap's binary header (an update of a few hundred bytes would
# otherwise carry some 250 bytes of them). A constant, not built from a live tree: both ends must
# hold the same bytes whatever their OctoMap.
ZSTD_DICTIONARY = msgpack.packb(
    [
        "type",
        "version",
        "seq",
        "stamp_s",
        "body",
        "SceneUpdate",
        "kind",
        "snapshot",
        "delta",
        "scene_seq",
        "resolution_m",
        "octree",
        "colors",
        "dtype",
        "|u1",
        "shape",
        "data",
        "sim_time_s",
        "stream_id",
    ]
) + (
    b"# Octomap OcTree binary file\n# (feel free to add / change comments, but leave the first line as "
    b"it is!)\n#\nid OcTree\nsize \nres 0.1\ndata\n"
)
SMALL_ARRAY_SIZE = 64  # an array up to this size is range-checked as Python numbers (numpy's calls cost more)


def array(
    dtype: str,
    shape: tuple[int | None, ...],
    lo: float = -math.inf,
    hi: float = math.inf,
    max_rows: int = 100_000,
) -> Any:
    """A numpy array field: fixed dtype, shape (None: any length up to max_rows), range."""
    return field(
        metadata={"dtype": np.dtype(dtype), "shape": shape, "lo": lo, "hi": hi, "max_rows": max_rows}
    )


def scalar(lo: float = -math.inf, hi: float = math.inf, choices: tuple[str, ...] = ()) -> Any:
    return field(metadata={"lo": lo, "hi": hi, "choices": choices})


def blob(max_bytes: int) -> Any:
    """A bytes field of at most `max_bytes`."""
    return field(metadata={"max_bytes": max_bytes})


def _check_number(name: str, kind: type[int] | type[float], lo: float, hi: float, value: Any) -> Any:
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if not isinstance(value, kind) or isinstance(value, bool):
        raise ValueError(f"{name}: expected {kind.__name__}, got {type(value).__name__}")
    if kind is float and not math.isfinite(value):
        raise ValueError(f"{name}: not finite ({value})")
    if not lo <= value <= hi:
        raise ValueError(f"{name}: {value} outside [{lo}, {hi}]")
    return value


def _plainly_within(value: np.ndarray, lo: float, hi: float) -> bool:
    """True if a small array's values are all finite and in [lo, hi], told without numpy's calls; False
    for a large array or one in doubt (a NaN, an infinity, a sum that overflows), which the full checks
    then judge."""
    if value.size > SMALL_ARRAY_SIZE:
        return False
    values = (value if value.ndim == 1 else value.ravel()).tolist()
    return not values or (math.isfinite(sum(values)) and lo <= min(values) and max(values) <= hi)


def _check_array(name: str, meta: Mapping[str, Any], value: Any) -> np.ndarray:
    if not isinstance(value, np.ndarray):
        value = np.asarray(value, dtype=meta["dtype"])
    if value.dtype != meta["dtype"]:
        raise ValueError(f"{name}: dtype {value.dtype}, expected {meta['dtype']}")
    shape = meta["shape"]
    if value.shape != shape and (
        value.ndim != len(shape)
        or any(want is not None and got != want for got, want in zip(value.shape, shape, strict=True))
    ):
        raise ValueError(f"{name}: shape {value.shape}, expected {shape} (None: any)")
    if value.ndim and value.shape[0] > meta["max_rows"]:
        raise ValueError(f"{name}: {value.shape[0]} rows, at most {meta['max_rows']}")
    if not _plainly_within(value, meta["lo"], meta["hi"]):
        if value.dtype.kind == "f" and not np.all(np.isfinite(value)):
            raise ValueError(f"{name}: contains NaN or infinity")
        if value.size and (value.min() < meta["lo"] or value.max() > meta["hi"]):
            raise ValueError(f"{name}: values outside [{meta['lo']}, {meta['hi']}]")
    return _frozen(value)


def _frozen(value: np.ndarray) -> np.ndarray:
    """`value` itself if it is a view of bytes (as decoded: no one can change it), else a read-only copy."""
    base = value.base
    while isinstance(base, np.ndarray):
        base = base.base
    if isinstance(base, bytes):
        return value
    value = np.array(value, copy=True)
    value.flags.writeable = False
    return value


Check = Callable[[Any], Any]  # a field's value -> the value checked (an array: read-only); raises ValueError


def _checker(name: str, kind: Any, meta: Mapping[str, Any]) -> Check:
    """The check of field `name` of type `kind`, chosen once per message class."""
    if kind is np.ndarray:
        return functools.partial(_check_array, name, meta)
    if kind in (float, int):
        lo, hi = meta.get("lo", -math.inf), meta.get("hi", math.inf)
        return functools.partial(_check_number, name, kind, lo, hi)
    return functools.partial(_check_field, name, kind, meta)


def _check_field(name: str, kind: Any, meta: Mapping[str, Any], value: Any) -> Any:
    if kind is bytes:
        if not isinstance(value, bytes) or len(value) > meta.get("max_bytes", 16 * 2**20):
            raise ValueError(f"{name}: expected at most {meta.get('max_bytes', 16 * 2**20)} bytes")
        return value
    if kind is bool:
        if not isinstance(value, bool):
            raise ValueError(f"{name}: expected bool, got {type(value).__name__}")
        return value
    if kind is str:
        if not isinstance(value, str) or len(value) > 4096:
            raise ValueError(f"{name}: expected a string of at most 4096 characters")
        if meta.get("choices") and value not in meta["choices"]:
            raise ValueError(f"{name}: {value!r} not one of {meta['choices']}")
        return value
    if typing.get_origin(kind) is tuple:  # tuple[str, ...]
        if not isinstance(value, (list, tuple)) or len(value) > 256:
            raise ValueError(f"{name}: expected a list of at most 256 strings")
        return tuple(_check_field(f"{name}[{i}]", str, {}, v) for i, v in enumerate(value))
    if typing.get_origin(kind) is dict:
        value_kind = typing.get_args(kind)[1]
        if not isinstance(value, dict) or len(value) > 256:
            raise ValueError(f"{name}: expected a map of at most 256 entries")
        return {
            _check_field(f"{name} key", str, {}, k): _checker(f"{name}[{k}]", value_kind, {})(v)
            for k, v in value.items()
        }
    raise TypeError(f"{name}: unsupported field type {kind}")


class _Schema(NamedTuple):
    """What checking and coding a message class needs, read from its dataclass fields once."""

    checks: tuple[tuple[str, Check], ...]  # each field's name and check, in order
    names: frozenset[str]
    arrays: dict[str, dict[str, Any]]  # the array fields' metadata, with how they travel (`_wire`)


def _wire(meta: Mapping[str, Any]) -> dict[str, Any]:
    """An array field's metadata, with its dtype as it travels (little-endian) and that dtype's name."""
    wire_dtype = meta["dtype"].newbyteorder("<")
    return {**meta, "wire_dtype": wire_dtype, "wire_str": wire_dtype.str}


def _read_schema(cls: type) -> _Schema:
    hints = typing.get_type_hints(cls)
    fields = dataclasses.fields(cls)
    return _Schema(
        tuple((f.name, _checker(f.name, hints[f.name], dict(f.metadata))) for f in fields),
        frozenset(f.name for f in fields),
        {f.name: _wire(f.metadata) for f in fields if hints[f.name] is np.ndarray},
    )


# Per message class, cached. Typed as taking any class: mypy holds a frozen dataclass's class
# object unhashable (it reads the instances' __hash__), so functools.cache's Hashable arguments
# would refuse type[Message].
_schema: Callable[[type], _Schema] = functools.cache(_read_schema)


@dataclass(frozen=True)
class Message:
    """Base of every message: a frozen dataclass validated on construction."""

    TYPE: ClassVar[str] = ""
    VERSION: ClassVar[int] = 1
    COMPRESSED: ClassVar[bool] = False  # sent as one zstd frame

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        cls.TYPE = cls.__name__
        MESSAGES[cls.TYPE] = cls

    def __post_init__(self) -> None:
        for name, check in _schema(type(self)).checks:
            object.__setattr__(self, name, check(getattr(self, name)))


@dataclass(frozen=True)
class NavState(Message):
    """Vehicle navigation state. The simulation's truth on its truth key; on `simulation/nav`
    (simulation -> onboard), what the sensors last gave: the latest USBL fix delivered (taken at
    `usbl_time_s`, delivered later; repeated until the next), the IMU's attitude and rates, the
    DVL's velocity (meaningless without bottom lock: `dvl_valid`) and the pressure sensor's depth,
    each as of `sim_time_s`."""

    VERSION: ClassVar[int] = 2  # 2: usbl_time_s, depth_m, dvl_valid

    position_m_world: np.ndarray = array("f8", (3,), -1e5, 1e5)
    orientation_wxyz_world: np.ndarray = array("f8", (4,), -1.0, 1.0)
    velocity_mps_body: np.ndarray = array("f8", (3,), -100.0, 100.0)
    angular_velocity_radps_body: np.ndarray = array("f8", (3,), -100.0, 100.0)
    sim_time_s: float = scalar(0.0)
    # when the position was measured [s, simulated]; -1: no fix yet (the position means nothing)
    usbl_time_s: float = field(default=-1.0, metadata={"lo": -1.0, "hi": math.inf, "choices": ()})
    # [m] below the surface, from the pressure
    depth_m: float = field(default=0.0, metadata={"lo": -100.0, "hi": 11000.0, "choices": ()})
    dvl_valid: bool = True  # the DVL has bottom lock

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_unit_quaternion(self.orientation_wxyz_world)


def _check_unit_quaternion(quat_wxyz: np.ndarray) -> None:
    norm = math.hypot(*quat_wxyz.tolist())
    if abs(norm - 1.0) > 1e-3:
        raise ValueError(f"orientation_wxyz_world: not a unit quaternion (norm {norm:.4f})")


@dataclass(frozen=True)
class VelocityRef(Message):
    """Vehicle velocity reference in the body frame, onboard -> simulation."""

    linear_mps_body: np.ndarray = array("f8", (3,), -10.0, 10.0)
    yaw_rate_radps: float = scalar(-5.0, 5.0)


@dataclass(frozen=True)
class ArmVelocityRef(Message):
    """Arm joint velocity references (model order: common.models.ARM_JOINTS) and the
    gripper's opening speed; onboard -> simulation."""

    joint_velocities_radps: np.ndarray = array("f8", (6,), -5.0, 5.0)
    gripper_velocity_mps: float = scalar(-0.5, 0.5)


@dataclass(frozen=True)
class JointState(Message):
    """Arm joint positions and velocities (model order), the gripper's opening (the two fingers'
    travel, summed) and the force its motors squeeze with (as a real gripper reports from its
    motor current; 0 with the kinematic low level); simulation -> onboard."""

    VERSION: ClassVar[int] = 2  # 2: gripper_force_n

    positions_rad: np.ndarray = array("f8", (6,), -10.0, 10.0)
    velocities_radps: np.ndarray = array("f8", (6,), -100.0, 100.0)
    gripper_opening_m: float = scalar(0.0, 1.0)
    sim_time_s: float = scalar(0.0)
    gripper_force_n: float = field(default=0.0, metadata={"lo": 0.0, "hi": 1e4, "choices": ()})


IMAGE_ENCODINGS = ("jpeg", "png16")
POSE_FRAMES = ("vehicle", "world")


@dataclass(frozen=True)
class Image(Message):
    """A camera frame: RGB as JPEG, depth as 16-bit PNG in millimetres. Intrinsics of the
    pinhole model [px]; `pose_camera`: the camera's pose in `pose_frame`, x, y, z [m] and
    quaternion w, x, y, z, camera axes as OpenCV's (x right, y down, z forward). The simulation
    sends the pose in the vehicle frame (its mounting); onboard, which knows where the vehicle
    was when the frame was taken, sends it on in the world frame."""

    camera: str = scalar()
    encoding: str = scalar(choices=IMAGE_ENCODINGS)
    pose_frame: str = scalar(choices=POSE_FRAMES)
    width_px: int = scalar(1, 8192)
    height_px: int = scalar(1, 8192)
    fx_px: float = scalar(1e-3, 1e6)
    fy_px: float = scalar(1e-3, 1e6)
    cx_px: float = scalar(0.0, 8192.0)
    cy_px: float = scalar(0.0, 8192.0)
    pose_camera: np.ndarray = array("f8", (7,), -1e5, 1e5)
    data: bytes = blob(32 * 2**20)
    sim_time_s: float = scalar(0.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_unit_quaternion(self.pose_camera[3:])


SONAR_ENCODINGS = ("png8", "jpeg")


@dataclass(frozen=True)
class SonarImage(Message):
    """An imaging sonar's polar image, as a sonar's driver sends it: rows are `bins` range bins
    from 0 to `range_max_m` (nearest first), columns `beams` bearings evenly across
    `horizontal_fov_rad` from port to starboard; a grey level is the echo's strength in decibels,
    0 at the noise floor and 255 at `dynamic_range_db` above it. Each echo may come from anywhere
    within `vertical_aperture_rad` about the middle beam: the image holds no elevation.
    `pose_sonar`: the sonar's pose in `pose_frame`, x, y, z [m] and quaternion w, x, y, z, its axes
    x along the middle beam, y to port, z up; the simulation sends it in the vehicle frame (the
    mounting), onboard on in the world frame, as a camera's."""

    sonar: str = scalar()
    encoding: str = scalar(choices=SONAR_ENCODINGS)
    pose_frame: str = scalar(choices=POSE_FRAMES)
    beams: int = scalar(1, 4096)
    bins: int = scalar(1, 8192)
    range_max_m: float = scalar(0.1, 1000.0)
    horizontal_fov_rad: float = scalar(1e-3, 2.0 * math.pi)
    vertical_aperture_rad: float = scalar(1e-3, math.pi)
    dynamic_range_db: float = scalar(1.0, 200.0)
    pose_sonar: np.ndarray = array("f8", (7,), -1e5, 1e5)
    data: bytes = blob(8 * 2**20)
    sim_time_s: float = scalar(0.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_unit_quaternion(self.pose_sonar[3:])


CLOUD_SOURCES = ("depth", "stereo")
CLOUD_POINT_BYTES = 9  # x, y, z as int16 and r, g, b as uint8


@dataclass(frozen=True)
class PointCloud(Message):
    """A coloured point cloud in the world frame, quantised and compressed (common.clouds):
    each point as three int16 multiples of `scale_m` from `origin_m_world` and an RGB colour,
    the whole zlib-compressed. `sensor_m_world`: where the rays began, for ray casting."""

    source: str = scalar(choices=CLOUD_SOURCES)
    count: int = scalar(0, 2_000_000)
    scale_m: float = scalar(1e-4, 1.0)
    origin_m_world: np.ndarray = array("f8", (3,), -1e5, 1e5)
    sensor_m_world: np.ndarray = array("f8", (3,), -1e5, 1e5)
    data: bytes = blob(32 * 2**20)
    sim_time_s: float = scalar(0.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        expected = self.count * CLOUD_POINT_BYTES
        try:
            raw = zlib.decompressobj().decompress(self.data, expected + 1)
        except zlib.error as exc:
            raise ValueError(f"data: not zlib ({exc})") from None
        if len(raw) != expected:
            raise ValueError(f"data: {len(raw)} bytes decompressed; {self.count} points need {expected}")


SCENE_KINDS = ("snapshot", "delta")


@dataclass(frozen=True)
class SceneUpdate(Message):
    """The vessel's occupancy octree to shore, as OctoMap's binary stream (`octree`: what
    `OcTree::writeBinary` writes, header included): a snapshot holds every known leaf, a delta
    the leaves that changed since update `scene_seq - 1`. `colors`: RGB of the occupied leaves,
    in the order OctoMap's leaf iterator visits the tree that `octree` decodes to. `stream_id`
    is new with each scene model (a restarted vessel starts a new stream at `scene_seq` 0)."""

    VERSION: ClassVar[int] = 3  # 2: stream_id; 3: sent as a zstd frame
    COMPRESSED: ClassVar[bool] = True

    kind: str = scalar(choices=SCENE_KINDS)
    scene_seq: int = scalar(0, 2**53)
    resolution_m: float = scalar(1e-3, 10.0)
    octree: bytes = blob(16 * 2**20)
    colors: np.ndarray = array("u1", (None, 3), 0, 255, max_rows=2_000_000)
    sim_time_s: float = scalar(0.0)
    stream_id: int = field(default=0, metadata={"lo": 0, "hi": 2**53, "choices": ()})


@dataclass(frozen=True)
class SceneRequest(Message):
    """Shore asks the vessel for a snapshot: it missed an update, or has none yet."""

    last_seq: int = scalar(-1, 2**53)  # the last update applied on shore; -1: none
    reason: str = scalar()


@dataclass(frozen=True)
class SceneAck(Message):
    """Shore received scene update `scene_seq` (applied or not): the vessel paces its stream
    by these, end to end, as a real sender must."""

    scene_seq: int = scalar(0, 2**53)


@dataclass(frozen=True)
class RecognisedObjects(Message):
    """What the vessel recognised: per object a name, its pose in the world frame (x, y, z [m],
    quaternion w, x, y, z), half sizes [m] and a confidence in [0, 1]. `method` says what found
    the panel: "texture" (markers, PnP), "shape" (plane and ICP) or "texture+shape" (fused)."""

    names: tuple[str, ...] = scalar()
    poses_world: np.ndarray = array("f8", (None, 7), -1e5, 1e5, max_rows=256)
    half_sizes_m: np.ndarray = array("f8", (None, 3), 0.0, 100.0, max_rows=256)
    confidences: np.ndarray = array("f8", (None,), 0.0, 1.0, max_rows=256)
    method: str = scalar()
    sim_time_s: float = scalar(0.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        if not len(self.names) == len(self.poses_world) == len(self.half_sizes_m) == len(self.confidences):
            raise ValueError("names, poses_world, half_sizes_m and confidences differ in length")


PERCEPTION_SOURCES = (*CLOUD_SOURCES, "sonar")
SCENE_SOURCES = ("", "cameras", "sonar")


@dataclass(frozen=True)
class PerceptionStatus(Message):
    """What the vessel's perception has to work with, vessel -> onshore: per source (the
    cameras' clouds, depth and stereo, and the sonar's echoes) the points it received over the
    last `window_s` [points/s]; what the scene model maps from now (`scene_source`: "cameras",
    or "sonar" while the cameras' clouds bring no point, "" before either); the recognised
    panel's confidence now and what found it (RecognisedObjects.method; "" while not found)."""

    points_per_s: dict[str, float]
    window_s: float = scalar(0.1, 3600.0)
    scene_source: str = scalar(choices=SCENE_SOURCES)
    recognition_confidence: float = scalar(0.0, 1.0)
    recognition_method: str = scalar()
    sim_time_s: float = scalar(0.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        for source, rate in self.points_per_s.items():
            if source not in PERCEPTION_SOURCES or not 0.0 <= rate <= 1e9:
                raise ValueError(
                    f"points_per_s: {source!r}: {rate} (sources "
                    f"{', '.join(PERCEPTION_SOURCES)}, rates in [0, 1e9])"
                )


FAULTS = ("thruster", "camera", "noise", "seize", "clear")


@dataclass(frozen=True)
class SimulationControl(Message):
    """A fault injected into the simulation (scenario runner, tests):
    thruster NAME VALUE: that thruster's efficiency (0: failed, 0.5: weakened, 1: healthy);
    camera NAME VALUE: 0 blacks the camera out, 1 restores it; noise SENSOR VALUE: that
    navigation sensor's noise scale (usbl, depth, dvl, imu; 1 is nominal); seize PART VALUE: 1
    seizes that valve or lever where it stands (it turns no further), 0 frees it; clear: undo all."""

    fault: str = scalar(choices=FAULTS)
    target: str = scalar()
    value: float = scalar(0.0, 100.0)


@dataclass(frozen=True)
class SimulationStatus(Message):
    """The simulation's clock against the wall clock, and the active faults; with simulated time,
    the wall seconds it waited on each station (`held_s`: the one that limited the speed)."""

    VERSION: ClassVar[int] = 2  # 2: held_s
    sim_time_s: float = scalar(0.0)
    realtime_factor: float = scalar(0.0, 1e6)
    deadlines_met: float = scalar(0.0, 1.0)  # share of control periods that kept their deadline
    faults: dict[str, float] = field(default_factory=dict)
    held_s: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class SimTime(Message):
    """Simulated time (common.clock): the simulation's clock on `abyss/<system>/clock`, a
    station's progress (how far its loops are done) on `abyss/<system>/<station>/progress`."""

    sim_time_s: float = scalar(0.0)


LOCKSTEP_PHASES = ("delivered", "done")


@dataclass(frozen=True)
class LockstepReport(Message):
    """A station's progress through a lockstep period (common.lockstep) at `sim_time_s`: its links
    delivered what was due (`delivered`: messages per key so far), or it is done with the period."""

    sim_time_s: float = scalar(0.0)
    phase: str = scalar(choices=LOCKSTEP_PHASES)
    delivered: dict[str, float] = field(default_factory=dict)


MODES = ("idle", "moving", "reached", "hold", "missed")  # missed: a waypoint not reached in its time
# hold: the vehicle holds station and the arm holds still; auto: the goals are flown, the arm
# once the vehicle holds its last waypoint; teleop: the goals are flown, the arm at once
OPERATOR_MODES = ("hold", "auto", "teleop")
COMMANDS = ("waypoints", "arm", "mode", "intervene")  # what an operator command sets
LEVER_STOPS = ("up", "down")
# an intervention's phases, in order; it ends done or failed (its reason says why); "" none yet
INTERVENTION_PHASES = ("", "approach", "pre-grasp", "grasp", "turn", "release", "retreat", "done", "failed")
REFINABLE_PHASES = ("approach", "pre-grasp")  # before the fingers close: a goal resent is a refinement


@dataclass(frozen=True)
class Telemetry(Message):
    """The onboard controllers' state, onboard -> vessel -> onshore. Errors are goal minus
    estimate: position in the world frame [m], heading [rad], the end-effector's position [m,
    world] and orientation (angle of the rotation from the estimate to the goal) [rad]. `mode`
    is the vehicle's, `arm_mode` the arm's; `failsafe` names why both hold ('' when they don't);
    `boot_id` is new each time onboard starts, so that shore sees a reboot and hands the goals
    in force again. The intervention (`intervention_*`, -1 and "" when none): the part, the
    phase and why it failed; how far onboard has turned it [rad], of the goal; the gripper as
    the low level reports it."""

    VERSION: ClassVar[int] = 3  # 2: boot_id; 3: the intervention

    position_m_world: np.ndarray = array("f8", (3,), -1e5, 1e5)
    yaw_rad: float = scalar(-math.pi - 1e-6, math.pi + 1e-6)
    mode: str = scalar(choices=MODES)
    command_id: int = scalar(-1, 2**53)  # the waypoint list being flown; -1: none yet
    waypoint_index: int = scalar(0, 1000)
    waypoints_total: int = scalar(0, 1000)
    position_error_m_world: np.ndarray = array("f8", (3,), -1e5, 1e5)
    heading_error_rad: float = scalar(-math.pi - 1e-6, math.pi + 1e-6)
    arm_mode: str = scalar(choices=MODES)
    arm_command_id: int = scalar(-1, 2**53)  # the end-effector goal being reached; -1: none
    ee_position_error_m_world: np.ndarray = array("f8", (3,), -1e5, 1e5)
    ee_orientation_error_rad: float = scalar(0.0, math.pi + 1e-6)
    ee_position_m_world: np.ndarray = array("f8", (3,), -1e5, 1e5)  # where onboard sees the tool
    ee_orientation_wxyz_world: np.ndarray = array("f8", (4,), -1.0 - 1e-6, 1.0 + 1e-6)
    arm_positions_rad: np.ndarray = array("f8", (6,), -10.0, 10.0)  # model order
    failsafe: str = scalar()  # why the vehicle and arm hold; empty when they do not
    failsafe_events: int = scalar(0, 2**31)
    sim_time_s: float = scalar(0.0)
    operator_mode: str = field(default="auto", metadata={"choices": OPERATOR_MODES})
    boot_id: int = field(default=0, metadata={"lo": 0, "hi": 2**53, "choices": ()})
    intervention_id: int = field(default=-1, metadata={"lo": -1, "hi": 2**53, "choices": ()})
    intervention_target: str = ""
    intervention_phase: str = field(default="", metadata={"choices": INTERVENTION_PHASES})
    intervention_reason: str = ""
    turned_rad: float = field(default=0.0, metadata={"lo": -10.0, "hi": 10.0, "choices": ()})
    turn_goal_rad: float = field(default=0.0, metadata={"lo": -10.0, "hi": 10.0, "choices": ()})
    gripper_opening_m: float = field(default=0.0, metadata={"lo": 0.0, "hi": 1.0, "choices": ()})
    gripper_force_n: float = field(default=0.0, metadata={"lo": 0.0, "hi": 1e4, "choices": ()})

    @property
    def position_error_m(self) -> float:
        return float(np.linalg.norm(self.position_error_m_world))


@dataclass(frozen=True)
class ArmGoal(Message):
    """An end-effector pose goal: position [m] and orientation (w, x, y, z) in the world frame;
    onshore -> vessel -> onboard."""

    command_id: int = scalar(0, 2**53)
    position_m_world: np.ndarray = array("f8", (3,), -1e5, 1e5)
    orientation_wxyz_world: np.ndarray = array("f8", (4,), -1.0 - 1e-6, 1.0 + 1e-6)

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_unit_quaternion(self.orientation_wxyz_world)


@dataclass(frozen=True)
class Intervention(Message):
    """An operator's intent on a part of the panel (common.models.panel): turn valve `target` by
    `turn_rad`, or throw lever `target` to its stop `to` (up or down); onshore -> vessel, which
    resolves the part from the panel it recognised."""

    command_id: int = scalar(0, 2**53)
    target: str = scalar()
    turn_rad: float = scalar(-2 * math.pi, 2 * math.pi)  # a valve's; 0 for a lever
    to: str = scalar(choices=("", *LEVER_STOPS))  # a lever's; "" for a valve


@dataclass(frozen=True)
class InterventionGoal(Message):
    """An intervention resolved in the world frame (vessel -> onboard): the part's pivot [m] and
    rotation axis (unit), the tool point's grasp pose (position [m], orientation w, x, y, z), and
    the turn about the axis [rad, signed, from the grasp]; `to_stop`: the turn ends at a
    mechanical stop (a lever thrown), where the part stopping is success, not a fault."""

    command_id: int = scalar(0, 2**53)
    target: str = scalar()
    pivot_m_world: np.ndarray = array("f8", (3,), -1e5, 1e5)
    axis_world: np.ndarray = array("f8", (3,), -1.0 - 1e-6, 1.0 + 1e-6)
    grasp_m_world: np.ndarray = array("f8", (3,), -1e5, 1e5)
    grasp_orientation_wxyz_world: np.ndarray = array("f8", (4,), -1.0 - 1e-6, 1.0 + 1e-6)
    turn_rad: float = scalar(-2 * math.pi, 2 * math.pi)
    to_stop: bool = False

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_unit_quaternion(self.grasp_orientation_wxyz_world)
        if abs(float(np.linalg.norm(self.axis_world)) - 1.0) > 1e-3:
            raise ValueError("axis_world: not a unit vector")


@dataclass(frozen=True)
class PanelState(Message):
    """The simulation's truth of the panel, for scoring only: each valve's and lever's joint
    angle [rad], and the normal force [N] of the fingers' contacts with each (0: untouched)."""

    names: tuple[str, ...] = scalar()
    angles_rad: np.ndarray = array("f8", (None,), -10.0, 10.0, max_rows=64)
    finger_force_n: np.ndarray = array("f8", (None,), 0.0, 1e6, max_rows=64)
    sim_time_s: float = scalar(0.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        if not len(self.names) == len(self.angles_rad) == len(self.finger_force_n):
            raise ValueError("names, angles_rad and finger_force_n differ in length")


@dataclass(frozen=True)
class Heartbeat(Message):
    """The vessel's heartbeat to onboard: goals keep flowing, and whether shore is heard
    (the satellite link is up). Onboard holds station when it stops or shore is lost."""

    shore_silence_s: float = scalar(0.0)  # since shore was last heard [s]
    shore_heard: bool = True


def new_id() -> int:
    """An id that no other of its kind has (a command, a station's boot, a scene stream): 53
    random bits (the ids' range). Ids from the clock (milliseconds) collided when two tools
    sent in the same one."""
    return _ids[0]()


def _random_id() -> int:
    return secrets.randbelow(2**53 - 1) + 1


_ids: list[Callable[[], int]] = [_random_id]


def repeatable_ids(seed: Sequence[int]) -> None:
    """This process's ids from a stream of `seed` from now on (lockstep: a run repeats, its ids
    too; the seed holds the station and its boot, so that a restart still differs)."""
    rng = np.random.default_rng(list(seed))
    _ids[0] = lambda: int(rng.integers(1, 2**53))


@dataclass(frozen=True)
class Waypoints(Message):
    """A list of waypoints, rows of x, y, z [m, world] and yaw [rad]; onshore -> vessel -> onboard."""

    command_id: int = scalar(0, 2**53)
    waypoints: np.ndarray = array("f8", (None, 4), -1e5, 1e5, max_rows=1000)


@dataclass(frozen=True)
class OperatorMode(Message):
    """The operator's control mode (see OPERATOR_MODES); onshore -> vessel -> onboard."""

    command_id: int = scalar(0, 2**53)
    mode: str = scalar(choices=OPERATOR_MODES)


@dataclass(frozen=True)
class CommandAck(Message):
    """Onboard's answer to an operator command: taken, or refused and why; onboard -> vessel
    -> onshore. A command sent again is answered again, the same way."""

    command_id: int = scalar(0, 2**53)
    command: str = scalar(choices=COMMANDS)
    reason: str = scalar()  # why it was refused; '' when taken

    @property
    def accepted(self) -> bool:
        return not self.reason


@dataclass(frozen=True)
class LinkControl(Message):
    """A change of a hop's profile: a named profile, then field overrides ('20mbit', '5%')."""

    profile: str = ""
    overrides: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class LinkStats(Message):
    """What one emulated link direction measured."""

    hop: str = ""
    direction: str = ""  # "<sender>-><receiver>"
    profile: str = ""
    fields: dict[str, str] = field(default_factory=dict)  # the profile as written
    stats: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class MissionStatus(Message):
    """The mission as the operator sees it from the telemetry that reached shore."""

    VERSION: ClassVar[int] = 2  # 2: the interventions

    mode: str = scalar(choices=MODES)
    waypoint_index: int = scalar(0, 1000)
    waypoints_total: int = scalar(0, 1000)
    position_error_m: float = scalar(0.0)
    heading_error_rad: float = scalar(0.0, math.pi + 1e-6)
    arm_mode: str = scalar(choices=MODES)
    ee_position_error_m: float = scalar(0.0)
    ee_orientation_error_rad: float = scalar(0.0, math.pi + 1e-6)
    failsafe: str = scalar()  # why the vehicle and arm hold; empty when they do not
    failsafe_events: int = scalar(0, 2**31)
    done: bool = False
    interventions_done: int = field(default=0, metadata={"lo": 0, "hi": 1000, "choices": ()})
    interventions_total: int = field(default=0, metadata={"lo": 0, "hi": 1000, "choices": ()})
    intervention_target: str = ""  # the one in hand, or the last
    intervention_phase: str = field(default="", metadata={"choices": INTERVENTION_PHASES})
    intervention_reason: str = ""  # why it failed


@dataclass(frozen=True)
class ReplayStart(Message):
    """When the replayed stations begin (`abyss replay`): the recorded run's first message is
    published again at `start_s` (wall clock [s]), the rest at their recorded times after it."""

    start_s: float = scalar(0.0)


def _pack(value: Any, array: Mapping[str, Any] | None) -> Any:
    """A field's value as it travels; an array (`array`: its field's metadata) as its map, little-endian."""
    if array is None:
        return value
    wire_dtype = array["wire_dtype"]
    little = value if value.dtype == wire_dtype else value.astype(wire_dtype)
    return {"dtype": array["wire_str"], "shape": list(value.shape), "data": little.tobytes()}


def encode(message: Message, seq: int, stamp_s: float) -> bytes:
    schema = _schema(type(message))
    body = {name: _pack(getattr(message, name), schema.arrays.get(name)) for name, _ in schema.checks}
    packed = msgpack.packb(
        {"type": message.TYPE, "version": message.VERSION, "seq": seq, "stamp_s": stamp_s, "body": body},
        use_bin_type=True,
    )
    if not message.COMPRESSED:
        return packed
    if not hasattr(_zstd, "compressor"):
        _zstd.compressor = zstandard.ZstdCompressor(
            level=ZSTD_LEVEL, write_checksum=True, dict_data=_dictionary()
        )
    return _zstd.compressor.compress(packed)


def wire_bytes(message: Message) -> int:
    """What `message` takes on the wire, compressed where its class is (envelope included, give or
    take the few bytes its sequence number and stamp take)."""
    return len(encode(message, 0, 0.0))


def _dictionary() -> zstandard.ZstdCompressionDict:
    return zstandard.ZstdCompressionDict(ZSTD_DICTIONARY, dict_type=zstandard.DICT_TYPE_RAWCONTENT)


def unwrap(data: bytes) -> bytes:
    """An encoded message's msgpack map: `data` itself, or the zstd frame's content. ValueError
    on a frame that does not decompress, or announces more than MAX_DECOMPRESSED_BYTES."""
    if not data.startswith(ZSTD_MAGIC):
        return data
    try:
        size = zstandard.frame_content_size(data)
    except zstandard.ZstdError as exc:
        raise ValueError(f"not a zstd frame: {exc}") from None
    if not 0 <= size <= MAX_DECOMPRESSED_BYTES:
        raise ValueError(f"a zstd frame of {size} bytes (at most {MAX_DECOMPRESSED_BYTES}; -1: unsaid)")
    if not hasattr(_zstd, "decompressor"):
        _zstd.decompressor = zstandard.ZstdDecompressor(dict_data=_dictionary())
    try:
        return _zstd.decompressor.decompress(data)
    except zstandard.ZstdError as exc:
        raise ValueError(f"a zstd frame that does not decompress: {exc}") from None


@dataclass(frozen=True)
class Received:
    """A decoded message with its envelope."""

    key: str
    message: Message
    seq: int
    stamp_s: float


ENVELOPE_KEYS = frozenset(("type", "version", "seq", "stamp_s", "body"))
ARRAY_MAP_KEYS = frozenset(("dtype", "shape", "data"))


def _unpack_array(name: str, raw: Any, meta: dict[str, Any]) -> np.ndarray:
    """An array field's map as a read-only array over its bytes, which `_check_array` then checks."""
    if not isinstance(raw, dict) or raw.keys() != ARRAY_MAP_KEYS:
        raise ValueError(f"{name}: expected an array map with dtype, shape and data")
    dtype = meta["wire_dtype"]
    if raw["dtype"] != meta["wire_str"]:
        raise ValueError(f"{name}: dtype {raw['dtype']!r}, expected {meta['wire_str']!r}")
    shape = raw["shape"]
    if not isinstance(shape, list) or not all(isinstance(n, int) and n >= 0 for n in shape):
        raise ValueError(f"{name}: bad shape {shape!r}")
    if not isinstance(raw["data"], bytes) or len(raw["data"]) != dtype.itemsize * math.prod(shape):
        raise ValueError(f"{name}: {len(raw['data'])} data bytes do not fill shape {shape}")
    value = np.ndarray(shape, dtype, raw["data"])
    return value if dtype == meta["dtype"] else value.astype(meta["dtype"])


def decode(key: str, data: bytes, expected: str | None = None) -> Received:
    """Decode and validate; raises BadMessage(key, reason) on anything malformed."""
    try:
        data = unwrap(data)
    except ValueError as exc:
        raise BadMessage(key, str(exc)) from None
    try:
        envelope = msgpack.unpackb(data, raw=False, strict_map_key=True)
    except Exception as exc:  # msgpack raises several unrelated types on bad bytes
        raise BadMessage(key, f"not msgpack: {exc}") from None
    if not isinstance(envelope, dict) or envelope.keys() != ENVELOPE_KEYS:
        raise BadMessage(key, "not a message envelope (type, version, seq, stamp_s, body)")
    name = envelope["type"]
    cls = MESSAGES.get(name) if isinstance(name, str) else None
    if cls is None:
        raise BadMessage(key, f"unknown message type {name!r}")
    if expected is not None and name != expected:
        raise BadMessage(key, f"message type {name}, expected {expected}")
    if envelope["version"] != cls.VERSION:
        raise BadMessage(key, f"{name} schema version {envelope['version']!r}, expected {cls.VERSION}")
    seq, stamp_s, body = envelope["seq"], envelope["stamp_s"], envelope["body"]
    if not isinstance(seq, int) or isinstance(seq, bool) or seq < 0:
        raise BadMessage(key, f"bad sequence number {seq!r}")
    if not isinstance(stamp_s, float) or not math.isfinite(stamp_s):
        raise BadMessage(key, f"bad stamp {stamp_s!r}")
    schema = _schema(cls)
    if not isinstance(body, dict) or body.keys() != schema.names:
        raise BadMessage(
            key,
            f"{name} fields {sorted(body) if isinstance(body, dict) else body!r}, "
            f"expected {sorted(schema.names)}",
        )
    try:
        arrays = schema.arrays
        values = {n: _unpack_array(n, v, arrays[n]) if n in arrays else v for n, v in body.items()}
        message = cls(**values)
    except (ValueError, TypeError) as exc:
        raise BadMessage(key, f"{name}: {exc}") from None
    return Received(key, message, seq, stamp_s)
