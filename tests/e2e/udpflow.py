"""A bulk UDP flow for the lab tests (`python tests/e2e/udpflow.py ...` on a lab host).

receive ADDRESS PORT SECONDS: counts datagrams for SECONDS after the first; prints their count, IP
  bytes (payload + 28 B of headers) and the first and last arrival times as JSON.
send ADDRESS PORT RATE_BPS SECONDS PAYLOAD_BYTES: sends datagrams at RATE_BPS (IP bytes) for SECONDS."""

from __future__ import annotations

import json
import socket
import sys
import time

IP_UDP_HEADER_BYTES = 28


def receive(address: str, port: int, seconds: float) -> dict[str, float]:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind((address, port))
        sock.settimeout(30.0)
        first_s = last_s = 0.0
        packets = ip_bytes = 0
        while True:
            try:
                data = sock.recv(65536)
            except TimeoutError:
                break
            last_s = time.monotonic()
            first_s = first_s or last_s
            packets += 1
            ip_bytes += len(data) + IP_UDP_HEADER_BYTES
            sock.settimeout(max(0.01, first_s + seconds - last_s))
            if last_s - first_s >= seconds:
                break
    return {"packets": packets, "ip_bytes": ip_bytes, "first_s": first_s, "last_s": last_s}


def send(address: str, port: int, rate_bps: float, seconds: float, payload_bytes: int) -> dict[str, float]:
    gap_s = (payload_bytes + IP_UDP_HEADER_BYTES) * 8.0 / rate_bps
    sent = 0
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            sock.sendto(bytes(payload_bytes), (address, port))
            sent += 1
            time.sleep(max(0.0, t0 + sent * gap_s - time.monotonic()))
    return {"sent": sent}


if __name__ == "__main__":
    verb, args = sys.argv[1], sys.argv[2:]
    if verb == "receive":
        print(json.dumps(receive(args[0], int(args[1]), float(args[2]))))
    else:
        print(json.dumps(send(args[0], int(args[1]), float(args[2]), float(args[3]), int(args[4]))))
