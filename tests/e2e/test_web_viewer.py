"""`abyss up --viewer web`: rerun's web viewer, served on a local port, loaded in headless
Debian Chromium, shows the live system: its 3D view is not blank."""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from browser import Browser, chromium
from conftest import Up

from abyss.stations.runtime import free_port

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(240)]
COLOURFUL_PX = 1500  # the hull, the path, the voxels: more saturated pixels than the UI's accents
# the 3D view in the web viewer's layout at 1280 x 800 (beside its side panels): x from, x to,
# y from, y to [share of the page]
VIEW_BOX = (0.17, 0.6, 0.08, 0.74)


def colourful_px_in_3d_view(bgr: np.ndarray) -> int:
    h, w = bgr.shape[:2]
    x0, x1, y0, y1 = VIEW_BOX
    view = bgr[int(y0 * h):int(y1 * h), int(x0 * w):int(x1 * w)]
    saturation = cv2.cvtColor(view, cv2.COLOR_BGR2HSV)[..., 1]
    return int((saturation > 100).sum())


@pytest.mark.skipif(chromium() is None, reason="no chromium: setup.sh installs Debian's package as root")
def test_the_web_viewer_shows_the_live_system_in_a_browser(tmp_path: Path) -> None:
    up = Up(tmp_path / "run", "--viewer", "web", "--keep-running", "--duration", "150", "--system", "e2e-web")
    url = up.wait_for(r"web viewer at (http://127\.0\.0\.1:\d+/\S+)").group(1)
    browser = Browser(tmp_path / "chromium", free_port())
    try:
        blank = browser.screenshot()  # before the page: the count a blank view gives
        browser.open(url)
        deadline, seen = time.monotonic() + 150.0, 0
        while time.monotonic() < deadline and seen < COLOURFUL_PX:
            time.sleep(3.0)
            shot = browser.screenshot()
            seen = colourful_px_in_3d_view(shot)
        cv2.imwrite(str(tmp_path / "web_viewer.png"), shot)
    finally:
        browser.close()
    assert colourful_px_in_3d_view(blank) < COLOURFUL_PX
    assert seen >= COLOURFUL_PX, f"the 3D view stayed blank ({seen} colourful pixels); see {tmp_path}"
    up.interrupt()
    assert (tmp_path / "run" / "onshore.rrd").stat().st_size > 0  # saved as well as served
