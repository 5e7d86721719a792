"""The controllers' record of a run: onboard's telemetry as `abyss up` observes it (at its full
rate, after the tether), and the panel's truth, one CSV row per message, read back by
`abyss plot` and scenarios (`control.csv`, `panel.csv`; the bus's own recording, MCAP, is
`recording/`'s)."""

from __future__ import annotations

import csv
import threading
from pathlib import Path
from typing import IO, Any

import numpy as np

from abyss.interface.messages import PanelState, Telemetry

CONTROL_FILE = "control.csv"
PANEL_FILE = "panel.csv"  # the panel's truth: each part's angle and the fingers' force on it
COLUMNS = (
    "sim_time_s",
    "mode",
    "waypoint_index",
    "waypoints_total",
    "error_x_m",
    "error_y_m",
    "error_z_m",
    "heading_error_rad",
    "arm_mode",
    "ee_error_x_m",
    "ee_error_y_m",
    "ee_error_z_m",
    "ee_orientation_error_rad",
    "failsafe",
    "failsafe_events",
    "intervention_target",
    "intervention_phase",
    "gripper_opening_m",
    "gripper_force_n",
)
TEXT_COLUMNS = {"mode", "arm_mode", "failsafe", "intervention_target", "intervention_phase"}


def row_of(t: Telemetry) -> list[str | float | int]:
    return [
        t.sim_time_s,
        t.mode,
        t.waypoint_index,
        t.waypoints_total,
        *t.position_error_m_world,
        t.heading_error_rad,
        t.arm_mode,
        *t.ee_position_error_m_world,
        t.ee_orientation_error_rad,
        t.failsafe,
        t.failsafe_events,
        t.intervention_target,
        t.intervention_phase,
        t.gripper_opening_m,
        t.gripper_force_n,
    ]


def panel_columns(names: tuple[str, ...]) -> list[str]:
    return ["sim_time_s", *(f"{n}_rad" for n in names), *(f"{n}_finger_force_n" for n in names)]


class ControlRecorder:
    """Appends onboard's telemetry to RUN_DIR/control.csv and the panel's truth to
    RUN_DIR/panel.csv, a row per message, from any thread."""

    def __init__(self, run_dir: Path) -> None:
        self._file: IO[str] = (run_dir / CONTROL_FILE).open("w", newline="")
        self._writer = csv.writer(self._file)
        self._writer.writerow(COLUMNS)
        self._panel_path = run_dir / PANEL_FILE
        self._panel_file: IO[str] | None = None
        self._panel_writer: Any = None
        self._lock = threading.Lock()
        self.last: Telemetry | None = None

    def add(self, message: Telemetry | PanelState) -> None:
        with self._lock:
            if self._file.closed:
                return
            if isinstance(message, Telemetry):
                self._writer.writerow(row_of(message))
                self.last = message
                return
            if self._panel_file is None:  # the parts are the model's: the first message names them
                self._panel_file = self._panel_path.open("w", newline="")
                self._panel_writer = csv.writer(self._panel_file)
                self._panel_writer.writerow(panel_columns(message.names))
            self._panel_writer.writerow([message.sim_time_s, *message.angles_rad, *message.finger_force_n])

    def close(self) -> None:
        with self._lock:
            self._file.close()
            if self._panel_file is not None:
                self._panel_file.close()


def _columns(path: Path, text: set[str]) -> dict[str, np.ndarray]:
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        rows = list(reader)
        names = reader.fieldnames or []
    return {c: np.array([r[c] for r in rows], dtype=str if c in text else float) for c in names}


def read_control(run_dir: Path) -> dict[str, np.ndarray]:
    """The record as columns: numbers as float arrays, modes and reasons as string arrays."""
    return _columns(run_dir / CONTROL_FILE, TEXT_COLUMNS)


def read_panel(run_dir: Path) -> dict[str, np.ndarray] | None:
    """The panel's truth as columns (see `panel_columns`), or None if the run recorded none."""
    path = run_dir / PANEL_FILE
    return _columns(path, set()) if path.is_file() else None
