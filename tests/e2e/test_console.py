"""The pilot's console (`abyss console`) in a real browser, Debian's Chromium driven by Selenium
through chromium-driver, against a running system: its instruments show what reached shore, and
its commands take shore's path to onboard, each showing onboard's answer."""

from __future__ import annotations

import base64
import contextlib
import hashlib
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import zenoh
from conftest import ROOT, Up, abyss
from cryptography import x509
from cryptography.hazmat.primitives import serialization
from selenium import webdriver
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import Select, WebDriverWait

from abyss.bus.session import client_config, message_of, open_session, zenoh_config
from abyss.common.ports import free_port
from abyss.console.server import Console
from abyss.description.site import site_at
from abyss.interface import keys
from abyss.interface.messages import MissionStatus, NavState, PanelState, Telemetry
from abyss.security import certs
from abyss.security.certs import CertFiles

PANEL = site_at("").panel  # the shipped site's: what these systems run

pytestmark = pytest.mark.timeout(300)
WAIT_S = 60.0  # for what the page shows to come, on this loaded machine
# the page's parts, each taken alone for docs/console.md (docs/images/console_<part>.png)
PARTS = (
    "camera",
    "sonar",
    "vehicle",
    "map-section",
    "mission-section",
    "commands-section",
    "links-section",
    "alerts-section",
)


@contextlib.contextmanager
def chromium(profile: Path, *flags: str) -> Iterator[webdriver.Chrome]:
    """Debian's Chromium, headless, through chromium-driver."""
    driver_path, binary = shutil.which("chromedriver"), shutil.which("chromium")
    if driver_path is None or binary is None:
        pytest.skip("Debian's chromium and chromium-driver are not installed (setup.sh installs them)")
    options = webdriver.ChromeOptions()
    options.binary_location = binary
    for flag in (
        "--headless=new",
        "--no-sandbox",
        "--disable-dev-shm-usage",
        "--window-size=1280,900",
        *flags,
    ):
        options.add_argument(flag)
    options.add_argument(f"--user-data-dir={profile}")
    driver = webdriver.Chrome(options=options, service=webdriver.ChromeService(executable_path=driver_path))
    try:
        yield driver
    finally:
        driver.quit()


@pytest.fixture
def browser(tmp_path: Path) -> Iterator[webdriver.Chrome]:
    with chromium(tmp_path / "profile") as driver:
        yield driver


class Shore:
    """What reached shore, as the test sees it on shore's network: each with its arrival [s]."""

    def __init__(self, endpoint: str, system: str) -> None:
        self.lock = threading.Lock()
        self.missions: list[tuple[float, MissionStatus]] = []
        self.telemetry: list[tuple[float, Telemetry]] = []
        self.session = open_session(client_config(endpoint), "the test's shore")
        self.subscribers = [
            self.session.declare_subscriber(keys.mission_key(system), self._mission),
            self.session.declare_subscriber(keys.spec("vessel", "telemetry").key(system), self._telemetry),
        ]

    def _mission(self, sample: zenoh.Sample) -> None:
        if (m := message_of(sample, MissionStatus)) is not None:
            with self.lock:
                self.missions.append((time.monotonic(), m))

    def _telemetry(self, sample: zenoh.Sample) -> None:
        if (t := message_of(sample, Telemetry)) is not None:
            with self.lock:
                self.telemetry.append((time.monotonic(), t))

    def since(self, seconds: float) -> tuple[list[MissionStatus], list[Telemetry]]:
        now = time.monotonic()
        with self.lock:
            return (
                [m for t, m in self.missions if now - t <= seconds],
                [m for t, m in self.telemetry if now - t <= seconds],
            )

    def close(self) -> None:
        for subscriber in self.subscribers:
            subscriber.undeclare()
        self.session.close()


def text(driver: webdriver.Chrome, selector: str) -> str:
    """The text of the page's element `selector` (an id, or CSS with a leading `css:`), read in one
    go in the page: it redraws twice a second."""
    query = selector[4:] if selector.startswith("css:") else f"#{selector}"
    return str(
        driver.execute_script(
            "const e = document.querySelector(arguments[0]); return e ? e.textContent : ''", query
        )
    )


def test_the_console_shows_what_reached_shore_and_its_commands_get_onboards_answers(
    tmp_path: Path, browser: webdriver.Chrome
) -> None:
    """`abyss console` for a system elsewhere, bound where others reach it: without the
    operator's token the page can neither read nor send; with it, its instruments match shore's,
    each part shows, and its commands come back with onboard's answers."""
    up = Up(tmp_path / "run", "--keep-running", "--duration", "90")
    up.wait_up()
    endpoint = up.endpoint
    console = subprocess.Popen(
        [sys.executable, "-P", "-m", "abyss.cli", "console", "--connect", endpoint, "--bind", "0.0.0.0"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        text=True,
    )
    shore = Shore(endpoint, "default")
    shots = Path(os.environ.get("ABYSS_SCREENSHOTS", tmp_path))  # docs/images: set it to docs/images
    try:
        assert console.stdout is not None
        line = console.stdout.readline()
        printed = re.search(r"http://[^/\s]+:(\d+)/\?token=(\S+)", line)
        assert printed, line
        page = f"http://127.0.0.1:{printed.group(1)}/"
        wait = WebDriverWait(browser, WAIT_S, poll_frequency=0.2)
        # without the token: the page says what it needs, shows nothing and sends nothing
        browser.get(page)
        wait.until(lambda d: "needs the operator's token" in text(d, "access"))
        browser.find_element(By.ID, "hold").click()
        wait.until(lambda d: "token" in text(d, "error"))
        assert text(browser, "commands") == "" and text(browser, "mission") == "no status yet"
        browser.get(f"{page}?token={printed.group(2)}")
        # the mission's waypoint as the page shows it is one shore published in the last seconds
        depth_css = 'css:[data-name="depth"] .value'
        wait.until(lambda d: text(d, "mission-waypoint") and text(d, depth_css))
        for _ in range(3):
            shown = text(browser, "mission-waypoint")
            missions, telemetry = shore.since(3.0)
            assert shown in {f"{m.waypoint_index}/{m.waypoints_total}" for m in missions}, (
                shown,
                missions[-1:],
            )
            depth = text(browser, depth_css)
            assert any(abs(float(depth.split()[0]) + t.position_m_world[2]) < 0.05 for t in telemetry), depth
            speed = float(text(browser, 'css:[data-name="speed"] .value').split()[0])
            assert any(abs(speed - np.linalg.norm(t.velocity_mps_body)) < 0.01 for t in telemetry), speed
            before = text(browser, "telemetry-age")
            wait.until(lambda d, before=before: text(d, "telemetry-age") != before)  # the page polled again
        assert "older than 3 s" in browser.page_source
        wait.until(
            lambda d: "stale" not in (d.find_element(By.ID, "instruments").get_attribute("class") or "")
        )
        # every station's liveliness, every hop's health as the stations measured it
        wait.until(lambda d: all(text(d, f'css:[data-station="{s}"]') == s for s in keys.STATIONS))
        wait.until(lambda d: all(text(d, f'css:[data-hop="{h}"]') for h in keys.HOPS))
        satellite_rtt_ms = float(
            re.search(r"round trip (\d+) ms", text(browser, 'css:[data-hop="satellite"]')).group(1)
        )
        assert 2 * 150 * 0.8 < satellite_rtt_ms < 2 * 150 * 3, satellite_rtt_ms  # profile: 150 ms each way
        wait.until(lambda d: "the scene stream's backlog" in text(d, "backlog"))
        # hold: through shore, the satellite, the vessel and the tether; onboard's answer shows
        browser.find_element(By.ID, "hold").click()
        wait.until(lambda d: "mode hold: taken" in text(d, "commands"))
        wait.until(lambda d: "failsafe: operator hold" in text(d, "alerts"))
        # a waypoint picked on the map, a metre east of the vehicle, lands in the text field
        _, telemetry = shore.since(3.0)
        x, y, z = (float(v) for v in telemetry[-1].position_m_world)
        picked = browser.execute_script(
            "const [px, py] = abyssMap.toPixel(arguments[0], arguments[1]);"
            "const c = document.getElementById('map'), r = c.getBoundingClientRect(), k = r.width / c.width;"
            "c.dispatchEvent(new MouseEvent('click', {clientX: r.left + px * k, clientY: r.top + py * k}));"
            "return document.getElementById('waypoints').value;",
            x + 1.0,
            y,
        )
        px, py, pz, _ = (float(v) for v in picked.split(","))
        assert abs(px - x - 1.0) < 0.1 and abs(py - y) < 0.1 and abs(pz - z) < 0.2, (picked, (x, y, z))
        # a waypoint at the surface: onboard refuses it, and the page says why
        browser.find_element(By.ID, "waypoints").clear()
        browser.find_element(By.ID, "waypoints").send_keys("5,0,-0.01,0")
        browser.find_element(By.CSS_SELECTOR, "#waypoints-form button").click()
        wait.until(lambda d: "refused: waypoint 0" in text(d, "commands"))
        assert "of the surface" in text(browser, "commands") and "refused" in text(browser, "alerts")
        # text the console cannot parse is refused in the page, sent nowhere
        browser.find_element(By.ID, "waypoints").clear()
        browser.find_element(By.ID, "waypoints").send_keys("5,0")
        browser.find_element(By.CSS_SELECTOR, "#waypoints-form button").click()
        wait.until(lambda d: "expected 4" in text(d, "error"))
        # stop here: one waypoint where the vehicle is, taken
        browser.find_element(By.ID, "stop").click()
        wait.until(
            lambda d: re.search(r"waypoints [-\d.]+,[-\d.]+,[-\d.]+,[-\d.]+: taken", text(d, "commands"))
        )
        # the relayed camera frame and the sonar's fan came across the satellite
        for image in ("frame", "sonar-fan"):
            wait.until(
                lambda d, i=image: d.execute_script(f"return document.getElementById('{i}').naturalWidth") > 0
            )
        browser.set_window_size(1280, 1500)  # the whole page, for the docs
        wait.until(lambda d: d.execute_script("return window.innerHeight") > 1200)
        browser.save_screenshot(str(shots / "console.png"))
        for part in PARTS:
            browser.find_element(By.ID, part).screenshot(str(shots / f"console_{part}.png"))
    finally:
        shore.close()
        console.send_signal(signal.SIGINT)
        try:
            console.wait(timeout=30)  # it closes within its bound (common.leave)
        finally:
            if console.poll() is None:  # nothing left running past the test, whatever failed
                console.kill()
                console.wait()
            if console.stdout is not None:
                console.stdout.close()
            up.stop()
    assert console.returncode == 0, console.returncode


def test_an_intervention_picked_in_the_console_turns_the_valve_and_an_outage_greys_the_page(
    tmp_path: Path, browser: webdriver.Chrome
) -> None:
    """The mission's waypoints flown, the pilot picks valve_1 from the parts the vessel recognised
    and turns it 90 deg: it turns on the simulation's truth. Then the satellite goes down: the
    instruments grey out and the alert rises; it comes back: they clear. The console is the one
    `abyss up` serves."""
    up = Up(tmp_path / "run", "--keep-running", "--duration", "200", "--set", "mission.interventions=[]")
    up.wait_up()
    endpoint = up.endpoint
    angles: dict[str, float] = {}
    vehicle: list[NavState] = []
    session = open_session(client_config(endpoint), "the test's truth")

    def on_panel(sample: zenoh.Sample) -> None:
        if (panel := message_of(sample, PanelState)) is not None:
            angles.update(zip(panel.names, (math.degrees(a) for a in panel.angles_rad), strict=True))

    def on_truth(sample: zenoh.Sample) -> None:
        if (truth := message_of(sample, NavState)) is not None:
            vehicle.append(truth)

    truths = [
        session.declare_subscriber(keys.panel_truth_key("default"), on_panel),
        session.declare_subscriber(keys.truth_key("default"), on_truth),
    ]
    link = ("--connect", endpoint)
    try:
        browser.get(up.wait_for(r"the pilot's console at (http://127\.0\.0\.1:\d+/)").group(1))
        wait = WebDriverWait(browser, 120, poll_frequency=0.2)
        wait.until(lambda d: text(d, "mission-mode") == "reached" and "valve_1" in text(d, "part"))
        wait.until(lambda d: "valve_1" in angles)
        start_deg = angles["valve_1"]
        Select(browser.find_element(By.ID, "part")).select_by_visible_text("valve_1")
        browser.find_element(By.ID, "amount").send_keys("90")
        browser.find_element(By.ID, "intervene").click()
        wait.until(lambda d: "valve valve_1 90: taken" in text(d, "commands"))
        wait.until(lambda d: abs(angles["valve_1"] - start_deg - 90.0) < 10.0)
        # the satellite down: no telemetry reaches shore, the page greys out and says so
        assert abyss("link", "set", "satellite", "--profile", "outage", *link).returncode == 0
        wait.until(lambda d: "stale" in (d.find_element(By.ID, "instruments").get_attribute("class") or ""))
        wait.until(lambda d: "no telemetry from the vessel" in text(d, "alerts"))
        assert abyss("link", "set", "satellite", "--profile", "satellite", *link).returncode == 0
        wait.until(lambda d: "reaches shore again" in text(d, "alerts"))
        wait.until(
            lambda d: "stale" not in (d.find_element(By.ID, "instruments").get_attribute("class") or "")
        )
        # a gamepad (the page's navigator.getGamepads, the test's): the stick back with the dead-man
        # held backs the vehicle away from the panel; let go, it stops
        browser.execute_script(
            "window.pad = {id: 'the test pad', axes: [0, 1, 0, 0],"
            " buttons: Array.from({length: 8}, () => ({pressed: false, value: 0}))};"
            "navigator.getGamepads = () => [window.pad];"
        )
        wait.until(lambda d: text(d, "gamepad") == "the test pad")
        x0 = vehicle[-1].position_m_world[0]
        browser.execute_script("window.pad.buttons[4].pressed = true;")
        wait.until(lambda d: vehicle[-1].position_m_world[0] < x0 - 0.3)
        browser.execute_script("window.pad.buttons[4].pressed = false;")
        wait.until(lambda d: text(d, "deadman") == "released")
        wait.until(lambda d: abs(vehicle[-1].velocity_mps_body[0]) < 0.02)
        sent, stopped, seen = text(browser, "teleop-sent"), vehicle[-1].position_m_world, len(vehicle)
        wait.until(lambda d: len(vehicle) >= seen + 60)  # three more simulated seconds of the truth
        assert abs(vehicle[-1].position_m_world[0] - stopped[0]) < 0.1, (
            stopped,
            vehicle[-1].position_m_world,
        )
        assert text(browser, "teleop-sent") == sent and int(sent) > 0  # nothing sent since the release
    finally:
        for truth in truths:
            truth.undeclare()
        session.close()
        up.stop()


def test_over_https_with_the_operators_certificate_the_page_is_secure_and_asks_its_token(
    tmp_path: Path,
) -> None:
    """Chromium trusting the operator's key alone (as a browser that imported the system's CA would
    trust its certificate) at a host the certificate names: the page is a secure context (a gamepad
    allowed), reads the console's state with the token, and says what it needs without it."""
    certs.make(tmp_path / "certs", {certs.OPERATOR: ["127.0.0.2"]})
    operator = CertFiles(tmp_path / "certs", certs.OPERATOR)
    key = x509.load_pem_x509_certificate(operator.certificate.read_bytes()).public_key()
    spki = key.public_bytes(serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo)
    pin = base64.b64encode(hashlib.sha256(spki).digest()).decode()
    session = open_session(zenoh_config([f"tcp/127.0.0.1:{free_port()}"], mode="router"), "the test's shore")
    console = Console(session, "https-test", 0, PANEL, host="0.0.0.0", certificates=operator)
    port = console.server.server_address[1]
    try:
        with chromium(tmp_path / "profile", f"--ignore-certificate-errors-spki-list={pin}") as driver:
            wait = WebDriverWait(driver, WAIT_S)
            driver.get(f"https://127.0.0.2:{port}/?token={console.access.token}")
            wait.until(lambda d: text(d, "system") == "system https-test")
            assert driver.execute_script("return window.isSecureContext") is True
            assert text(driver, "gamepad") == "none"  # allowed, none plugged in
            driver.get(f"https://127.0.0.2:{port}/")
            wait.until(lambda d: "needs the operator's token" in text(d, "access"))
    finally:
        console.close()
        session.close()
