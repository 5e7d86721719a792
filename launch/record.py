"""The controllers' record of a run: onboard's telemetry as `abyss up` observes it (at its full
rate, after the tether), one CSV row per message, read back by `abyss plot` and scenarios."""

from __future__ import annotations

import csv
import threading
from pathlib import Path
from typing import IO

import numpy as np

from abyss.common.messages import Telemetry

CONTROL_FILE = "control.csv"
COLUMNS = ("sim_time_s", "mode", "waypoint_index", "waypoints_total",
           "error_x_m", "error_y_m", "error_z_m", "heading_error_rad",
           "arm_mode", "ee_error_x_m", "ee_error_y_m", "ee_error_z_m", "ee_orientation_error_rad",
           "failsafe", "failsafe_events")


def row_of(t: Telemetry) -> list[str | float | int]:
    return [t.sim_time_s, t.mode, t.waypoint_index, t.waypoints_total, *t.position_error_m_world,
            t.heading_error_rad, t.arm_mode, *t.ee_position_error_m_world, t.ee_orientation_error_rad,
            t.failsafe, t.failsafe_events]


class ControlRecorder:
    """Appends telemetry rows to RUN_DIR/control.csv from any thread."""

    def __init__(self, run_dir: Path) -> None:
        self._file: IO[str] = (run_dir / CONTROL_FILE).open("w", newline="")
        self._writer = csv.writer(self._file)
        self._writer.writerow(COLUMNS)
        self._lock = threading.Lock()
        self.last: Telemetry | None = None

    def add(self, telemetry: Telemetry) -> None:
        with self._lock:
            if self._file.closed:
                return
            self._writer.writerow(row_of(telemetry))
            self.last = telemetry

    def close(self) -> None:
        with self._lock:
            self._file.close()


def read_control(run_dir: Path) -> dict[str, np.ndarray]:
    """The record as columns: numbers as float arrays, modes and reasons as string arrays."""
    path = run_dir / CONTROL_FILE
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    text = {"mode", "arm_mode", "failsafe"}
    return {c: np.array([r[c] for r in rows], dtype=str if c in text else float) for c in COLUMNS}
