"""Camera frames on the wire: RGB as JPEG, depth as 16-bit PNG in millimetres."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from abyss.common.errors import BadInput
from abyss.interface.messages import Image

DEPTH_SCALE_M = 0.001  # one PNG count [m]


def decode_image(image: Image) -> np.ndarray:
    """RGB uint8 (H, W, 3), or depth [m] float32 (H, W); BadInput if the bytes do not decode
    to an image of the size the message states."""
    buffer = np.frombuffer(image.data, np.uint8)
    flags = cv2.IMREAD_UNCHANGED if image.encoding == "png16" else cv2.IMREAD_COLOR
    pixels = cv2.imdecode(buffer, flags) if len(buffer) else None
    expected = (image.height_px, image.width_px)
    if pixels is None or pixels.shape[:2] != expected:
        got = "nothing" if pixels is None else f"{pixels.shape}"
        raise BadInput(f"{image.camera}: {image.encoding} data decodes to {got}, expected {expected}")
    if image.encoding == "png16":
        if pixels.dtype != np.uint16 or pixels.ndim != 2:
            raise BadInput(f"{image.camera}: depth is not a 16-bit single-channel PNG")
        depth_m = pixels.astype(np.float32)
        depth_m *= DEPTH_SCALE_M
        return depth_m
    return cv2.cvtColor(pixels, cv2.COLOR_BGR2RGB)


def encode_jpeg(rgb: np.ndarray, quality: int) -> bytes:
    bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    ok, buffer = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise RuntimeError("OpenCV could not encode a JPEG")
    return buffer.tobytes()


def downscale(image: Image, scale: float, quality: int) -> Image:
    """An RGB frame at `scale` of its size, as JPEG of `quality`, its intrinsics scaled with it.
    BadInput if it does not decode."""
    rgb = decode_image(image)
    width_px, height_px = max(1, round(image.width_px * scale)), max(1, round(image.height_px * scale))
    small = cv2.resize(rgb, (width_px, height_px), interpolation=cv2.INTER_AREA)
    sx, sy = width_px / image.width_px, height_px / image.height_px
    return dataclasses.replace(
        image,
        encoding="jpeg",
        width_px=width_px,
        height_px=height_px,
        fx_px=image.fx_px * sx,
        fy_px=image.fy_px * sy,
        cx_px=image.cx_px * sx,
        cy_px=image.cy_px * sy,
        data=encode_jpeg(small, quality),
    )
