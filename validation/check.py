"""`abyss check STATION`: interface testing of a running component, real or simulated. It
listens to every key the station publishes (`interface.keys.KEYS`) for a while and reports, per
key, the rate against the nominal one and how many messages decoded and validated against
their schema; a team checks a hardware driver this way before it replaces a station."""

from __future__ import annotations

import functools
import threading
import time
from collections import Counter
from dataclasses import dataclass

import zenoh

from abyss.bus.session import client_config, open_session
from abyss.common.errors import BadMessage
from abyss.interface import keys
from abyss.interface.messages import Message, decode

RATE_TOLERANCE = 0.5  # a periodic key within this share of its nominal rate passes


@dataclass(frozen=True)
class KeyReport:
    key: str
    message: str
    nominal_hz: float
    received: int
    invalid: int
    rate_hz: float
    reason: str  # the first invalid message's, or why the key fails; '' when it passes

    @property
    def passed(self) -> bool:
        return not self.reason


def check(endpoint: str, system: str, station: str, duration_s: float) -> list[KeyReport]:
    specs = [s for s in keys.KEYS if s.station == keys.check_station(station)]
    counts: Counter[str] = Counter()
    invalid: Counter[str] = Counter()
    reasons: dict[str, str] = {}
    lock = threading.Lock()

    def on_sample(sample: zenoh.Sample, message: type[Message]) -> None:
        key = str(sample.key_expr)
        try:
            decode(key, sample.payload.to_bytes(), message)
        except BadMessage as exc:
            with lock:
                invalid[key] += 1
                reasons.setdefault(key, exc.reason)
        with lock:
            counts[key] += 1

    session = open_session(client_config(endpoint), "abyss check")
    try:
        subscribers = [
            session.declare_subscriber(s.key(system), functools.partial(on_sample, message=s.message_class))
            for s in specs
        ]
        time.sleep(duration_s)
        for subscriber in subscribers:
            subscriber.undeclare()
    finally:
        session.close()
    reports = []
    for s in specs:
        key, n = s.key(system), counts[s.key(system)]
        if s.feature and not n:  # a feature the system does not run (mavlink.enabled off)
            continue
        rate_hz = n / duration_s
        reason = reasons.get(key, "")
        if not reason and s.rate_hz and abs(rate_hz - s.rate_hz) > RATE_TOLERANCE * s.rate_hz:
            reason = f"{rate_hz:.2f} Hz, nominal {s.rate_hz:g} Hz"
        reports.append(KeyReport(key, s.message, s.rate_hz, n, invalid[key], rate_hz, reason))
    return reports


def run_check(endpoint: str, system: str, station: str, duration_s: float) -> int:
    print(f"abyss check: listening to {station}'s keys of system {system} at {endpoint} for {duration_s:g} s")
    reports = check(endpoint, system, station, duration_s)
    print(f"  {'key':<48} {'message':<18} {'nominal':>8} {'rate':>8} {'received':>8} {'invalid':>7}  verdict")
    for r in reports:
        nominal = f"{r.nominal_hz:g} Hz" if r.nominal_hz else "event"
        verdict = "ok" if r.passed else f"FAIL: {r.reason}"
        print(
            f"  {r.key:<48} {r.message:<18} {nominal:>8} {r.rate_hz:>6.2f}Hz {r.received:>8} "
            f"{r.invalid:>7}  {verdict}"
        )
    periodic_silent = [r for r in reports if r.nominal_hz and not r.received]
    failed = [r for r in reports if not r.passed]
    events = [r.key for r in reports if not r.nominal_hz and not r.received]
    if events:
        print(f"  (event keys with nothing sent while listening: {', '.join(events)})")
    print(
        f"abyss check: {station}: {len(reports) - len(failed)}/{len(reports)} keys pass"
        + (f"; {len(periodic_silent)} periodic keys silent" if periodic_silent else "")
    )
    return 0 if not failed else 1
