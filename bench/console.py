"""The pilot's console, measured on the live system (`abyss up`, default mission and links, the
camera's frame relayed to shore at 1 Hz) in Debian's Chromium driven by Selenium:
- the delay from a telemetry sample reaching shore (this script's own subscriber on shore's
  network) to the page showing it (the page's log, `window.abyssLog`, same clock);
- from a click to onboard's answer reaching the console's server, and to the page showing it,
  alternating Hold and Auto, against `abyss op`'s own send and wait on the same path (the peer);
- the browser's CPU (all of Chromium's processes, cores) with the console open, against the same
  browser on a blank page in the same sitting (the floor).
Run: .venv/bin/python bench/console.py [--seconds S] [--clicks N]. Prints figures; asserts nothing."""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import zenoh
from selenium import webdriver
from selenium.webdriver.common.by import By

from abyss.bus.session import client_config, message_of, open_session
from abyss.console.op import send
from abyss.interface import keys
from abyss.interface.messages import OperatorMode, Telemetry, new_id

ROOT = Path(__file__).resolve().parents[1]
TICKS_PER_S = os.sysconf("SC_CLK_TCK")


def tree_cpu_s(root_pid: int) -> float:
    """User + system CPU time [s] of a process and all its descendants alive now."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    total, todo = 0.0, [root_pid]
    while todo:
        pid = todo.pop()
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        total += (int(fields[11]) + int(fields[12])) / TICKS_PER_S
        todo += children.get(pid, [])
    return total


def browser(profile: Path) -> webdriver.Chrome:
    options = webdriver.ChromeOptions()
    options.binary_location = shutil.which("chromium") or "chromium"
    for flag in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1280,900"):
        options.add_argument(flag)
    options.add_argument(f"--user-data-dir={profile}")
    service = webdriver.ChromeService(executable_path=shutil.which("chromedriver") or "chromedriver")
    return webdriver.Chrome(options=options, service=service)


def cores(driver: webdriver.Chrome, seconds: float) -> float:
    pid = driver.service.process.pid  # chromedriver, whose descendants are the browser's processes
    c0, t0 = tree_cpu_s(pid), time.monotonic()
    time.sleep(seconds)
    return (tree_cpu_s(pid) - c0) / (time.monotonic() - t0)


def percentiles(values: list[float]) -> str:
    if not values:
        return "none"
    p50, p95 = np.percentile(values, [50, 95])
    return f"median {p50 * 1e3:.0f} ms, p95 {p95 * 1e3:.0f} ms (n={len(values)})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=40.0, help="measured seconds per CPU window")
    parser.add_argument("--clicks", type=int, default=8, help="Hold/Auto clicks timed")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        up = subprocess.Popen(
            [sys.executable, "-m", "abyss.cli", "up", "--port", "0", "--keep-running", "--duration",
             str(3 * args.seconds + 30 * args.clicks + 120), "--viewer", "none", "--out", str(out),
             "--system", "bench-console", "--set", "vessel.image_period_s=1"],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=ROOT,
        )  # fmt: skip
        lines: list[str] = []
        found = threading.Event()

        def read() -> None:
            for line in up.stdout or ():
                lines.append(line)
                if "pilot's console at" in line:
                    found.set()

        threading.Thread(target=read, daemon=True).start()
        if not found.wait(180.0):
            raise SystemExit("abyss up gave no console:\n" + "".join(lines))
        text = "".join(lines)
        url = re.search(r"pilot's console at (\S+)", text).group(1)  # type: ignore[union-attr]
        endpoint = re.search(r"(tcp/127\.0\.0\.1:\d+)", text).group(1)  # type: ignore[union-attr]
        arrivals: dict[float, float] = {}  # telemetry's sim time [s] -> wall arrival on shore [s]
        session = open_session(client_config(endpoint), "bench")

        def on_telemetry(sample: zenoh.Sample) -> None:
            if (t := message_of(sample, Telemetry)) is not None:
                arrivals.setdefault(t.sim_time_s, time.time())

        subscriber = session.declare_subscriber(
            keys.spec("vessel", "telemetry").key("bench-console"), on_telemetry
        )
        driver = browser(Path(tmp) / "profile")
        try:
            driver.get("about:blank")
            time.sleep(5.0)
            blank = cores(driver, args.seconds)
            driver.get(url)
            time.sleep(10.0)  # the page loaded, the first frames in
            console = cores(driver, args.seconds)
            frames = driver.execute_script("return document.getElementById('frame').naturalWidth")
            shown = driver.execute_script("return window.abyssLog.telemetry")
            delays = [page_s - arrivals[sim_s] for sim_s, page_s, _ in shown if sim_s in arrivals]
            for i in range(args.clicks):
                before = len(driver.execute_script("return Object.keys(window.abyssLog.answers)"))
                driver.find_element(By.ID, "hold" if i % 2 == 0 else "auto").click()
                deadline = time.monotonic() + 30.0
                while time.monotonic() < deadline:
                    if len(driver.execute_script("return Object.keys(window.abyssLog.answers)")) > before:
                        break
                    time.sleep(0.05)
                time.sleep(1.0)
            answers = driver.execute_script("return Object.values(window.abyssLog.answers)")
            op = []  # the peer: `abyss op`'s own send and wait, on the same path, no page
            for i in range(args.clicks):
                t0 = time.monotonic()
                command = OperatorMode(new_id(), "hold" if i % 2 == 0 else "auto")
                if send(endpoint, "bench-console", command, "mode", 30.0) is not None:
                    op.append(time.monotonic() - t0)
                time.sleep(1.0)
        finally:
            driver.quit()
            subscriber.undeclare()
            session.close()
            up.terminate()
            up.wait(60)
    answered = [a["answered_s"] - a["clicked_s"] for a in answers]
    page = [a["shown_s"] - a["clicked_s"] for a in answers]
    print(f"telemetry on shore -> shown in the page: {percentiles(delays)}")
    print(f"click -> onboard's answer at the console: {percentiles(answered)}")
    to_put = [a["sent_s"] - a["clicked_s"] for a in answers]
    put_to_answer = [a["answered_s"] - a["sent_s"] for a in answers]
    print(f"  of which click -> the console's put:     {percentiles(to_put)}")
    print(f"  and the put -> the answer:               {percentiles(put_to_answer)}")
    print(f"click -> the answer shown in the page:    {percentiles(page)}")
    print(f"abyss op's send -> onboard's answer (peer): {percentiles(op)}")
    print(f"browser CPU: {console:.3f} cores with the console open (frames at 1 Hz, {frames} px wide), "
          f"{blank:.3f} on a blank page: the page costs {console - blank:.3f} cores")  # fmt: skip


if __name__ == "__main__":
    main()
