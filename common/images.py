"""Camera frames on the wire: RGB as JPEG, depth as 16-bit PNG in millimetres."""

from __future__ import annotations

import cv2
import numpy as np

from common.messages import Image

DEPTH_SCALE_M = 0.001  # one PNG count [m]


def decode_image(image: Image) -> np.ndarray:
    """RGB uint8 (H, W, 3), or depth [m] float32 (H, W)."""
    buffer = np.frombuffer(image.data, np.uint8)
    if image.encoding == "png16":
        return cv2.imdecode(buffer, cv2.IMREAD_UNCHANGED).astype(np.float32) * DEPTH_SCALE_M
    return cv2.cvtColor(cv2.imdecode(buffer, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
