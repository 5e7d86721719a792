"""Camera frames as Image messages: RGB as JPEG, depth as 16-bit PNG in millimetres."""

from __future__ import annotations

import cv2
import numpy as np

from abyss.interface.images import DEPTH_SCALE_M, encode_jpeg
from abyss.interface.messages import Image
from abyss.stations.simulation.rendering import Cameras


def encode_image(cameras: Cameras, data: object, camera: str, jpeg_quality: int) -> Image:
    intrinsics = cameras.intrinsics(camera)
    if camera == cameras.depth_camera:
        depth = cameras.depth_m(data, camera)  # a fresh array: to millimetres in place
        np.divide(depth, DEPTH_SCALE_M, out=depth)
        depth_mm = np.clip(depth, 0, 65535, out=depth).astype(np.uint16)
        ok, buffer = cv2.imencode(".png", depth_mm)
        if not ok:
            raise RuntimeError(f"OpenCV could not encode the {camera} frame")
        encoding, payload = "png16", buffer.tobytes()
    else:
        encoding, payload = "jpeg", encode_jpeg(cameras.rgb(data, camera), jpeg_quality)
    return Image(
        camera=camera,
        encoding=encoding,
        pose_frame="vehicle",
        width_px=intrinsics.width_px,
        height_px=intrinsics.height_px,
        fx_px=intrinsics.fx_px,
        fy_px=intrinsics.fy_px,
        cx_px=intrinsics.cx_px,
        cy_px=intrinsics.cy_px,
        pose_camera=cameras.pose_in_vehicle(camera),
        data=payload,
        sim_time_s=float(data.time),  # type: ignore[attr-defined]
    )
