"""`abyss stress satellite` as a user runs it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import abyss

pytestmark = pytest.mark.timeout(200)


def test_stress_satellite_reports_consistent_figures(tmp_path: Path) -> None:
    done = abyss(
        "stress",
        "satellite",
        "--resolutions",
        "0.2,0.1",
        "--duration",
        "6",
        "--out",
        str(tmp_path),
        timeout_s=180,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert "rendered frame 6/6" in done.stdout and "finest resolution" in done.stdout
    report = json.loads((tmp_path / "stress_satellite.json").read_text())
    assert (tmp_path / "stress_satellite.png").stat().st_size > 10_000
    results = report["results"]
    assert [r["resolution_m"] for r in results] == [0.1, 0.2]
    for r in results:
        assert 0 < r["throughput_bps"] <= r["link_rate_bps"]  # never above the link's rate
        assert (
            r["scene_delivered"] <= r["scene_offered"] and r["telemetry_delivered"] <= r["telemetry_offered"]
        )
        assert r["telemetry_delivered"] >= 10  # 2 Hz for 6 s, the last ones possibly in flight
        assert r["scene_latency_p50_ms"] >= 150  # the satellite's delay is a floor
        assert r["scene_latency_p50_ms"] <= r["scene_latency_p95_ms"]
        assert r["update_bytes_max"] <= 16_000 + 1_000  # an update and its envelope
        assert r["scene_bytes_sent"] >= r["update_bytes_mean"] * r["updates"] * 0.999
    fine, coarse = results
    assert fine["map_bt_bytes"] > coarse["map_bt_bytes"]  # a finer map is a bigger map
    assert report["finest_within_budget_m"] in (None, 0.1, 0.2)


def test_stress_rejects_bad_arguments() -> None:
    bad = abyss("stress", "satellite", "--resolutions", "fine")
    assert bad.returncode == 2 and "--resolutions" in bad.stderr and "metres" in bad.stderr
    bad = abyss("stress", "satellite", "--resolutions", "0.001")
    assert bad.returncode == 2 and "[0.02, 2] m" in bad.stderr
    bad = abyss("stress", "satellite", "--link-profile", "carrier-pigeon")
    assert bad.returncode == 2 and "carrier-pigeon" in bad.stderr
