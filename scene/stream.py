"""The scene stream from the vessel to shore, without Zenoh: the model's updates, and now and then
a small camera frame and a sonar frame, paced by shore's acknowledgements (`pacing.ScenePacer`).
Each step takes what came in and the time, and returns what to send."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from abyss.common.errors import BadInput
from abyss.config.stations import VesselConfig
from abyss.interface.images import downscale
from abyss.interface.messages import Image, Message, SceneAck, SonarImage, wire_bytes
from abyss.interface.sonar_frames import decode_polar, encode_polar
from abyss.scene.model import SceneModel
from abyss.scene.pacing import ScenePacer

Outgoing = list[tuple[str, Message]]  # (topic, message) in the order to publish


@dataclass
class StreamOutputs:
    messages: Outgoing = field(default_factory=list)
    rejected: list[tuple[str, str]] = field(default_factory=list)  # (topic, why) of a frame not sent


class SceneStream:
    """Scene updates, and now and then a small camera frame and a sonar frame, paced by shore's
    acknowledgements (`pacing.ScenePacer`)."""

    def __init__(self, cfg: VesselConfig, model: SceneModel) -> None:
        self.cfg = cfg
        self.model = model
        self.pacer = ScenePacer(cfg.scene_share, cfg.satellite_capacity_bps, cfg.scene_update_bytes)
        self.last_frame_s = {"image": -float("inf"), "sonar": -float("inf")}

    def _frame(
        self, now_s: float, image: Image | None, sonar: SonarImage | None, out: StreamOutputs
    ) -> tuple[str, Image | SonarImage] | None:
        """The camera's frame, downscaled, or the sonar's, as JPEG, if one is due."""
        periods = {"image": (image, self.cfg.image_period_s), "sonar": (sonar, self.cfg.sonar_period_s)}
        for topic, (frame, period_s) in periods.items():
            if frame is None or now_s - self.last_frame_s[topic] < period_s:
                continue
            self.last_frame_s[topic] = now_s
            try:
                if isinstance(frame, Image):
                    return topic, downscale(frame, self.cfg.image_scale, self.cfg.image_jpeg_quality)
                return topic, dataclasses.replace(
                    frame,
                    encoding="jpeg",
                    data=encode_polar(decode_polar(frame), "jpeg", self.cfg.image_jpeg_quality),
                )
            except BadInput as exc:
                out.rejected.append((topic, exc.reason))
        return None

    def step(
        self,
        now_s: float,
        sim_time_s: float,
        acks: list[SceneAck],
        snapshot_asked: bool,
        image: Image | None,
        sonar: SonarImage | None = None,
    ) -> StreamOutputs:
        out = StreamOutputs()
        for ack in acks:
            self.pacer.acknowledged(now_s, ack.scene_seq)
        if snapshot_asked:
            self.model.request_snapshot()
        self.pacer.tick(now_s)
        while self.pacer.allows():
            frame = self._frame(now_s, image, sonar, out)
            if frame is not None:
                out.messages.append(frame)
                self.pacer.sent(now_s, len(frame[1].data))
                continue
            update = self.model.next_update(sim_time_s, self.pacer.update_bytes())
            if update is None:
                break
            out.messages.append(("scene", update))
            self.pacer.sent(now_s, wire_bytes(update), update.scene_seq)
        return out
