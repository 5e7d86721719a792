"""A station runs numpy's BLAS (and OpenMP) on one thread unless its user asked for more: the
pools' spinning threads cost a station about as much CPU as its own work (launch.station)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

PROBE = """
import json, numpy
from threadpoolctl import threadpool_info
before = [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]
from abyss.launch.station import single_threaded_native_pools
single_threaded_native_pools()
after = [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]
import os
print(json.dumps({"before": before, "after": after, "omp": os.environ["OMP_NUM_THREADS"]}))
"""


def probe(**env: str) -> dict[str, object]:
    environment = {k: v for k, v in os.environ.items() if not k.endswith("_NUM_THREADS")}
    out = subprocess.run(
        [sys.executable, "-c", PROBE],
        env={**environment, **env},
        capture_output=True,
        text=True,
        check=True,
        timeout=60,
    ).stdout
    return dict(json.loads(out))


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="one core: numpy's pool has one thread anyway")
def test_a_station_limits_numpy_pool_to_one_thread() -> None:
    found = probe()
    assert found["before"] and all(n > 1 for n in found["before"])  # numpy's own default: a pool
    assert found["after"] == [1] * len(found["before"])
    assert found["omp"] == "1"  # for libraries loaded later (Open3D)


def test_a_users_own_setting_stands() -> None:
    found = probe(OPENBLAS_NUM_THREADS="2", OMP_NUM_THREADS="2")
    assert found["after"] == [2] * len(found["after"]) and found["after"]
    assert found["omp"] == "2"
