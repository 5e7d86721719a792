"""Camera frames as Image messages: RGB as JPEG, depth as 16-bit PNG in millimetres."""

from __future__ import annotations

import cv2
import numpy as np

from common.images import DEPTH_SCALE_M
from common.messages import Image
from stations.simulation.rendering import Cameras


def encode_image(cameras: Cameras, data: object, camera: str, jpeg_quality: int) -> Image:
    intrinsics = cameras.intrinsics(camera)
    if camera == "cam_depth":
        depth_mm = np.clip(cameras.depth_m(data, camera) / DEPTH_SCALE_M, 0, 65535).astype(np.uint16)
        ok, buffer = cv2.imencode(".png", depth_mm)
        encoding = "png16"
    else:
        bgr = cv2.cvtColor(cameras.rgb(data, camera), cv2.COLOR_RGB2BGR)
        ok, buffer = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
        encoding = "jpeg"
    if not ok:
        raise RuntimeError(f"OpenCV could not encode the {camera} frame")
    return Image(camera=camera, encoding=encoding, width_px=intrinsics.width_px,
                 height_px=intrinsics.height_px, fx_px=intrinsics.fx_px, fy_px=intrinsics.fy_px,
                 cx_px=intrinsics.cx_px, cy_px=intrinsics.cy_px,
                 pose_camera_in_vehicle=cameras.pose_in_vehicle(camera), data=buffer.tobytes(),
                 sim_time_s=float(data.time))  # type: ignore[attr-defined]
