"""Onboard's frame sets, without Zenoh: the cameras' frames gathered into sets by the instant
they were taken, each complete set made into clouds in the world frame with the navigation pose
estimated for that instant, and the left frame sent on to the vessel at its own rate.

A set is complete once it holds every frame the cloud sources need: cam_left, cam_depth for the
depth source, and cam_right for the stereo source on the sets it runs on, every `stereo_every`-th
by the set's index on the simulated clock (description.models.stereo_set: the simulation renders
cam_right on those alone). Only the newest complete set is worked on: complete sets not
processed when a newer one came are shed, the oldest first, and counted. A set with no
navigation estimate near its time is skipped. After each set the core rests in proportion to
its work, so that it is busy `perception_max_busy` of the time at most (frames that come
meanwhile wait; the newest set is taken)."""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from abyss.common.errors import BadInput
from abyss.config.stations import OnboardConfig
from abyss.description.models import stereo_set
from abyss.description.robot_file import CamerasSection
from abyss.interface.images import decode_image, encode_jpeg
from abyss.interface.messages import Image, PointCloud
from abyss.stations.onboard.navigation import PoseHistory
from abyss.stations.onboard.perception import CloudSettings, camera_in_world, clouds_of

INCOMPLETE_KEPT = 4  # sets that never complete (a frame lost): the newest this many are kept
log = logging.getLogger(__name__)


@dataclass
class FrameSetInputs:
    """What reached perception since the last step."""

    frames: Sequence[tuple[str, Image]] = ()  # (camera, frame), oldest first
    poses: PoseHistory = field(default_factory=PoseHistory)  # the navigation estimate, as handed over
    arm_m_world: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # the arm's chain [m, world]


@dataclass
class FrameSetOutputs:
    clouds: list[PointCloud] = field(default_factory=list)
    image: Image | None = None  # the left frame, its pose in the world, for the vessel
    shed: int = 0  # complete sets let go unprocessed, a newer one having come
    rejected: list[str] = field(default_factory=list)  # why a set's frames were dropped (BadInput)
    taken_s: float | None = None  # the sim time [s] of the set worked on this step
    skipped_s: float | None = None  # the sim time [s] of a set dropped for want of a pose estimate


@dataclass(frozen=True)
class FrameSetJob:
    """A complete set's work, with everything it needs taken when the set was (FrameSets.take)."""

    frames: dict[str, Image]  # camera -> frame
    pose: tuple[np.ndarray, np.ndarray]  # the navigation estimate at the set's time
    arm_m_world: np.ndarray  # [m, world] the arm's chain then (the clouds' self-filter)
    sources: tuple[str, ...]  # the cloud sources run on this set
    image: bool  # the left frame goes on to the vessel (at onboard.image_rate_hz)
    taken_s: float  # when the set was taken [s, the station's clock]


class FrameSets:
    """One perception step at a time: frames in, clouds and the camera image out."""

    def __init__(self, cfg: OnboardConfig, camera_rate_hz: float, cameras: CamerasSection) -> None:
        """`cameras`: the robot's (description.robot): the stereo pair and the depth camera."""
        self.cfg, self.camera_rate_hz, self.cameras = cfg, camera_rate_hz, cameras
        self.settings = CloudSettings.of(cfg)
        left, self.right = cameras.stereo
        self.needed = {left} | ({cameras.depth} if "depth" in cfg.cloud_sources else set())
        self.sets: dict[float, dict[str, Image]] = {}  # sim time [s] -> camera -> frame
        self.last_image_s = -float("inf")  # [s, this station's clock]
        self.resting_until_s = -float("inf")
        self._started_s: float | None = None  # when the set being worked on was taken

    def step(self, inputs: FrameSetInputs, now_s: float) -> FrameSetOutputs:
        """Gather `inputs.frames`, and work on the newest complete set unless resting (`take`,
        then `work`). `now_s` [s, this station's clock]; call `finished` once what this returns
        is published."""
        out, job = self.take(inputs, now_s)
        return self.work(job, out) if job is not None else out

    def take(self, inputs: FrameSetInputs, now_s: float) -> tuple[FrameSetOutputs, FrameSetJob | None]:
        """Gather `inputs.frames` and take the newest complete set unless resting: what is known
        at once (sets shed, a set skipped), and the set's work, if any, for `work` (which may run
        in another thread while frames come on, but not beside the next `take`)."""
        out = FrameSetOutputs()
        for camera, frame in inputs.frames:
            self.sets.setdefault(frame.sim_time_s, {})[camera] = frame
        if now_s < self.resting_until_s:  # what comes meanwhile waits; the newest set is taken
            return out, None
        t = self._newest_complete(out)
        if t is None:
            return out, None
        frames = self.sets.pop(t)
        pose = inputs.poses.at(t)
        if pose is None:
            log.debug("no navigation estimate at %.2f s; frames skipped", t)
            out.skipped_s = t
            return out, None
        out.taken_s, self._started_s = t, now_s
        sources = tuple(s for s in self.cfg.cloud_sources if s != "stereo" or self._stereo(t))
        image = self.cfg.image_rate_hz > 0 and now_s - self.last_image_s >= 1.0 / self.cfg.image_rate_hz
        return out, FrameSetJob(frames, pose, inputs.arm_m_world, sources, image, now_s)

    def work(self, job: FrameSetJob, out: FrameSetOutputs) -> FrameSetOutputs:
        """The clouds of a set `take` took (and the left frame for the vessel, when due) into
        `out`; frames that do not decode, or a camera pose in the wrong frame, are rejected."""
        try:
            out.clouds = clouds_of(
                self.cameras, job.frames, job.pose, job.arm_m_world, job.sources, self.settings
            )
            if job.image:
                out.image = self._image(job.frames[self.cameras.stereo[0]], job.pose)
                self.last_image_s = job.taken_s
        except BadInput as exc:
            out.rejected.append(exc.reason)
        return out

    def finished(self, now_s: float) -> None:
        """The set taken by the last step is done (published) at `now_s` [s, this station's
        clock]: rest so that the work was `perception_max_busy` of the time."""
        if self._started_s is not None:
            busy_s = now_s - self._started_s
            self.resting_until_s = self._started_s + busy_s / self.cfg.perception_max_busy
            self._started_s = None

    def _newest_complete(self, out: FrameSetOutputs) -> float | None:
        """The sim time of the newest complete set, those older let go (complete ones counted
        as shed); None if none is complete."""
        complete = [t for t, frames in self.sets.items() if self._needed(t) <= set(frames)]
        if not complete:
            for t in sorted(self.sets)[:-INCOMPLETE_KEPT]:
                del self.sets[t]
            return None
        newest = max(complete)
        out.shed = len(complete) - 1  # not yet processed when a newer one came: the oldest first
        for older in [s for s in self.sets if s < newest]:
            del self.sets[older]
        return newest

    def _stereo(self, t_s: float) -> bool:
        """Whether the stereo source runs on the set taken at `t_s` [s]."""
        return "stereo" in self.cfg.cloud_sources and stereo_set(
            t_s, self.camera_rate_hz, self.cfg.stereo_every
        )

    def _needed(self, t_s: float) -> set[str]:
        """The cameras the set taken at `t_s` [s] must hold to be complete."""
        return self.needed | {self.right} if self._stereo(t_s) else self.needed

    def _image(self, left: Image, pose: tuple[np.ndarray, np.ndarray]) -> Image:
        """The left frame for the vessel, re-encoded with its pose in the world."""
        return dataclasses.replace(
            left,
            pose_frame="world",
            pose_camera=camera_in_world(left, pose),
            data=encode_jpeg(decode_image(left), self.cfg.image_jpeg_quality),
        )
