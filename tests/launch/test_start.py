"""`abyss up`'s start and stop without Zenoh: the config the stations are given, the run
directory cleared of an earlier run, the options refused together, the signals turned into a
request to stop and put back after, and the progress line."""

from __future__ import annotations

import dataclasses
import os
import signal
import threading
from pathlib import Path

import pytest

from abyss.common.config import Config
from abyss.common.config.system import TimeConfig
from abyss.common.errors import ConfigError
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
