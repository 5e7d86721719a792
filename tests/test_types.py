"""mypy, as configured in pyproject.toml, finds nothing in the package.

The package `abyss` is the repository root itself (pyproject's package-dir maps abyss -> .), and
the editable install reaches it through an import hook that mypy cannot follow. So the test makes
a folder holding one symlink, `abyss` -> the repository, and checks `-p abyss` with that folder on
MYPYPATH: every module has its real name (abyss.bus.session, ...). mypy runs in that folder, so
the paths it reports, and matches pyproject's `exclude` against (tests/, bench/, .venv/, build
outputs), begin `abyss/` whatever the temporary folder is called."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.timeout(300)
def test_mypy_is_clean(tmp_path: Path) -> None:
    search = tmp_path / "path"
    search.mkdir()
    (search / "abyss").symlink_to(ROOT, target_is_directory=True)
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "mypy",
            "--config-file",
            str(ROOT / "pyproject.toml"),
            "--cache-dir",
            str(tmp_path / "cache"),
            "-p",
            "abyss",
        ],
        capture_output=True,
        text=True,
        cwd=search,
        env={**os.environ, "MYPYPATH": str(search)},
        timeout=280,
    )
    assert done.returncode == 0, done.stdout + done.stderr
