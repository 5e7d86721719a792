"""A run's scratch folder on its node: a worker killed mid-run leaves its own, and the next run
on the node removes it."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from abyss.validation.campaign.execute import SCRATCH_PREFIX, sweep_scratch


def test_the_scratch_of_a_worker_gone_is_swept_and_a_live_ones_kept(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    gone = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    )
    dead = tmp_path / f"{SCRATCH_PREFIX}{int(gone.stdout)}-abc"
    live = tmp_path / f"{SCRATCH_PREFIX}{os.getpid()}-def"
    other = tmp_path / f"{SCRATCH_PREFIX}notapid"  # named by someone else: left alone
    for folder in (dead, live, other):
        (folder / "run").mkdir(parents=True)
        (folder / "run" / "onboard.log").write_text("x")
    assert sweep_scratch() == [dead]
    assert not dead.exists() and live.exists() and other.exists()
