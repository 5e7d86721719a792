"""`abyss up` from a user's project folder that has folders named like abyss's own: `common/`,
`stations/`, even `abyss/`. The installed console script and the four stations it starts
(run in the run directory, with `python -P`) must import abyss's modules, never the user's."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ARM_MISSION

pytestmark = pytest.mark.timeout(150)

# every top-level name abyss imports under, and the import package itself
SHADOWS = (
    "abyss",
    "common",
    "config",
    "interface",
    "bus",
    "timing",
    "stations",
    "linkemu",
    "launch",
    "cli",
    "console",
    "validation",
)
BROKEN = "raise RuntimeError(\"wrong {name} imported: the user's folder shadows abyss's\")\n"
# an upper bound in simulated seconds: `abyss up` ends when shore sees the mission done (ARM_MISSION:
# about 28 s), in lockstep (what is tested is where abyss imports from, not time: the load changes
# the wall time and never the verdict), so a generous one costs nothing
DURATION_S = 90


def console_script() -> Path:
    script = Path(sys.executable).with_name("abyss")
    if not script.is_file():
        found = shutil.which("abyss")
        assert found, "no `abyss` console script next to the interpreter or on PATH"
        script = Path(found)
    return script


def shadow(folder: Path) -> None:
    for name in SHADOWS:
        (folder / name).mkdir(parents=True)
        (folder / name / "__init__.py").write_text(BROKEN.format(name=name))


def test_up_flies_the_mission_beside_folders_that_shadow_abyss(tmp_path: Path) -> None:
    shadow(tmp_path)  # the user's current directory
    shadow(tmp_path / "run")  # and the run directory, the stations' current directory
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONSAFEPATH")}
    process = subprocess.Popen(
        [
            console_script(),
            "up",
            "--time",
            "lockstep",
            "--duration",
            str(DURATION_S),
            "--port",
            "0",
            "--out",
            "run",
            "--viewer",
            "none",
            "--system",
            "shadow",
            *ARM_MISSION,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=tmp_path,
        env=env,
        start_new_session=True,
    )
    try:
        output, _ = process.communicate(timeout=DURATION_S + 45)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)  # what is left of it when the test failed
        process.wait()
    assert process.returncode == 0, output
    assert "wrong" not in output, output
    run = tmp_path / "run"
    summary = json.loads((run / "summary.json").read_text())
    assert summary["verdict"] == "done", output
    assert summary["mission"] is not None and summary["mission"]["done"] is True, output
    assert summary["mission_done_s"] is not None and summary["mission_done_s"] < DURATION_S
    for name, station in summary["stations"].items():
        assert station["exit_code"] == 0 and station["alive_seen"], (name, station)
        log = (run / f"{name}.log").read_text()
        assert "wrong" not in log, log
    state = json.loads((run / "state.json").read_text())
    assert state["phase"] == "ended" and state["verdict"] == "done" and state["mission_done"] is True
    assert not (tmp_path / "runs").exists()  # --out was taken relative to the current directory
