"""A scenario written from docs/scenarios.md runs as written: its first example, copied into a
file as a reader would, run by `abyss scenario run` (in lockstep, so that it costs the suite
less wall time and its events land on their periods) to a pass, its events carried out."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from conftest import ROOT, abyss

pytestmark = pytest.mark.timeout(300)


def test_the_docs_first_scenario_runs_as_written(tmp_path: Path) -> None:
    example = re.findall(r"```toml\n(.*?)```", (ROOT / "docs" / "scenarios.md").read_text(), re.DOTALL)[0]
    path = tmp_path / "mine.toml"
    path.write_text(example)
    done = abyss(
        "scenario", "run", str(path), "--time", "lockstep", "--report", "rep", timeout_s=280, cwd=tmp_path
    )
    assert done.returncode == 0, done.stdout[-6000:] + done.stderr
    said = done.stdout
    assert "link tether -> outage" in said and "link tether -> tether" in said, said[
        -6000:
    ]  # both carried out
