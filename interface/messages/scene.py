"""The scene stream (vessel -> onshore) and what perception tells about it."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from abyss.common.errors import BadInput
from abyss.interface.messages.schema import Message, array, blob, scalar
from abyss.interface.messages.sensors import CLOUD_SOURCES

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
    the panel: "texture" (markers, PnP), "shape" (plane and ICP) or "texture+shape" (fused). A
    valve's or lever's pose is the panel's turned about the part's axis by the angle measured on
    its handle in the image, and its confidence that measurement's (0: not measured, at rest)."""

    names: tuple[str, ...] = scalar()
    poses_world: np.ndarray = array("f8", (None, 7), -1e5, 1e5, max_rows=256)
    half_sizes_m: np.ndarray = array("f8", (None, 3), 0.0, 100.0, max_rows=256)
    confidences: np.ndarray = array("f8", (None,), 0.0, 1.0, max_rows=256)
    method: str = scalar()
    sim_time_s: float = scalar(0.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        if not len(self.names) == len(self.poses_world) == len(self.half_sizes_m) == len(self.confidences):
            raise BadInput("names, poses_world, half_sizes_m and confidences differ in length")


PERCEPTION_SOURCES = (*CLOUD_SOURCES, "sonar")
SCENE_SOURCES = ("", "cameras", "sonar")


@dataclass(frozen=True)
class PerceptionStatus(Message):
    """What the vessel's perception has to work with, vessel -> onshore: per source (the
    cameras' clouds, depth and stereo, and the sonar's echoes) the points it received over the
    last `window_s` [points/s]; what the scene model maps from now (`scene_source`: "cameras",
    or "sonar" while the cameras' clouds bring no point, "" before either); the recognised
    panel's confidence now and what found it (RecognisedObjects.method; "" while not found);
    the scene stream's backlog: the cells the scene model has queued for shore and not yet sent
    (with a snapshot due, the whole map)."""

    VERSION: ClassVar[int] = 2  # 2: scene_backlog_cells

    points_per_s: dict[str, float]
    window_s: float = scalar(0.1, 3600.0)
    scene_source: str = scalar(choices=SCENE_SOURCES)
    recognition_confidence: float = scalar(0.0, 1.0)
    recognition_method: str = scalar()
    sim_time_s: float = scalar(0.0)
    scene_backlog_cells: int = field(default=0, metadata={"lo": 0, "hi": 2**53, "choices": ()})

    def __post_init__(self) -> None:
        super().__post_init__()
        for source, rate in self.points_per_s.items():
            if source not in PERCEPTION_SOURCES or not 0.0 <= rate <= 1e9:
                raise BadInput(
                    f"points_per_s: {source!r}: {rate} (sources "
                    f"{', '.join(PERCEPTION_SOURCES)}, rates in [0, 1e9])"
                )
