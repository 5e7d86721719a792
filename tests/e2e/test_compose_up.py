"""`docker compose up` end to end: the image built from the Dockerfile (on a base made from
Debian's packages, as no registry is reachable here), four containers healthy, the mission done
as a tool on the host sees it, a link changed from inside a container and taken at both ends,
shore's recording in the volume, every station stopped cleanly.

The images are cached (engine.py): with nothing changed the test takes about a minute; a code
change rebuilds a thin layer in seconds; a cold cache costs a few minutes more (the base image
and ~1 GB of wheels)."""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import engine
import pytest
from conftest import abyss
from rerun.chunk import RrdReader

from abyss.common.ports import free_port
from abyss.interface import keys
from abyss.recording.reader import open_recording

LINK = "auto"  # compose.yaml's default: netem where the kernel has sch_netem, else the TUN shaper
SYSTEM = "e2e-compose"
HEALTHY_TIMEOUT_S = 120.0
MISSION_TIMEOUT_S = 180.0


HOP_ENDS = {hop: tuple(s for s in keys.STATIONS if hop in keys.hops_of(s)) for hop in keys.HOPS}


def link_show(
    endpoint: str,
    holds: Callable[[dict[tuple[str, str], dict[str, str]]], bool],
    *hop: str,
    timeout_s: float = 30.0,
) -> dict[tuple[str, str], dict[str, str]]:
    """`abyss link show --json` from the host, asked again until what it shows holds (its query
    waits 3 s for the replies, which cross the emulated links) or `timeout_s` passes: each hop
    direction's fields."""
    deadline = time.monotonic() + timeout_s
    while True:
        shown = abyss("link", "show", *hop, "--json", "--connect", endpoint, "--system", SYSTEM)
        links = {(d["hop"], d["direction"]): d["fields"] for d in json.loads(shown.stdout or "[]")}
        if holds(links) or time.monotonic() > deadline:
            return links
        engine.say(f"link show: {sorted(links)}; asking again")


def losses(links: dict[tuple[str, str], dict[str, str]]) -> dict[tuple[str, str], str]:
    return {direction: fields["loss"] for direction, fields in links.items()}


@pytest.fixture(scope="module")
def image() -> Iterator[str]:
    """The project's image on the Debian-made base, built only when its inputs changed."""
    for reason in (engine.unusable(), engine.start_engine()):
        if reason:
            pytest.skip(reason)
    try:
        engine.build_base()
    except FileNotFoundError as missing:
        pytest.skip(f"no base image and no {missing}")
    engine.build_image()
    yield engine.IMAGE


PHYSICS_PROBE = """
import shutil
import numpy as np
from abyss.config.simulation import SimulationConfig
from abyss.stations.simulation.world import World
print(World(SimulationConfig(), np.random.default_rng(0)).runs_in, shutil.which("cc"))
"""


@pytest.mark.timeout(1500)  # a cold cache: the base image, ~1 GB of wheels, then the mission
def test_the_image_runs_the_physics_in_c_and_holds_no_compiler(image: str) -> None:
    """Its build stage compiled the physics against the image's MuJoCo and left the compiler
    behind: a run in a container is a host's run (setup.sh builds the same), step for step."""
    done = engine.docker("run", "--rm", "--entrypoint", "/opt/abyss/bin/python", image, "-c", PHYSICS_PROBE)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["c", "None"], done.stdout + done.stderr


@pytest.mark.timeout(1500)  # a cold cache: the base image, ~1 GB of wheels, then the mission
def test_compose_up_runs_the_mission(image: str, tmp_path: Path) -> None:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    compose = engine.Compose(
        f"abysse2e{os.getpid()}",
        tmp_path,
        {"ABYSS_LINK": LINK, "ABYSS_SYSTEM": SYSTEM, "ABYSS_PORT": str(port)},
    )
    try:
        up = compose("up", "-d", "--no-build")
        assert up.returncode == 0, up.stderr
        engine.say(f"up: {image}, project {compose.project}, --link {LINK}, shore on {endpoint}")
        healthy_s = compose.wait_healthy(HEALTHY_TIMEOUT_S)
        engine.say(f"all healthy after {healthy_s:.1f} s")
        mission_s = compose.wait_mission(endpoint, SYSTEM, MISSION_TIMEOUT_S)
        engine.say(f"mission done {mission_s:.1f} s later")

        # each station shaped its own interfaces (it says which way), none fell back to emulating
        logs = compose.logs(tail="all")  # lines "<project>_<service>_1 | ..." (v1), "<service>-1 | ..."
        modes = {
            s: line.split("link mode auto: ", 1)[1].split()[0]
            for line in logs.splitlines()
            for s in keys.STATIONS
            if "link mode auto: " in line and s in line.split("|", 1)[0]
        }
        assert set(modes) == set(keys.STATIONS) and set(modes.values()) <= {"netem", "tun"}, (modes, logs)
        engine.say(f"link modes: {modes}")

        # a tool on the host, through shore's published port: every hop, both directions
        every_direction = {(hop, d) for hop, (a, b) in HOP_ENDS.items() for d in (f"{a}->{b}", f"{b}->{a}")}
        shown = link_show(endpoint, lambda links: set(links) == every_direction)
        assert set(shown) == every_direction, shown

        # from inside shore's container: both ends of the satellite take the change
        changed = compose(
            "exec", "-T", "onshore", "abyss", "link", "set", "satellite", "--loss", "10%", "--system", SYSTEM
        )
        # sent; only its read-back query may time out on a busy satellite (the check follows)
        assert changed.returncode == 0 or "sent, but no station" in changed.stderr, changed.stderr
        ten = {("satellite", "onshore->vessel"): "10%", ("satellite", "vessel->onshore"): "10%"}
        shown = link_show(endpoint, lambda links: losses(links) == ten, "satellite")
        assert losses(shown) == ten, shown
        engine.say("satellite loss 10% at both ends")

        stopped = compose("stop", "-t", "20")
        assert stopped.returncode == 0, stopped.stderr
        assert compose.exit_codes() == dict.fromkeys(keys.STATIONS, 0), compose.logs()
        # shore's recording, in the volume: copied out of its stopped container and read back
        recording = tmp_path / "onshore.rrd"
        copied = engine.docker("cp", f"{compose.container('onshore')}:/runs/onshore.rrd", str(recording))
        assert copied.returncode == 0, copied.stderr
        entities = {chunk.entity_path.lstrip("/") for chunk in RrdReader(recording).stream().to_chunks()}
        assert "world/vehicle" in entities, sorted(entities)[:20]
        engine.say(f"recording {recording.stat().st_size / 1e6:.1f} MB, {len(entities)} entities")
        # every station's bus recording, in the same volume, closed as each station stopped
        copied = engine.docker("cp", f"{compose.container('onshore')}:/runs/record", str(tmp_path / "record"))
        assert copied.returncode == 0, copied.stderr
        bus = open_recording(tmp_path)
        assert bus.stations == set(keys.STATIONS) and all(f.complete for f in bus.files)
        assert any(r.topic == "vessel/telemetry" for r in bus.records(("onshore",), ("received",)))
    finally:
        down = compose("down", "-v", "--remove-orphans", "-t", "10")
        assert down.returncode == 0, down.stderr
