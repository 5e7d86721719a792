"""The TCP comparison's programs that run in the lab's namespaces (`python -m
abyss.validation.tcpcheck.programs send|receive`): the sender sends a phase's schedule and counts
its namespace's TCP counters; the receiver notes when each message's last byte arrived."""

from __future__ import annotations

import argparse
import contextlib
import json
import socket
import struct
import sys
import time
from collections.abc import Sequence
from pathlib import Path

PORT = 5201
HEADER = struct.Struct("!Id")  # a message's size [bytes] and when it was due [s, CLOCK_MONOTONIC]
START_TIMEOUT_S = 20.0  # a shaper or the receiver ready, the connection made
WINDOW_GRACE_S = 1.0  # the receiver reads this long past a bulk transfer's window


def tcp_counters() -> dict[str, int]:
    """This namespace's TCP counters: {"TcpRetransSegs": ..., "TcpExtTCPTimeouts": ...}."""
    counters: dict[str, int] = {}
    for path in ("/proc/net/snmp", "/proc/net/netstat"):
        lines = Path(path).read_text().splitlines()
        for names, values in zip(lines[::2], lines[1::2], strict=True):
            kind, *keys = names.split()
            if kind in ("Tcp:", "TcpExt:"):
                numbers = values.split()[1:]
                counters.update({kind[:-1] + k: int(v) for k, v in zip(keys, numbers, strict=True)})
    return counters


def _connect(address: str, congestion_control: str, timeout_s: float) -> socket.socket:
    """A connection to the receiver with `congestion_control` and no Nagle delay, tried again
    until START_TIMEOUT_S has passed."""
    deadline_s = time.monotonic() + START_TIMEOUT_S
    while True:
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_CONGESTION, congestion_control.encode())
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        try:
            sock.settimeout(timeout_s)
            sock.connect((address, PORT))
            return sock
        except OSError:
            sock.close()
            if time.monotonic() > deadline_s:
                raise
            time.sleep(0.05)


def send(
    address: str,
    schedule: Sequence[tuple[float, int]],
    congestion_control: str,
    window_s: float | None,
    timeout_s: float,
) -> dict[str, object]:
    """Connect with `congestion_control`; send each message when it is due (no Nagle delay) and
    wait until the receiver has read everything, or, with `window_s`, send until then and reset the
    connection. When it started and this namespace's counters at the end."""
    before = tcp_counters()
    with _connect(address, congestion_control, timeout_s) as sock:
        t0_s = time.monotonic()
        end_s = t0_s + (window_s if window_s is not None else timeout_s)
        try:
            for offset_s, size in schedule:
                time.sleep(max(0.0, t0_s + offset_s - time.monotonic()))
                sock.settimeout(max(1e-3, end_s - time.monotonic()))
                sock.sendall(HEADER.pack(size, t0_s + offset_s).ljust(size, b"\0"))
            sock.shutdown(socket.SHUT_WR)
            sock.recv(1)  # the receiver closes once it has read everything
        except TimeoutError:
            if window_s is None:
                raise
        after = tcp_counters()
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))  # close: reset
    return {"t0_s": t0_s, "counters": {k: after[k] - before[k] for k in after}}


def receive(window_s: float | None, timeout_s: float) -> list[tuple[float, int, float]]:
    """Accept one connection; (due_s, size_bytes, delivered_s) of each message read from it until
    the sender closes it or, with `window_s`, until that long after the first message was due
    (the sender's reset may be lost on the way)."""
    with socket.create_server(("0.0.0.0", PORT)) as listener:
        print("ready", flush=True)
        listener.settimeout(timeout_s)
        conn, _ = listener.accept()
    out: list[tuple[float, int, float]] = []
    buffer = bytearray()
    end_s = time.monotonic() + timeout_s
    with conn, contextlib.suppress(ConnectionResetError, TimeoutError):
        while True:
            conn.settimeout(max(1e-3, end_s - time.monotonic()))
            chunk = conn.recv(1 << 20)
            if not chunk:
                break
            now_s = time.monotonic()
            buffer += chunk
            while len(buffer) >= HEADER.size and len(buffer) >= (size := HEADER.unpack_from(buffer)[0]):
                due_s = HEADER.unpack_from(buffer)[1]
                if not out and window_s is not None:
                    end_s = due_s + window_s + WINDOW_GRACE_S
                out.append((due_s, size, now_s))
                del buffer[:size]
    return out


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m abyss.validation.tcpcheck.programs")
    sub = parser.add_subparsers(dest="role", required=True)
    s = sub.add_parser("send")
    s.add_argument("--to", required=True)
    s.add_argument("--congestion-control", required=True)
    s.add_argument("--window", type=float, help="send until then [s], then reset the connection")
    r = sub.add_parser("receive")
    r.add_argument("--window", type=float, help="read until then [s] after the first message was due")
    for p in (s, r):
        p.add_argument("--timeout", type=float, default=120.0)
    args = parser.parse_args(argv)
    if args.role == "send":
        report = send(args.to, json.load(sys.stdin), args.congestion_control, args.window, args.timeout)
        print(json.dumps(report))
    else:
        print(json.dumps(receive(args.window, args.timeout)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
