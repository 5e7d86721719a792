"""The TCP model against kernel TCP through the TUN shaper, on the same profiles and seeds
(issue #17): kernel TCP as it ships (SACK, RACK-TLP, PRR) with Reno's window, between two
namespaces of a throw-away lab, each direction shaped by its sender's TUN shaper; the model
with made-up times. Each figure agrees when the model's and the kernel's means differ by at
most 25 % of the kernel's plus twice the standard error of the difference (their spreads over
the seeds) plus, for a per-packet count, one event per run (`tcpcheck.Agreement`).

A bounded subset of bench/tcp_model.py's table: the satellite's bulk transfer and 1 kB
messages (5 % loss: loss recovery and the window), 100 kB messages on the tether (no loss:
the initial window and slow start, a tight spread) and lone 1 kB messages on the tether at
10 % loss (recovered when the retransmission timer fires: the RTO and its floor). As root,
with /dev/net/tun; under 90 s."""

from __future__ import annotations

import os
from collections.abc import Mapping

import numpy as np
import pytest

from abyss.validation.tcpcheck.compare import agreement, run_all
from abyss.validation.tcpcheck.kernel import kernel_unusable
from abyss.validation.tcpcheck.workload import Job, Run

# the kernel's side: through the TUN shaper here; through netem inside UML (test_netem_uml.py sets
# ABYSS_TCP_VARIANT=reno-netem), so that the model, tun and netem are held to the same bounds
VARIANT = os.environ.get("ABYSS_TCP_VARIANT", "reno")
MODEL_SEEDS = range(20)
FIGURES: dict[tuple[str, str], tuple[range, tuple[str, ...]]] = {  # (case, phase) -> kernel seeds, metrics
    ("satellite", "bulk"): (range(6), ("goodput_bps", "retrans_per_packet", "timeouts_per_packet")),
    ("satellite", "1kB"): (range(6), ("latency_p50_s", "latency_p95_s")),
    ("tether", "100kB"): (range(3), ("latency_p50_s", "latency_p95_s")),
    ("tether-10%", "1kB"): (range(8), ("latency_p95_s", "retrans_per_packet", "timeouts_per_packet")),
}


@pytest.fixture(scope="module")
def runs() -> Mapping[Job, Run]:
    if reason := kernel_unusable([VARIANT]):
        pytest.skip(reason)
    return run_all(
        [
            Job(way, case, phase, seed)
            for (case, phase), (kernel_seeds, _) in FIGURES.items()
            for way, seeds in (("model", MODEL_SEEDS), (VARIANT, kernel_seeds))
            for seed in seeds
        ]
    )


@pytest.mark.timeout(150)
@pytest.mark.parametrize(
    ("case", "phase", "metric"),
    [(case, phase, metric) for (case, phase), (_, metrics) in FIGURES.items() for metric in metrics],
)
def test_model_agrees_with_kernel_tcp(runs: Mapping[Job, Run], case: str, phase: str, metric: str) -> None:
    model, kernel = (
        [r.metrics() for j, r in runs.items() if (j.way, j.case, j.phase) == (way, case, phase)]
        for way in ("model", VARIANT)
    )
    a = agreement(metric, model, kernel)
    assert a.agrees, (
        f"{case} {phase} {metric}: model {np.mean(a.model):.4g} over {len(a.model)} seeds, "
        f"kernel {VARIANT} {np.mean(a.kernel):.4g} over {len(a.kernel)}: they may differ by "
        f"{a.allowed:.4g} (model / kernel {a.ratio:.2f})"
    )
