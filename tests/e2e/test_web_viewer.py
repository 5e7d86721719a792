"""`abyss up --viewer web`: rerun's web viewer, served on a local port, loaded in headless
Debian Chromium, shows the live system: its 3D view is not blank, and the operator's layout
(one plot per unit, the links' plots per hop, the intervention's views) is the one it has."""

from __future__ import annotations

import re
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from browser import Browser, chromium
from conftest import Up

from abyss.common.ports import free_port, listening
from abyss.interface import keys

pytestmark = pytest.mark.timeout(240)
COLOURFUL_PX = 1500  # the hull, the path, the voxels: more saturated pixels than the UI's accents
# the 3D view at 1280 x 800, on the left under the tabs, both before the operator's layout
# collapses the web viewer's side panels and after (not the blueprint panel's blue selection):
# x from, x to, y from, y to [share of the page]
VIEW_BOX = (0.17, 0.53, 0.13, 0.78)
# the views' names that the layout gives its plots and logs
LINK_PLOTS = ("throughput [kbit/s]", "delay [ms]", "losses and retransmissions [count]")  # per hop
PANELS = ["World", "Camera", "Vehicle position error [m]", "Heading error [deg]", "Tool position error [mm]",
          "Tool orientation error [deg]", "Intervention phase", "Valve and lever angles [deg]",
          "Grasp: gripper opening [mm]", "Grasp: grip force [N]",
          *(f"{hop} {plot}" for hop in keys.HOPS for plot in LINK_PLOTS)]  # fmt: skip


def colourful_px_in_3d_view(bgr: np.ndarray) -> int:
    h, w = bgr.shape[:2]
    x0, x1, y0, y1 = VIEW_BOX
    view = bgr[int(y0 * h) : int(y1 * h), int(x0 * w) : int(x1 * w)]
    saturation = cv2.cvtColor(view, cv2.COLOR_BGR2HSV)[..., 1]
    return int((saturation > 100).sum())


def panels_missing(browser: Browser) -> list[str]:
    """The names in PANELS that the page's viewer does not have: read from the viewer's own
    state, which its JavaScript handle serialises (Protocol Buffers, the names as UTF-8)."""
    state = bytes(browser.evaluate("window._handle ? Array.from(window._handle.viewer_state()) : []"))
    return [name for name in PANELS if name.encode() not in state]


@pytest.mark.skipif(chromium() is None, reason="no chromium: setup.sh installs Debian's package as root")
def test_the_web_viewer_shows_the_live_system_in_a_browser(tmp_path: Path) -> None:
    up = Up(tmp_path / "run", "--viewer", "web", "--keep-running", "--duration", "150", "--system", "e2e-web")
    url = up.wait_for(r"web viewer at (http://127\.0\.0\.1:\d+/\S+)").group(1)
    browser = Browser(tmp_path / "chromium", free_port())
    try:
        blank = browser.screenshot()  # before the page: the count a blank view gives
        browser.open(url)
        deadline, seen, missing = time.monotonic() + 150.0, 0, PANELS
        while time.monotonic() < deadline and (seen < COLOURFUL_PX or missing):
            time.sleep(3.0)
            shot = browser.screenshot()
            seen = colourful_px_in_3d_view(shot)
            missing = panels_missing(browser)
        cv2.imwrite(str(tmp_path / "web_viewer.png"), shot)
        # the pilot's console of the same run embeds this viewer
        browser.open(up.wait_for(r"the pilot's console at (http://127\.0\.0\.1:\d+/)").group(1))
        embedded, deadline = "", time.monotonic() + 30.0
        while time.monotonic() < deadline and embedded != url:
            time.sleep(0.5)
            embedded = browser.evaluate("(document.getElementById('viewer') || {}).src || ''")
    finally:
        browser.close()
    assert embedded == url, f"the console embeds {embedded!r}, not the viewer at {url}"
    assert colourful_px_in_3d_view(blank) < COLOURFUL_PX
    assert seen >= COLOURFUL_PX, f"the 3D view stayed blank ({seen} colourful pixels); see {tmp_path}"
    assert not missing, f"the viewer has no view named {missing}; see {tmp_path}"
    up.interrupt()  # and no failure: shore's last flush to the viewer cost it nothing
    assert (tmp_path / "run" / "onshore.rrd").stat().st_size > 0  # saved as well as served
    ports = [int(p) for p in re.findall(r"(?:127\.0\.0\.1:|%3A)(\d+)", url)]
    assert len(ports) == 2 and not any(map(listening, ports)), (
        f"the viewer's server outlived the run: {ports}"
    )
