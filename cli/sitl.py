"""`abyss sitl`: the simulation's physics as ArduPilot's JSON backend (docs/mavlink.md), for a
team's own ArduSub build: `abyss sitl --robot bluerov2_heavy_alpha5`, then ArduSub with
`--model JSON:127.0.0.1` (`sim_vehicle.py -v ArduSub --model JSON`). Runs until Ctrl-C."""

from __future__ import annotations

import argparse
import logging
import signal
import threading
from typing import Any


def cmd_sitl(args: argparse.Namespace) -> int:
    import numpy as np

    from abyss.config import load
    from abyss.stations.simulation.json_backend import JsonBackend, bind, serve
    from abyss.stations.simulation.world import World

    overrides = [*args.set]
    if args.robot:
        overrides.append(f"simulation.robot={args.robot}")
    if args.site:
        overrides.append(f"simulation.site={args.site}")
    config = load(args.config, overrides)
    backend = JsonBackend(World(config.simulation, np.random.default_rng(config.seed)))
    sock = bind(args.host, args.port, "--port")
    logging.basicConfig(level=logging.INFO, format="abyss: %(message)s")
    print(
        f"abyss: {backend.world.robot.name} on {backend.world.site.name} as ArduPilot's JSON physics on "
        f"udp {args.host}:{args.port}; ArduSub's motors 1-8 are its thrusters "
        + ", ".join(backend.world.robot.marine.thrusters.names[j] for j, _ in backend.mapping),
        flush=True,
    )
    datum = backend.world.site.spec.datum
    print(  # the JSON positions are north-east-down from the site's origin: ArduSub's home
        f"abyss: run ArduSub with --model JSON:{args.host} --home "
        f"{datum.latitude_deg},{datum.longitude_deg},{datum.surface_amsl_m},0",
        flush=True,
    )
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    serve(backend, sock, stop)
    c = backend.counter
    print(f"abyss: sitl: {c.last or 0} frames, {c.lost} lost, {c.resent} resent, {c.restarts} restarts")
    return 0


def add_commands(sub: Any) -> None:
    p = sub.add_parser(
        "sitl",
        help="the simulation's physics as ArduPilot's JSON backend, for a team's ArduSub (--model JSON)",
    )
    p.add_argument("--config", default=None, help="TOML configuration file")
    p.add_argument(
        "--set", action="append", default=[], metavar="SECTION.FIELD=VALUE", help="override a field"
    )
    p.add_argument(
        "--robot", default="", metavar="DIR", help="the robot package (the BlueROV2 Heavy's frame)"
    )
    p.add_argument("--site", default="", metavar="DIR", help="the site package")
    p.add_argument("--host", default="127.0.0.1", help="where to listen (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=9002, help="ArduPilot's JSON port (default 9002)")
    p.set_defaults(func=cmd_sitl)
