"""`abyss up`'s stop: SIGINT and SIGTERM turned into a request to stop, and every station stopped
within its bound, whatever else failed."""

from __future__ import annotations

import signal
import subprocess
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager

from abyss.launch.start import Station

STOP_TIMEOUT_S = 10.0  # twice a station's stop bound (launch.station): past it, a defect


@contextmanager
def interrupts_to(interrupted: threading.Event) -> Iterator[None]:
    """While inside: SIGINT and SIGTERM set `interrupted` instead of ending this process; the
    handlers before are put back after."""
    previous = {s: signal.signal(s, lambda *_: interrupted.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def stop_all(stations: Iterable[Station], echo: Callable[[str], None]) -> str:
    """SIGINT to every station; one that has not stopped in `STOP_TIMEOUT_S` is killed, and
    that is a failure of the run (a station must stop within its bound): '' or that failure."""
    stations = list(stations)
    for station in stations:
        if station.process.poll() is None:
            station.process.send_signal(signal.SIGINT)
    deadline = time.monotonic() + STOP_TIMEOUT_S
    stuck = []
    for station in stations:
        try:
            station.process.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            echo(f"abyss: {station.name} did not stop in {STOP_TIMEOUT_S:g} s; killing it")
            station.process.kill()
            station.process.wait()
            stuck.append(station.name)
    return f"{', '.join(stuck)} did not stop within {STOP_TIMEOUT_S:g} s" if stuck else ""
