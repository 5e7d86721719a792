"""Deployment figures: what one station's image installs and how long a station takes to start,
and, where a Docker engine can run (root, docker.io), the images and compose themselves.

- apt layer: apt-packages.txt and every package it depends on, less what Debian's slim base
  already has (priority required/important), summed from the archive's Installed-Size;
- pip layer: the package's runtime requirements and theirs, summed from the installed files;
- start-up: `abyss station simulation` from exec until its liveliness token is seen, against
  the floor of a bare Python that imports zenoh and opens a session;
- images (tests/e2e/engine.py, as the compose test builds them): the base image from Debian's
  packages, the project's image cold (--cold: both images and the build cache removed first:
  every wheel downloaded again), warm with nothing changed and warm with one source file
  changed, its size and its largest layer;
- compose: `up -d` until the four containers are healthy, and until shore reports the mission
  done (with --link MODE: ABYSS_LINK; compose.yaml's default otherwise).

Run: .venv/bin/python bench/deploy.py [--cold] [--link MODE]. Prints figures; asserts nothing."""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from importlib import metadata
from pathlib import Path

from abyss.bus.session import client_config, open_session
from abyss.interface import keys
from abyss.launch.station import free_port

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "e2e"))
import engine  # noqa: E402  (the compose test's: the same images, built the same way)

MB = 1e6


def apt_packages() -> list[str]:
    lines = (ROOT / "apt-packages.txt").read_text().splitlines()
    return [line.strip() for line in lines if line.strip() and not line.startswith("#")]


def apt_show(names: list[str]) -> dict[str, dict[str, str]]:
    out = subprocess.run(
        ["apt-cache", "show", "--no-all-versions", *names], capture_output=True, text=True, check=False
    ).stdout
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
    added = {
        n: float(f.get("Installed-Size", "0")) * 1024 / MB
        for n, f in seen.items()
        if f.get("Priority") not in ("required", "important")
    }
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
            station.append(
                seconds_until_alive(
                    [
                        sys.executable,
                        "-m",
                        "abyss.cli",
                        "station",
                        "simulation",
                        "--system",
                        "bench-start",
                        "--connect",
                        endpoint,
                        "--zenoh-mode",
                        "peer",
                    ],
                    "bench-start",
                    endpoint,
                )
            )
            floor.append(
                seconds_until_alive(
                    [
                        sys.executable,
                        "-c",
                        BARE_ZENOH,
                        "peer",
                        endpoint,
                        keys.alive_key("floor", "simulation"),
                    ],
                    "floor",
                    endpoint,
                )
            )
        return sorted(station)[1], sorted(floor)[1]
    finally:
        router.terminate()
        router.wait()


def code_change_context(into: Path) -> Path:
    """A copy of the build context with one source file changed, as a commit would."""
    sources = engine.files_of(engine.copied_sources(ROOT / "Dockerfile"))
    for path in [ROOT / "Dockerfile", ROOT / ".dockerignore", *sources]:
        target = into / path.relative_to(ROOT)
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(path, target)
    with (into / "interface" / "keys.py").open("a") as keys_py:
        keys_py.write(f"# changed for the benchmark at {time.time()}\n")
    return into


def images(cold: bool) -> None:
    if cold:
        engine.docker("rmi", "-f", engine.IMAGE, engine.BASE_IMAGE)
        engine.docker("builder", "prune", "-af", timeout_s=300)
    base_s = engine.build_base()
    cold_s = engine.build_image()
    warm_s = engine.build_image(force=True)
    with tempfile.TemporaryDirectory() as tmp:
        code_s = engine.build_image(tag="abyss:bench-code-change", context=code_change_context(Path(tmp)))
    engine.docker("rmi", "abyss:bench-code-change")
    history = engine.docker("history", "--human=false", "--format", "{{.Size}}\t{{.CreatedBy}}", engine.IMAGE)
    layers = [line.split("\t", 1) for line in history.stdout.splitlines()]
    size, step = max((int(size), step) for size, step in layers)
    print("images:")
    print(
        f"  {engine.BASE_IMAGE}: "
        + (f"made in {base_s:.0f} s" if base_s else "there already")
        + f", {engine.image_size_bytes(engine.BASE_IMAGE) / MB:.0f} MB"
    )
    print(
        f"  {engine.IMAGE}: {engine.image_size_bytes(engine.IMAGE) / MB:.0f} MB; build "
        + (f"{'cold' if cold else 'first'} {cold_s:.0f} s, " if cold_s is not None else "")
        + f"warm {warm_s or 0:.1f} s (nothing changed), {code_s or 0:.1f} s (one source file changed)"
    )
    print(f"  largest layer {size / MB:.0f} MB: {step[:90]}")


def compose_up(link: str | None) -> None:
    port = free_port()
    system = "bench-compose"
    env = {"ABYSS_SYSTEM": system, "ABYSS_PORT": str(port), **({"ABYSS_LINK": link} if link else {})}
    with tempfile.TemporaryDirectory() as tmp:
        compose = engine.Compose(f"abyssbench{os.getpid()}", Path(tmp), env)
        start = time.monotonic()
        try:
            up = compose("up", "-d", "--no-build")
            assert up.returncode == 0, up.stderr
            compose.wait_healthy(120.0)
            healthy_s = time.monotonic() - start
            compose.wait_mission(f"tcp/127.0.0.1:{port}", system, 180.0)
            done_s = time.monotonic() - start
        finally:
            compose("down", "-v", "--remove-orphans", "-t", "10")
    elapsed_s = time.monotonic() - start
    print(
        f"compose (--link {link or 'default'}): up -d to all four healthy {healthy_s:.1f} s, "
        f"to the mission done {done_s:.1f} s (with down -v: {elapsed_s:.1f} s)"
    )


def main() -> None:
    options = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    options.add_argument("--cold", action="store_true", help="remove both images and the build cache first")
    options.add_argument("--link", help="the stations' --link (ABYSS_LINK); compose.yaml's default otherwise")
    args = options.parse_args()
    apt_mb, apt_n, apt_top = apt_layer()
    pip_mb, pip_n, pip_top = pip_layer()
    total = apt_mb + pip_mb
    print("image layers beyond python:3.11-slim (computed from the Dockerfile's package set):")
    print(
        f"  apt: {apt_mb:7.1f} MB in {apt_n} packages ({apt_mb / total:.0%}); largest: "
        + ", ".join(f"{n} {s:.1f}" for n, s in apt_top)
    )
    print(
        f"  pip: {pip_mb:7.1f} MB in {pip_n} distributions ({pip_mb / total:.0%}); largest: "
        + ", ".join(f"{n} {s:.1f}" for n, s in pip_top)
    )
    print(f"  total {total:.1f} MB")
    station_s, floor_s = startup()
    print(
        f"start-up to liveliness: simulation station {station_s:.2f} s, bare zenoh session {floor_s:.2f} s "
        f"({station_s / floor_s:.1f}x the floor)"
    )
    reason = engine.unusable() or engine.start_engine()
    if reason:
        print(f"images and compose: not measured: {reason}")
        return
    images(args.cold)
    compose_up(args.link)


if __name__ == "__main__":
    main()
