"""Kernel TCP through netem, for the UML test (test_netem_uml.py): the TCP comparison's satellite
phases (bulk, 1 kB messages) with Reno as it ships, each direction shaped at its sender by
netem, SEEDS labs; prints each run's figures as JSON, one line.

    python netem_tcp.py SEEDS
"""

from __future__ import annotations

import json
import sys

from abyss.validation.tcpcheck.compare import run_all
from abyss.validation.tcpcheck.workload import Job

VARIANT = "reno-netem"
PHASES = ("bulk", "1kB")

if __name__ == "__main__":
    jobs = [Job(VARIANT, "satellite", phase, seed) for phase in PHASES for seed in range(int(sys.argv[1]))]
    runs = run_all(jobs, echo=lambda line: print(line, file=sys.stderr, flush=True))
    print(json.dumps([{"phase": job.phase, **run.metrics()} for job, run in runs.items()]))
