"""The vessel's intake, without Zenoh: what comes up from onboard goes into the scene model (the
cameras' clouds, or the sonar's echoes while the cameras see nothing), recognition runs on its
schedule, and shore is told what perception works with. Each step takes what came in and the
time, and returns what to send; what the vessel's other threads read of it (the latest cloud's
simulated time, recognition's latest objects, the sonar's latest frame) is kept in `Latest`s."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from abyss.common.errors import BadInput
from abyss.common.shared import Latest
from abyss.config.hybrid import HybridConfig
from abyss.config.stations import VesselConfig
from abyss.description.models.panel import Panel
from abyss.interface.clouds import unpack_cloud
from abyss.interface.images import decode_image
from abyss.interface.messages import Image, Message, PointCloud, RecognisedObjects, SonarImage
from abyss.interface.sonar_frames import ECHO_RGB, echo_arcs
from abyss.scene.model import SceneModel
from abyss.stations.vessel.core import Perception
from abyss.stations.vessel.recognition import PanelTracker, expected_pose


@dataclass
class IntakeInputs:
    clouds: list[PointCloud] = field(default_factory=list)  # onboard's, since the last step
    pings: list[SonarImage] = field(default_factory=list)  # the sonar's frames, since the last step
    image: Image | None = None  # the camera's latest frame


@dataclass(frozen=True)
class Insertion:
    """A cloud or the sonar's echoes for the scene model (SceneModel.integrate, then track)."""

    points_m_world: np.ndarray
    colors: np.ndarray  # [uint8 RGB] one a point
    sensor_m_world: np.ndarray  # where the rays start
    stamp_s: float  # its simulated time


@dataclass
class IntakeOutputs:
    messages: list[tuple[str, Message]] = field(default_factory=list)  # (topic, message) to publish
    rejected: list[tuple[str, str]] = field(default_factory=list)  # (onboard's topic, why)


class Intake:
    """Clouds and echoes into `model` (unless a ROS 2 node maps them: `maps` False, and the model
    adopts the node's maps instead), the model's changes flushed once no more came for a track
    period, the panel recognised every `recognition_period_s` from the latest image and cloud
    (the depth camera's when there is one), and perception's status every
    `perception_period_s` [s]."""

    def __init__(
        self,
        cfg: VesselConfig,
        panel: Panel,
        model: SceneModel,
        now_s: float,
        maps: bool = True,
        hybrid: HybridConfig | None = None,
    ) -> None:
        self.cfg = cfg
        self.model = model
        self.maps = maps
        self.perception = Perception(cfg)
        # the panel first looked for where the site package puts it, registered in a hybrid run
        position, rotation = expected_pose(panel, hybrid or HybridConfig())
        self.tracker = PanelTracker(
            panel, position, bias_m_world=cfg.recognition_bias_m, expected_rotation=rotation
        )
        self.sim_time_s: Latest[float] = Latest(0.0)  # of the latest cloud (or echoes inserted)
        self.objects: Latest[RecognisedObjects | None] = Latest(None)  # recognition's latest
        self.sonar: Latest[SonarImage | None] = Latest(None)  # the sonar's latest frame
        self.inserted_s = now_s  # when the model last took a cloud or echoes
        self.last_recognition_s = self.last_status_s = -float("inf")
        self.points: np.ndarray | None = None  # [m, world] the cloud recognition fits the panel to

    def step(self, inputs: IntakeInputs, now_s: float) -> IntakeOutputs:
        """One step at once: `take`, `integrate`, `settle`."""
        out, cells = self.take(inputs, now_s)
        self.integrate(cells)
        return self.settle(cells, inputs.image, now_s, out)

    def take(self, inputs: IntakeInputs, now_s: float) -> tuple[IntakeOutputs, list[Insertion]]:
        """What came in, counted and kept; the clouds and echoes for the model, to `integrate`
        (which may run in another thread while the station goes on: it touches the octree alone)
        and then `settle`. Without them, what the last clouds changed is flushed once no more
        came for a track period."""
        out = IntakeOutputs()
        cells = self._clouds(inputs.clouds, now_s) + self._pings(inputs.pings, now_s, out)
        if self.maps and now_s - self.inserted_s >= self.cfg.scene_track_period_s:
            self.model.flush()
        return out, cells

    def integrate(self, cells: list[Insertion]) -> None:
        """The clouds and echoes `take` returned, into the octree (scene.model: nothing queued)."""
        for insertion in cells:
            if len(insertion.points_m_world):
                self.model.integrate(insertion.points_m_world, insertion.colors, insertion.sensor_m_world)

    def settle(
        self, cells: list[Insertion], image: Image | None, now_s: float, out: IntakeOutputs
    ) -> IntakeOutputs:
        """After `integrate`, the step `take` began at `now_s` ends: what the clouds changed
        queued for shore (at their stamps' track period), perception's status and recognition
        (on `image`, the camera's latest then) when due, into `out`."""
        for insertion in cells:
            if len(insertion.points_m_world):
                self.model.track(insertion.stamp_s)
        if now_s - self.last_status_s >= self.cfg.perception_period_s:
            self.last_status_s = now_s
            status = self.perception.status(
                now_s, self.objects.get(), self.sim_time_s.get(), self.model.backlog_cells()
            )
            out.messages.append(("perception", status))
        due = now_s - self.last_recognition_s >= self.cfg.recognition_period_s
        if due and (image is not None or self.points is not None):
            self.last_recognition_s = now_s
            self._recognise(image, out)
        return out

    def _clouds(self, clouds: list[PointCloud], now_s: float) -> list[Insertion]:
        cells = []
        for cloud in clouds:
            points, colors = unpack_cloud(cloud)
            self.perception.received(cloud.source, len(points), now_s)
            if self.maps:
                cells.append(Insertion(points, colors, cloud.sensor_m_world, cloud.sim_time_s))
                self.inserted_s = now_s
            self.sim_time_s.set(cloud.sim_time_s)
            if cloud.source == "depth" or self.points is None:
                self.points = points
        return cells

    def _pings(self, pings: list[SonarImage], now_s: float, out: IntakeOutputs) -> list[Insertion]:
        """The sonar's echoes, counted, and inserted while the sonar feeds the model."""
        cells = []
        for ping in pings:
            self.sonar.set(ping)
            try:
                echoes, origin = echo_arcs(ping, self.cfg.octree_resolution_m)
            except BadInput as exc:
                out.rejected.append(("sonar", exc.reason))
                continue
            self.perception.received("sonar", len(echoes), now_s)
            if self.maps and self.perception.sonar_feeds(now_s) and len(echoes):
                colors = np.tile(np.array(ECHO_RGB, np.uint8), (len(echoes), 1))
                cells.append(Insertion(echoes, colors, origin, ping.sim_time_s))
                self.inserted_s = now_s
                self.sim_time_s.update(ping.sim_time_s, max)
        return cells

    def _recognise(self, image: Image | None, out: IntakeOutputs) -> None:
        """The panel from the latest image (when it decodes, posed in the world frame) and cloud."""
        rgb = None
        if image is not None:
            try:
                if image.pose_frame != "world":
                    raise BadInput(
                        f"camera pose in the {image.pose_frame} frame; the vessel needs it in the world frame"
                    )
                rgb = decode_image(image)
            except BadInput as exc:
                out.rejected.append(("image", exc.reason))
        self.tracker.update(rgb, image, self.points)
        objects = self.tracker.objects(self.sim_time_s.get())
        if objects is not None:
            self.objects.set(objects)
            out.messages.append(("objects", objects))
