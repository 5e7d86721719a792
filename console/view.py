"""`abyss view`: a run's recording in rerun's native viewer, or served to a browser."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

from abyss.common.errors import ConfigError
from abyss.stations.onshore.viewer import RECORDING_FILE, rerun_command


def view(run_dir: Path, web_port: int | None) -> int:
    """Open a run's recording in rerun's native viewer, or serve it to a browser on `web_port`."""
    recording = run_dir / RECORDING_FILE
    if not recording.is_file():
        raise ConfigError("RUN_DIR", f"{run_dir} holds no {RECORDING_FILE} (a run with --viewer none?)")
    rerun = rerun_command()
    if web_port is not None:
        command = [
            rerun,
            str(recording),
            "--serve-web",
            "--bind",
            "127.0.0.1",
            "--web-viewer-port",
            str(web_port),
        ]
        print(f"abyss: serving {recording} at http://127.0.0.1:{web_port} (Ctrl-C stops)", flush=True)
    elif os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        command = [rerun, str(recording)]
    else:
        raise ConfigError("display", "no display for the native viewer; use --web-port PORT and a browser")
    try:
        return subprocess.run(command, check=False).returncode
    except KeyboardInterrupt:
        return 0
