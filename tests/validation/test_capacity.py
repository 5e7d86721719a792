"""`--parallel auto` (validation/scenario/capacity.py): the systems at once follow from the cores
here and what a system measured here costs, kept across runs in the user's cache; before any
measurement, the project's own figure; a bad --parallel fails at start naming itself."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from abyss.cli import main
from abyss.validation.scenario import capacity


def summary(*cores: float) -> dict:  # type: ignore[type-arg]
    return {"stations": {f"s{i}": {"cpu": {"cores": c}} for i, c in enumerate(cores)}}


def test_auto_parallel_follows_the_cost_measured_here(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert capacity.measured_cores() == (
        capacity.REFERENCE_CORES,
        "the project's measurement (none here yet)",
    )
    capacity.record([summary(0.2, 0.2), summary(0.3, 0.1), {"stations": {}}, summary(0.4, 0.2)])
    cores, source = capacity.measured_cores()
    assert cores == pytest.approx(0.4) and "latest 3 systems" in source  # the median; nothing from no CPU
    capacity.record([summary(0.1)] * capacity.KEPT)
    assert capacity.measured_cores()[0] == pytest.approx(0.1)  # only the latest are kept
    monkeypatch.setattr(capacity, "available_cores", lambda: 2.0)
    count, why = capacity.auto_parallel(scenarios=40)
    assert count == 16 and "16 systems at once (2 cores here" in why  # floor(0.8 * 2 / 0.1)
    assert capacity.auto_parallel(scenarios=5)[0] == 5  # never more than there are scenarios
    capacity.cost_file().write_text("{not json")
    assert capacity.measured_cores()[0] == capacity.REFERENCE_CORES  # a spoilt file is no measurement
    assert 1 <= capacity.available_cores() <= (os.cpu_count() or 1)


@pytest.mark.parametrize("value", ["0", "-1", "many", "1.5"])
def test_a_bad_parallel_fails_at_start_naming_it(value: str, capsys: pytest.CaptureFixture[str]) -> None:
    nominal = Path(__file__).resolve().parents[2] / "scenarios" / "nominal.toml"
    assert main(["scenario", "run", str(nominal), "--parallel", value]) == 2
    assert f"--parallel: '{value}': a whole number, at least 1, or auto" in capsys.readouterr().err
