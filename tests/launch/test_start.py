"""`abyss up`'s start and stop without Zenoh: the config the stations are given, the run
directory cleared of an earlier run, the options refused together, the signals turned into a
request to stop and put back after, and the progress line."""

from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from abyss.common.errors import ConfigError
from abyss.config import Config
from abyss.config.system import TimeConfig
from abyss.launch.start import (
    CONFIG_FILE,
    SIMULATION_STATE_FILE,
    Replayed,
    checked_external,
    prepare_run_dir,
    run_config,
)
from abyss.launch.stop import interrupts_to
from abyss.launch.supervise import progress
from abyss.recording.store import RECORD_DIR


def test_the_run_config_keeps_the_run_in_its_directory_and_lockstep_ends_on_the_duration(
    tmp_path: Path,
) -> None:
    config = run_config(Config(system="unit"), tmp_path, 30.0)
    assert config.onshore.record_dir == str(tmp_path)
    assert config.simulation.state_file == str(tmp_path / SIMULATION_STATE_FILE)
    assert config.record.directory == str(tmp_path / RECORD_DIR)
    assert config.time.end_s == 0.0  # real time: no end in the config
    lockstep = dataclasses.replace(Config(system="unit"), time=TimeConfig(mode="lockstep"))
    assert run_config(lockstep, tmp_path, 30.0).time.end_s == 30.0


def test_the_run_directory_loses_an_earlier_runs_recording_and_state(tmp_path: Path) -> None:
    (tmp_path / RECORD_DIR).mkdir()
    (tmp_path / RECORD_DIR / "onboard.mcap").write_bytes(b"old")
    (tmp_path / SIMULATION_STATE_FILE).write_bytes(b"old")
    (tmp_path / "onboard.log").write_text("kept")
    config = run_config(Config(system="unit"), tmp_path, None)
    prepare_run_dir(tmp_path, config)
    assert not (tmp_path / RECORD_DIR).exists() and not (tmp_path / SIMULATION_STATE_FILE).exists()
    assert (tmp_path / "onboard.log").read_text() == "kept"
    assert (tmp_path / CONFIG_FILE).read_text() == config.to_json()  # what the stations are given


def test_simulated_time_refuses_what_runs_on_the_wall_clock(tmp_path: Path) -> None:
    sim = dataclasses.replace(Config(system="unit"), time=TimeConfig(mode="sim"))
    with pytest.raises(ConfigError, match="--external"):
        checked_external(sim, ["onboard"], False, None)
    with pytest.raises(ConfigError, match="--replay"):
        checked_external(sim, [], False, Replayed(tmp_path, ("onboard",)))
    lockstep = dataclasses.replace(Config(system="unit"), time=TimeConfig(mode="lockstep"))
    with pytest.raises(ConfigError, match="--restart"):
        checked_external(lockstep, [], True, None)
    assert checked_external(Config(system="unit"), ["onboard"], True, None) == ("onboard",)


def test_sigint_and_sigterm_ask_to_stop_and_the_handlers_are_put_back() -> None:
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    interrupted = threading.Event()
    with interrupts_to(interrupted):
        os.kill(os.getpid(), signal.SIGTERM)
        assert interrupted.wait(5.0)  # this process is still here
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before


def test_the_progress_line_before_shore_hears_anything() -> None:
    assert progress(None, False) == "no telemetry on shore yet"


def test_a_viewer_port_held_by_another_process_is_said_with_who_holds_it(tmp_path: Path) -> None:
    """An old run's viewer server still on 9876 (as one outlived a suite): the new run takes a
    free port, and says which process holds the configured one, so the user can stop it."""
    holder = subprocess.Popen(
        [sys.executable, "-c", "import socket, sys, time\ns = socket.socket(); s.bind(('127.0.0.1', 0)); "
         "s.listen(); print(s.getsockname()[1], flush=True); time.sleep(60)"],
        stdout=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert holder.stdout is not None
        held = int(holder.stdout.readline())
        said: list[str] = []
        config = dataclasses.replace(
            Config(), onshore=dataclasses.replace(Config().onshore, viewer="web", viewer_grpc_port=held)
        )
        ran = run_config(config, tmp_path, None, said.append)
        assert ran.onshore.viewer_grpc_port != held
        assert any(f"port {held} is held by pid {holder.pid} (" in line for line in said), said
    finally:
        holder.kill()
        holder.wait()
        if holder.stdout is not None:
            holder.stdout.close()
