"""The operator's recording stream and its sinks with a real rerun web server: the gRPC sink
connects only once the server listens (one that found nobody gave up for good, and the browser
saw the recording's properties alone), a viewer that comes late gets what came before it, a
server that goes away costs shore nothing, and the server never outlives shore."""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from rerun.chunk import RrdReader

from abyss.common.ports import free_port, listening
from abyss.config.stations import OnshoreConfig
from abyss.stations.onshore.viewer import RECORDING_FILE, Sinks, rerun_command

pytestmark = pytest.mark.timeout(120)


def web(tmp_path: Path) -> OnshoreConfig:
    return OnshoreConfig(
        viewer="web", viewer_grpc_port=free_port(), viewer_web_port=free_port(), record_dir=str(tmp_path)
    )


def entities(path: Path) -> set[str]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a stream cut short has no footer
        try:
            return {c.entity_path for c in RrdReader(path).stream().to_chunks()}
        except Exception:  # not written yet, or cut mid-chunk
            return set()


def log_vehicle(sinks: Sinks, steps: int = 10) -> None:
    assert sinks.recording is not None
    for i in range(steps):
        sinks.recording.set_time("stamp", duration=0.1 * i)
        sinks.recording.log("world/vehicle", rr.Points3D(np.zeros((4, 3))))


def test_the_server_listens_before_the_sink_connects_and_a_late_viewer_gets_what_came_before(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    cfg = web(tmp_path)
    sinks = Sinks(cfg, "e2e")
    late: subprocess.Popen[bytes] | None = None
    try:
        assert listening(cfg.viewer_grpc_port) and listening(cfg.viewer_web_port)
        log_vehicle(sinks)
        saved = tmp_path / "late.rrd"  # a viewer that came after the data, as a browser does
        late = subprocess.Popen(
            [rerun_command(), f"rerun+http://127.0.0.1:{cfg.viewer_grpc_port}/proxy", "--save", str(saved),
             "--port", str(free_port())], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
        deadline_s = time.monotonic() + 60.0
        while "/world/vehicle" not in entities(saved) and time.monotonic() < deadline_s:
            time.sleep(0.2)
        assert "/world/vehicle" in entities(saved)
    finally:
        if late is not None:
            late.terminate()
            late.wait()
        with caplog.at_level(logging.WARNING):
            sinks.close()
    assert not caplog.records  # the stream was whole to its end
    assert not listening(cfg.viewer_grpc_port) and not listening(cfg.viewer_web_port)
    assert "/world/vehicle" in entities(tmp_path / RECORDING_FILE)


def test_a_viewer_gone_costs_shore_nothing_and_the_file_keeps_everything(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    sinks = Sinks(web(tmp_path), "e2e")
    log_vehicle(sinks, 3)
    assert sinks.server is not None
    sinks.server.kill()  # the viewer's server gone mid-run
    sinks.server.wait()
    log_vehicle(sinks, 10)
    with caplog.at_level(logging.WARNING):
        sinks.close()  # does not raise
    assert "/world/vehicle" in entities(tmp_path / RECORDING_FILE)


def test_a_held_port_is_said_and_the_run_goes_on_without_a_web_viewer(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    cfg = web(tmp_path)
    import socket

    with socket.socket() as holder:
        holder.bind(("127.0.0.1", cfg.viewer_grpc_port))
        holder.listen()
        with caplog.at_level(logging.ERROR):
            sinks = Sinks(cfg, "e2e")
        assert sinks.server is None
        assert f"port [{cfg.viewer_grpc_port}] is held" in caplog.text
        log_vehicle(sinks)
        sinks.close()
    assert "/world/vehicle" in entities(tmp_path / RECORDING_FILE)


SHORE = """
import sys, time
from abyss.config.stations import OnshoreConfig
from abyss.stations.onshore.viewer import Sinks
grpc_port, web_port = map(int, sys.argv[1:])
sinks = Sinks(OnshoreConfig(viewer="web", viewer_grpc_port=grpc_port, viewer_web_port=web_port), "e2e")
print(sinks.server.pid, flush=True)
time.sleep(600)
"""


def test_the_web_server_ends_with_shore_even_when_shore_is_killed() -> None:
    shore = subprocess.Popen(
        [sys.executable, "-c", SHORE, str(free_port()), str(free_port())], stdout=subprocess.PIPE, text=True
    )
    assert shore.stdout is not None
    server_pid = int(shore.stdout.readline())
    os.kill(shore.pid, signal.SIGKILL)
    shore.wait()
    shore.stdout.close()
    deadline_s = time.monotonic() + 30.0
    while time.monotonic() < deadline_s:
        try:
            os.kill(server_pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.1)
    else:
        os.kill(server_pid, signal.SIGKILL)
        pytest.fail("rerun's web server outlived shore")
