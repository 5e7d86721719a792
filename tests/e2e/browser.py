"""Headless Debian Chromium driven over the DevTools protocol: open a page, take screenshots,
evaluate JavaScript in it. WebGL runs on SwiftShader (software), as a machine without a GPU has it."""

from __future__ import annotations

import base64
import contextlib
import json
import shutil
import subprocess
import time
import urllib.request
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from websockets.sync.client import ClientConnection, connect

FLAGS = ("--headless=new", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
         "--ignore-gpu-blocklist", "--enable-webgl", "--no-first-run", "--no-default-browser-check",
         "--disable-dev-shm-usage", "--mute-audio")  # fmt: skip


def chromium() -> str | None:
    return shutil.which("chromium")


class Browser:
    def __init__(self, profile_dir: Path, debug_port: int, width_px: int = 1280, height_px: int = 800):
        executable = chromium()
        assert executable is not None
        self.next_id = 0
        self.stack = contextlib.ExitStack()
        self.process = subprocess.Popen(
            [executable, *FLAGS, f"--window-size={width_px},{height_px}", f"--user-data-dir={profile_dir}",
             f"--remote-debugging-port={debug_port}", "--remote-debugging-address=127.0.0.1", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
        self.stack.callback(self._stop)
        try:
            self._attach(debug_port, width_px, height_px)
        except BaseException:
            self.stack.close()
            raise

    def _attach(self, debug_port: int, width_px: int, height_px: int) -> None:
        deadline = time.monotonic() + 30.0
        while True:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{debug_port}/json/list", timeout=2) as answer:
                    targets = json.load(answer)
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)
        page = next(t for t in targets if t.get("type") == "page")
        self.ws: ClientConnection = self.stack.enter_context(
            connect(page["webSocketDebuggerUrl"], max_size=None, open_timeout=30)
        )
        self.call("Emulation.setDeviceMetricsOverride", width=width_px, height=height_px, deviceScaleFactor=1,
                  mobile=False)  # fmt: skip

    def call(self, method: str, timeout_s: float = 60.0, **params: Any) -> dict[str, Any]:
        self.next_id += 1
        self.ws.send(json.dumps({"id": self.next_id, "method": method, "params": params}))
        deadline = time.monotonic() + timeout_s
        while True:  # events in between are not needed
            answer = json.loads(self.ws.recv(timeout=max(0.1, deadline - time.monotonic())))
            if answer.get("id") == self.next_id:
                if "error" in answer:
                    raise RuntimeError(f"{method}: {answer['error']}")
                return dict(answer.get("result", {}))

    def open(self, url: str) -> None:
        self.call("Page.navigate", url=url)

    def evaluate(self, expression: str) -> Any:
        """The value of a JavaScript expression in the page (JSON-serialisable)."""
        answer = self.call("Runtime.evaluate", expression=expression, returnByValue=True)
        if "exceptionDetails" in answer:
            raise RuntimeError(f"{expression}: {answer['exceptionDetails']}")
        return answer["result"].get("value")

    def screenshot(self) -> np.ndarray:
        """The page as BGR pixels."""
        png = base64.b64decode(self.call("Page.captureScreenshot", timeout_s=120.0, format="png")["data"])
        return cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)

    def close(self) -> None:
        self.stack.close()

    def _stop(self) -> None:
        self.process.terminate()
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
