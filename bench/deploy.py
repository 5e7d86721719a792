"""Deployment figures: what one station's image installs (computed from the Dockerfile's package
set, as this machine has no Docker engine) and how long a station takes to start.

- apt layer: apt-packages.txt and every package it depends on, less what Debian's slim base
  already has (priority required/important), summed from the archive's Installed-Size;
- pip layer: the package's runtime requirements and theirs, summed from the installed files;
- start-up: `abyss station simulation` from exec until its liveliness token is seen, against
  the floor of a bare Python that imports zenoh and opens a session.

Run: .venv/bin/python bench/deploy.py. Prints figures; asserts nothing."""

from __future__ import annotations

import re
import subprocess
import sys
import time
from importlib import metadata
from pathlib import Path

from abyss.common import keys
from abyss.common.bus import client_config, open_session
from abyss.stations.runtime import free_port

ROOT = Path(__file__).resolve().parents[1]
MB = 1e6


def apt_packages() -> list[str]:
    lines = (ROOT / "apt-packages.txt").read_text().splitlines()
    return [line.strip() for line in lines if line.strip() and not line.startswith("#")]


def apt_show(names: list[str]) -> dict[str, dict[str, str]]:
    out = subprocess.run(["apt-cache", "show", "--no-all-versions", *names], capture_output=True,
                         text=True, check=False).stdout
    info: dict[str, dict[str, str]] = {}
    for block in out.split("\n\n"):
        fields = dict(re.findall(r"^([\w-]+): (.*)$", block, re.M))
        if "Package" in fields:
            info[fields["Package"]] = fields
    return info


def apt_layer() -> tuple[float, int, list[tuple[str, float]]]:
    """(MB, packages, largest) of the dependency closure beyond the slim base."""
    seen: dict[str, dict[str, str]] = {}
    todo = apt_packages()
    while todo:
        info = apt_show(todo)
        todo = []
        for name, fields in info.items():
            if name in seen:
                continue
            seen[name] = fields
            for clause in re.split(r",", fields.get("Depends", "") + "," + fields.get("Pre-Depends", "")):
                dep = clause.split("|")[0].strip().split(" ")[0].split(":")[0]
                if dep and dep not in seen:
                    todo.append(dep)
    added = {n: float(f.get("Installed-Size", "0")) * 1024 / MB for n, f in seen.items()
             if f.get("Priority") not in ("required", "important")}
    largest = sorted(added.items(), key=lambda item: -item[1])[:5]
    return sum(added.values()), len(added), largest


def pip_layer() -> tuple[float, int, list[tuple[str, float]]]:
    """(MB, distributions, largest) of abyss's runtime requirement closure."""
    def name_of(requirement: str) -> str:
        return re.split(r"[ ;<>=!\[~]", requirement, maxsplit=1)[0].lower().replace("_", "-")

    todo = [name_of(r) for r in metadata.requires("abyss") or [] if "extra ==" not in r]
    sizes: dict[str, float] = {}
    while todo:
        name = todo.pop()
        if name in sizes:
            continue
        try:
            dist = metadata.distribution(name)
        except metadata.PackageNotFoundError:
            continue
        sizes[name] = sum((f.size or 0) for f in dist.files or []) / MB
        todo += [name_of(r) for r in dist.requires or [] if "extra ==" not in r]
    largest = sorted(sizes.items(), key=lambda item: -item[1])[:5]
    return sum(sizes.values()), len(sizes), largest


def seconds_until_alive(command: list[str], system: str, endpoint: str, timeout_s: float = 60.0) -> float:
    """Wall time from exec of `command` until `system`'s simulation token is seen at `endpoint`."""
    watcher = open_session(client_config(endpoint), "bench")
    start = time.monotonic()
    process = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        while time.monotonic() - start < timeout_s:
            if any(r.ok is not None for r in watcher.liveliness().get(keys.alive_key(system, "simulation"))):
                return time.monotonic() - start
            time.sleep(0.02)
        raise TimeoutError(command)
    finally:
        process.terminate()
        process.wait(timeout=30)
        watcher.close()


# a bare Zenoh process: mode, endpoint (listen for a router, connect for a peer), and a token
BARE_ZENOH = """
import json, sys, time, zenoh
mode, endpoint, token = sys.argv[1:]
c = zenoh.Config()
c.insert_json5("mode", json.dumps(mode))
c.insert_json5("scouting/multicast/enabled", "false")
c.insert_json5("listen/endpoints" if mode == "router" else "connect/endpoints", json.dumps([endpoint]))
s = zenoh.open(c)
t = s.liveliness().declare_token(token)
time.sleep(600)
"""


def startup() -> tuple[float, float]:
    """(station, floor) seconds, the median of three."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = subprocess.Popen([sys.executable, "-c", BARE_ZENOH, "router", endpoint, "bench/router"])
    time.sleep(1.0)
    try:
        station, floor = [], []
        for _ in range(3):
            station.append(seconds_until_alive(
                [sys.executable, "-m", "abyss.cli", "station", "simulation", "--system", "bench-start",
                 "--connect", endpoint, "--zenoh-mode", "peer"], "bench-start", endpoint))
            floor.append(seconds_until_alive([sys.executable, "-c", BARE_ZENOH, "peer", endpoint,
                                              keys.alive_key("floor", "simulation")], "floor", endpoint))
        return sorted(station)[1], sorted(floor)[1]
    finally:
        router.terminate()
        router.wait()


def main() -> None:
    apt_mb, apt_n, apt_top = apt_layer()
    pip_mb, pip_n, pip_top = pip_layer()
    total = apt_mb + pip_mb
    print("image layers beyond python:3.11-slim (computed from the Dockerfile's package set):")
    print(f"  apt: {apt_mb:7.1f} MB in {apt_n} packages ({apt_mb / total:.0%}); largest: "
          + ", ".join(f"{n} {s:.1f}" for n, s in apt_top))
    print(f"  pip: {pip_mb:7.1f} MB in {pip_n} distributions ({pip_mb / total:.0%}); largest: "
          + ", ".join(f"{n} {s:.1f}" for n, s in pip_top))
    print(f"  total {total:.1f} MB")
    station_s, floor_s = startup()
    print(f"start-up to liveliness: simulation station {station_s:.2f} s, bare zenoh session {floor_s:.2f} s "
          f"({station_s / floor_s:.1f}x the floor)")


if __name__ == "__main__":
    main()
