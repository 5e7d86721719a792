"""`abyss`: the command line."""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import os
import sys
import time
from pathlib import Path
from typing import Any

import zenoh

from common import keys
from common.bus import client_config, message_of, open_session
from common.config import VIEWERS, Config, load
from common.errors import AbyssError, BadMessage, ConfigError
from common.messages import (
    FAULTS,
    LinkControl,
    LinkStats,
    SimulationControl,
    SimulationStatus,
    decode,
    encode,
)
from common.models import CAMERAS, NAV_SENSORS, SEABED_CLOUD_FILE, THRUSTERS
from common.security import TLS_DIR_ENV
from linkemu.netem import run_tc, tc_command
from linkemu.profile import FIELDS, load_profiles, profile

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


def _config_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", type=Path, help="TOML configuration file")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE",
                   help="override one configuration field")
    p.add_argument("--system", help="system id: keys are abyss/<system>/...")
    p.add_argument("--profile", action="append", default=[], metavar="HOP=NAME",
                   help=f"link profile of a hop ({', '.join(keys.HOPS)})")
    p.add_argument("--seed", type=int)
    p.add_argument("--realtime-factor", type=float, metavar="X",
                   help="simulated seconds per wall-clock second (default 1)")


def _pairs(option: str, items: list[str]) -> list[tuple[str, str]]:
    """KEY=VALUE items of a repeated option."""
    pairs = []
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key or not value:
            raise ConfigError(option, f"{item!r} is not KEY=VALUE")
        pairs.append((key, value))
    return pairs


def _config(args: argparse.Namespace) -> Config:
    overrides = list(args.set)
    if args.system:
        overrides.append(f"system={args.system}")
    if args.seed is not None:
        overrides.append(f"seed={args.seed}")
    if args.realtime_factor is not None:
        overrides.append(f"simulation.realtime_factor={args.realtime_factor}")
    for hop, name in _pairs("--profile", args.profile):
        overrides.append(f"links.{keys.check_hop(hop)}={name}")
    return load(args.config, overrides)


def _profile_args(p: argparse.ArgumentParser) -> None:
    for name in FIELDS:
        p.add_argument(f"--{name.replace('_', '-')}", dest=f"field_{name}", metavar="VALUE")


def _profile_fields(args: argparse.Namespace) -> dict[str, str]:
    return {n: getattr(args, f"field_{n}") for n in FIELDS if getattr(args, f"field_{n}") is not None}


def _client(args: argparse.Namespace) -> zenoh.Session:
    return open_session(client_config(args.connect), "abyss")


def cmd_up(args: argparse.Namespace) -> int:
    from stations.supervisor import run_up
    config = _config(args)
    if args.viewer is not None or not any(s.startswith("onshore.viewer=") for s in args.set):
        viewer = args.viewer or ("spawn" if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
                                 else "save")
        config = dataclasses.replace(config, onshore=dataclasses.replace(config.onshore, viewer=viewer))
    return run_up(config, args.out, args.duration, args.keep_running, args.port, args.external,
                  args.restart)


def cmd_replay(args: argparse.Namespace) -> int:
    from stations.onshore.viewer import replay
    return replay(args.run_dir, args.web_port)


def cmd_station(args: argparse.Namespace) -> int:
    from stations.runtime import configure_logging, run_station
    configure_logging(args.verbose)
    peers = dict(_pairs("--peer", args.peer))
    for hop in peers:
        keys.check_hop(hop)
    code = run_station(args.name, _config(args), args.listen, args.connect, args.status_file, args.link,
                       args.zenoh_mode, args.tls, peers)
    # everything is closed and written: leave without the interpreter's finalisation, which
    # aborts the process ("exception not rethrown") when a daemon thread is still inside
    # native code (an octree insertion, an ICP) as it tears the threads down
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def cmd_health(args: argparse.Namespace) -> int:
    session = _client(args)
    try:
        token = keys.alive_key(args.system, args.station)
        alive = list(session.liveliness().get(token, timeout=args.timeout))
    finally:
        session.close()
    if not any(reply.ok is not None for reply in alive):
        print(f"abyss: {args.station} of system {args.system} is not alive at {args.connect}",
              file=sys.stderr)
        return 1
    print(f"{args.station} alive")
    return 0


def cmd_certs_make(args: argparse.Namespace) -> int:
    from common import certs
    hosts: dict[str, list[str]] = {}
    for holder, host in _pairs("--host", args.host):
        if holder not in certs.HOLDERS:
            raise ConfigError("--host", f"unknown holder {holder!r}; allowed: {', '.join(certs.HOLDERS)}")
        hosts.setdefault(holder, []).append(host)
    written = certs.make(args.directory, hosts)
    print(f"abyss: wrote {len(written)} files to {args.directory}: ca.pem (give it to every host), "
          f"and <holder>.pem/.key for {', '.join(certs.HOLDERS)}; keep ca.key offline")
    return 0


def cmd_keys(_args: argparse.Namespace) -> int:
    print(keys.keys_table())
    return 0


def query_links(session: zenoh.Session, system: str, hop: str | None) -> list[LinkStats]:
    selector = keys.link_key(system, hop) if hop else keys.key(system, "link", "*")
    found = []
    for reply in session.get(selector, consolidation=zenoh.ConsolidationMode.NONE, timeout=3.0):
        if reply.ok is None:
            continue
        try:
            message = decode(str(reply.ok.key_expr), reply.ok.payload.to_bytes(), "LinkStats").message
        except BadMessage as exc:
            print(f"abyss: ignoring a bad reply: {exc}", file=sys.stderr)
            continue
        assert isinstance(message, LinkStats)
        found.append(message)
    return sorted(found, key=lambda s: (list(keys.HOPS).index(s.hop), s.direction))


def cmd_link_show(args: argparse.Namespace) -> int:
    session = _client(args)
    try:
        found = query_links(session, args.system, args.hop)
    finally:
        session.close()
    if not found:
        print(f"abyss: no station of system {args.system} answered at {args.connect}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps([{"hop": s.hop, "direction": s.direction, "profile": s.profile,
                           "fields": s.fields, "stats": s.stats} for s in found], indent=2))
        return 0
    for s in found:
        f, st = s.fields, s.stats
        print(f"{s.hop} {s.direction}: profile {s.profile}: rate {f['rate']} delay {f['delay']} "
              f"jitter {f['jitter']} loss {f['loss']} corrupt {f['corrupt']} transport {f['transport']}")
        print(f"    delivered {st['messages_delivered']:.0f}/{st['messages_offered']:.0f} messages, "
              f"{st['bytes_delivered']:.0f} B; queue drops {st['queue_drops']:.0f}, losses "
              f"{st['losses']:.0f}, retransmissions {st['retransmissions']:.0f}; delay p50/p95/p99 "
              f"{st.get('delay_p50_ms', 0):.1f}/{st.get('delay_p95_ms', 0):.1f}/"
              f"{st.get('delay_p99_ms', 0):.1f} ms")
    return 0


def cmd_link_set(args: argparse.Namespace) -> int:
    fields = _profile_fields(args)
    base = profile(args.profile_name) if args.profile_name else None
    (base or profile("ideal")).with_fields(fields)  # fail here, not in the stations
    if base is None and not fields:
        raise ConfigError("link set", "give --profile NAME and/or fields such as --loss 10%")
    session = _client(args)
    try:
        session.put(keys.link_key(args.system, args.hop),
                    encode(LinkControl(args.profile_name or "", fields), 0, time.time()))
        time.sleep(0.3)
        found = query_links(session, args.system, args.hop)
    finally:
        session.close()
    for s in found:
        print(f"{s.hop} {s.direction}: profile {s.profile} {s.fields}")
    if not found:
        print(f"abyss: sent, but no station of system {args.system} answered", file=sys.stderr)
        return 1
    return 0


def cmd_link_netem(args: argparse.Namespace) -> int:
    p = profile(args.profile_name or _default_profile(args.hop), _profile_fields(args))
    command = tc_command(args.dev, None if args.clear else p, args.netns)
    if args.print or not (args.apply or args.clear):
        print(" ".join(command))
        return 0
    run_tc(command)
    print(("cleared: " if args.clear else "applied: ") + " ".join(command))
    return 0


def _default_profile(hop: str) -> str:
    return str(getattr(Config().links, keys.check_hop(hop)))


def cmd_link_profiles(_args: argparse.Namespace) -> int:
    profiles = load_profiles()
    ideal = profiles["ideal"].fields()
    for name, p in profiles.items():
        print(f"{name:<16} " + " ".join(f"{k}={v}" for k, v in p.fields().items() if v != ideal[k]))
    return 0


def cmd_fault(args: argparse.Namespace) -> int:
    targets = {"thruster": THRUSTERS, "camera": CAMERAS, "noise": NAV_SENSORS, "clear": ("",)}[args.fault]
    if args.target not in targets:
        raise ConfigError("fault target", f"{args.target!r} not one of {', '.join(targets)}")
    try:
        control = SimulationControl(args.fault, args.target, args.value)
    except ValueError as exc:
        raise ConfigError("fault value", str(exc)) from None
    session = _client(args)
    seen: list[SimulationStatus] = []

    def on_status(sample: zenoh.Sample) -> None:
        message = message_of(sample, "SimulationStatus")
        if isinstance(message, SimulationStatus):
            seen.append(message)

    try:
        subscriber = session.declare_subscriber(keys.simulation_status_key(args.system), on_status)
        session.put(keys.simulation_control_key(args.system), encode(control, 0, time.time()))
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline and len(seen) < 2:  # the first may predate the fault
            time.sleep(0.05)
        subscriber.undeclare()
    finally:
        session.close()
    if not seen:
        print(f"abyss: sent, but no simulation of system {args.system} reported", file=sys.stderr)
        return 1
    print(f"faults now: {seen[-1].faults or 'none'}")
    return 0


def cmd_teleop(args: argparse.Namespace) -> int:
    from stations.teleop import run_teleop
    if not 0 < args.step_m <= 1.0 or not 0 < args.step_deg <= 45.0:
        raise ConfigError("teleop", "--step-m must lie in (0, 1] m and --step-deg in (0, 45] deg")
    return run_teleop(args.connect, args.system, args.step_m, args.step_deg, args.joystick)


def cmd_op(args: argparse.Namespace) -> int:
    from stations.operator import run_op
    return run_op(args.connect, args.system, args.command, args.value, args.timeout)


def cmd_scenario_run(args: argparse.Namespace) -> int:
    from stations.scenario.report import junit, markdown
    from stations.scenario.runner import run_all
    from stations.scenario.spec import load_scenario
    if args.parallel < 1:
        raise ConfigError("--parallel", f"{args.parallel}: at least 1")
    scenarios = [load_scenario(path) for path in args.files]  # every file checked before anything runs
    report_dir = args.report or Path("runs") / f"scenarios-{time.strftime('%Y%m%d-%H%M%S')}"
    results = run_all(scenarios, report_dir, args.parallel)
    if args.junit:
        junit(results, args.junit)
    print(f"abyss: {sum(r.passed for r in results)}/{len(results)} scenarios passed; report "
          f"{markdown(results, report_dir)}" + (f", JUnit {args.junit}" if args.junit else ""))
    return 0 if all(r.passed for r in results) else 1


def cmd_check(args: argparse.Namespace) -> int:
    from stations.check import run_check
    if not 0 < args.duration <= 600:
        raise ConfigError("--duration", f"{args.duration} s outside (0, 600]")
    return run_check(args.connect, args.system, args.station, args.duration)


def cmd_plot(args: argparse.Namespace) -> int:
    from stations.plot import plot_run
    for line in plot_run(args.run_dir):
        print(line)
    return 0


def cmd_terrain_build(args: argparse.Namespace) -> int:
    from common.models import MODELS_DIR, WORLD_FILE
    from stations.simulation import terrain

    cloud = terrain.read_cloud(args.cloud)
    print(f"abyss: {len(cloud)} points from {args.cloud}; Poisson reconstruction ...", flush=True)
    built = terrain.reconstruct(cloud, depth=args.depth)
    print(f"abyss: surface of {built.vertices} vertices, {built.triangles} triangles; heights "
          f"{built.heights_m.min():.2f} to {built.heights_m.max():.2f} m on a "
          f"{terrain.GRID}x{terrain.GRID} grid")
    if args.out is None:
        terrain.install(built.heights_m, MODELS_DIR, WORLD_FILE)
        print(f"abyss: wrote {MODELS_DIR / 'terrain.bin'} and the terrain of {WORLD_FILE}")
    else:
        args.out.mkdir(parents=True, exist_ok=True)
        terrain.write_hfield(built.heights_m, args.out / "terrain.bin")
        asset, geom = terrain.hfield_xml(built.heights_m, "terrain.bin")
        print(f"abyss: wrote {args.out / 'terrain.bin'}; in an MJCF beside it:\n  {asset}\n  {geom}")
    return 0


def cmd_terrain_cloud(args: argparse.Namespace) -> int:
    from stations.simulation import terrain

    terrain.write_cloud(terrain.fractal_cloud(args.seed, args.points), args.out)
    print(f"abyss: wrote {args.points} points of a fractal seabed (seed {args.seed}) to {args.out}")
    return 0


def cmd_scene_export(args: argparse.Namespace) -> int:
    from common.scene import export
    from stations.onshore import SCENE_FILE

    source = args.run_dir / SCENE_FILE
    if not source.is_file():
        raise ConfigError("RUN_DIR", f"{args.run_dir} holds no {SCENE_FILE}: not a run directory, "
                                     "or no scene reached shore in that run")
    try:
        update = decode(str(source), source.read_bytes(), "SceneUpdate").message
    except BadMessage as exc:
        raise ConfigError("RUN_DIR", f"{source}: {exc.reason}") from None
    for fmt in args.format:
        path = args.run_dir / f"scene.{fmt}"
        cells = export(update, path, fmt)  # type: ignore[arg-type]
        print(f"abyss: wrote {path} ({cells} occupied cells at {update.resolution_m:g} m)")  # type: ignore[attr-defined]
    return 0


def cmd_stress_satellite(args: argparse.Namespace) -> int:
    from stations.stress import stress_satellite

    try:
        resolutions = sorted({float(r) for r in args.resolutions.split(",")})
    except ValueError:
        raise ConfigError("--resolutions",
                          f"{args.resolutions!r} is not a comma-separated list of metres") from None
    if not resolutions or not all(0.02 <= r <= 2.0 for r in resolutions):
        raise ConfigError("--resolutions", "each resolution must lie in [0.02, 2] m")
    if not 2.0 <= args.duration <= 3600.0:
        raise ConfigError("--duration", f"{args.duration} s: allowed 2 to 3600 s")
    profile(args.link_profile)  # an unknown name fails here, with the names there are
    out = args.out or Path("runs") / f"stress-satellite-{time.strftime('%Y%m%d-%H%M%S')}"
    stress_satellite(_config(args), resolutions, args.duration, out, args.budget_ms, args.link_profile,
                     echo=lambda line: print(f"abyss: {line}", flush=True))
    return 0


def parser() -> argparse.ArgumentParser:
    root = argparse.ArgumentParser(prog="abyss", description=__doc__)
    sub = root.add_subparsers(dest="command", required=True)

    p = sub.add_parser("up", help="run all four stations on this machine")
    _config_args(p)
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.add_argument("--keep-running", action="store_true", help="stay up after the mission ends")
    p.add_argument("--out", type=Path, help="run directory (default runs/<system>-<time>)")
    p.add_argument("--port", type=int, help=f"public Zenoh port (default {7447} if free; 0: any)")
    p.add_argument("--external", action="append", default=[], choices=keys.STATIONS, metavar="STATION",
                   help="do not start this station: wait for yours (a real component) on its keys")
    p.add_argument("--restart", action="store_true", help="start a station that dies again")
    p.add_argument("--viewer", choices=VIEWERS,
                   help="save: runs/<id>/onshore.rrd (the default without a display); web: rerun's web "
                        "viewer on a local port; spawn: the native viewer (the default with a display); "
                        "none")
    p.set_defaults(func=cmd_up)

    p = sub.add_parser("station", help="run one station, e.g. on its own host")
    p.add_argument("name", choices=keys.STATIONS)
    _config_args(p)
    p.add_argument("--listen", action="append", default=[], metavar="ENDPOINT")
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT")
    p.add_argument("--status-file", type=Path, help="write counters here on exit")
    p.add_argument("--link", choices=("emulated", "netem"), default="emulated",
                   help="netem: the in-process links pass through, and tc/netem applies each hop's profile "
                        "to the interface towards its neighbour (needs CAP_NET_ADMIN and sch_netem)")
    p.add_argument("--zenoh-mode", choices=("router", "peer"), default="router",
                   help="router (default): stations on separate hosts route for each other and for tools; "
                        "peer: under a router such as `abyss up`'s")
    p.add_argument("--tls", type=Path, default=os.environ.get(TLS_DIR_ENV) or None, metavar="DIR",
                   help=f"certificates from `abyss certs make DIR`: TLS on every endpoint (tls/HOST:PORT) "
                        f"and access control (default ${TLS_DIR_ENV})")
    p.add_argument("--peer", action="append", default=[], metavar="HOP=HOST",
                   help="with --link netem: the neighbour across HOP, whose route names the interface "
                        "to shape (default: the neighbour's station name)")
    p.add_argument("-v", "--verbose", action="store_true")
    p.set_defaults(func=cmd_station)

    p = sub.add_parser("health",
                       help="exit 0 when a station's liveliness token is seen (a container's health check)")
    p.add_argument("station", choices=keys.STATIONS)
    p.add_argument("--connect", default=DEFAULT_ENDPOINT, metavar="ENDPOINT")
    p.add_argument("--system", default="default")
    p.add_argument("--timeout", type=float, default=3.0, metavar="S")
    p.set_defaults(func=cmd_health)

    certs = sub.add_parser("certs", help="certificates for authenticated links").add_subparsers(
        dest="certs", required=True)
    p = certs.add_parser("make", help="a CA and one certificate per station and for the operator's tools")
    p.add_argument("directory", type=Path, metavar="DIR")
    p.add_argument("--host", action="append", default=[], metavar="HOLDER=NAME",
                   help="an extra name or address in a holder's certificate (repeatable)")
    p.set_defaults(func=cmd_certs_make)

    p = sub.add_parser("keys", help="print the table of every key")
    p.set_defaults(func=cmd_keys)

    link = sub.add_parser("link", help="show and change the links").add_subparsers(dest="link", required=True)
    for name, func, text in (("show", cmd_link_show, "profiles and live statistics"),
                             ("set", cmd_link_set, "change a hop's profile at run time")):
        p = link.add_parser(name, help=text)
        p.add_argument("hop", nargs="?" if name == "show" else None, choices=keys.HOPS)
        p.add_argument("--connect", default=DEFAULT_ENDPOINT, metavar="ENDPOINT")
        p.add_argument("--system", default="default")
        if name == "show":
            p.add_argument("--json", action="store_true")
        else:
            p.add_argument("--profile", dest="profile_name", metavar="NAME")
            _profile_args(p)
        p.set_defaults(func=func)
    p = link.add_parser("netem", help="render or apply a profile with tc/netem")
    p.add_argument("hop", choices=keys.HOPS)
    p.add_argument("--dev", required=True, metavar="IFACE")
    p.add_argument("--netns", help="network namespace of the interface")
    p.add_argument("--profile", dest="profile_name", metavar="NAME")
    _profile_args(p)
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--print", action="store_true", help="print the tc command (default)")
    mode.add_argument("--apply", action="store_true")
    mode.add_argument("--clear", action="store_true")
    p.set_defaults(func=cmd_link_netem)
    p = link.add_parser("profiles", help="list the named profiles")
    p.set_defaults(func=cmd_link_profiles)

    p = sub.add_parser("teleop", help="drive the vehicle or the end-effector from a joystick or the keyboard")
    p.add_argument("--connect", default=DEFAULT_ENDPOINT, metavar="ENDPOINT")
    p.add_argument("--system", default="default")
    p.add_argument("--step-m", type=float, default=0.1, help="goal step per key [m] (joystick: m/s)")
    p.add_argument("--step-deg", type=float, default=5.0, help="goal step per key [deg] (joystick: deg/s)")
    p.add_argument("--joystick", type=Path, metavar="DEVICE",
                   help="Linux joystick device (default /dev/input/js0 when present; else the keyboard)")
    p.set_defaults(func=cmd_teleop)

    p = sub.add_parser("op", help="send one operator command through shore and print onboard's answer")
    p.add_argument("command", choices=("waypoints", "arm", "mode"))
    p.add_argument("value", metavar="VALUE",
                   help="waypoints: 'x,y,z,yaw; ...' [m, rad]; arm: 'x,y,z,roll,pitch,yaw' [m, rad]; "
                        "mode: hold|auto|teleop")
    p.add_argument("--connect", default=DEFAULT_ENDPOINT, metavar="ENDPOINT")
    p.add_argument("--system", default="default")
    p.add_argument("--timeout", type=float, default=15.0, metavar="S", help="wait this long for the answer")
    p.set_defaults(func=cmd_op)

    p = sub.add_parser("replay", help="open a run's recording (onshore.rrd) in the rerun viewer")
    p.add_argument("run_dir", type=Path, metavar="RUN_DIR")
    p.add_argument("--web-port", type=int, metavar="PORT",
                   help="serve rerun's web viewer on this port instead of opening the native viewer")
    p.set_defaults(func=cmd_replay)

    scenario = sub.add_parser("scenario", help="validation scenarios").add_subparsers(dest="scenario",
                                                                                       required=True)
    p = scenario.add_parser("run", help="run scenario files, each as a whole isolated system, and judge them")
    p.add_argument("files", nargs="+", type=Path, metavar="FILE")
    p.add_argument("--parallel", type=int, default=1, metavar="N", help="systems at once (default 1)")
    p.add_argument("--junit", type=Path, metavar="PATH", help="write JUnit XML here")
    p.add_argument("--report", type=Path, metavar="DIR",
                   help="report and run directories (default runs/scenarios-<time>)")
    p.set_defaults(func=cmd_scenario_run)

    p = sub.add_parser("check", help="interface test of a running station: each of its keys' rate and schema")
    p.add_argument("station", choices=keys.STATIONS)
    p.add_argument("--duration", type=float, default=10.0, metavar="S", help="listen this long (default 10)")
    p.add_argument("--connect", default=DEFAULT_ENDPOINT, metavar="ENDPOINT")
    p.add_argument("--system", default="default")
    p.set_defaults(func=cmd_check)

    p = sub.add_parser("plot", help="the paper's four figures of controller errors from a run")
    p.add_argument("run_dir", type=Path, metavar="RUN_DIR")
    p.set_defaults(func=cmd_plot)

    p = sub.add_parser("fault", help="inject a fault into a running simulation")
    p.add_argument("fault", choices=FAULTS)
    p.add_argument("target", nargs="?", default="",
                   help=f"thruster ({', '.join(THRUSTERS)}), camera ({', '.join(CAMERAS)}) or "
                        f"navigation sensor ({', '.join(NAV_SENSORS)})")
    p.add_argument("value", nargs="?", type=float, default=0.0,
                   help="thruster efficiency, camera on (1) / off (0), or noise scale")
    p.add_argument("--connect", default=DEFAULT_ENDPOINT, metavar="ENDPOINT")
    p.add_argument("--system", default="default")
    p.set_defaults(func=cmd_fault)


    scene = sub.add_parser("scene", help="the scene a run left on shore").add_subparsers(
        dest="scene", required=True)
    p = scene.add_parser("export",
                         help="write the final octree as OctoMap .bt and a coloured point cloud .ply")
    p.add_argument("run_dir", type=Path, metavar="RUN_DIR")
    p.add_argument("--format", action="append", choices=("bt", "ply"),
                   help="bt, ply, or both when repeated (default both)")
    p.set_defaults(func=cmd_scene_export)

    stress = sub.add_parser("stress", help="load evaluations").add_subparsers(dest="stress", required=True)
    p = stress.add_parser("satellite", help="scene data per octree resolution over the satellite link")
    _config_args(p)
    p.add_argument("--resolutions", default="0.05,0.1,0.2", metavar="M,M,...", help="octree resolutions [m]")
    p.add_argument("--duration", type=float, default=30.0, metavar="S",
                   help="simulated seconds per resolution")
    p.add_argument("--budget-ms", type=float, default=2000.0, help="latency budget of the p95 [ms]")
    p.add_argument("--link-profile", default="satellite", help="the link's profile (default satellite)")
    p.add_argument("--out", type=Path, help="directory for the JSON and the plot")
    p.set_defaults(func=cmd_stress_satellite)

    terrain = sub.add_parser("terrain", help="seabed terrain from a point cloud").add_subparsers(
        dest="terrain", required=True)
    p = terrain.add_parser("build", help="reconstruct a surface (Open3D) and make it the world's terrain")
    p.add_argument("cloud", nargs="?", type=Path, default=SEABED_CLOUD_FILE,
                   help="point cloud (.ply, .pcd, .xyz); default: the shipped fractal seabed")
    p.add_argument("--out", type=Path, help="write here instead of into the world model")
    p.add_argument("--depth", type=int, default=8, choices=range(5, 12), metavar="5..11",
                   help="Poisson octree depth")
    p.set_defaults(func=cmd_terrain_build)
    p = terrain.add_parser("cloud", help="write a seeded fractal seabed point cloud")
    p.add_argument("out", type=Path)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--points", type=int, default=20000)
    p.set_defaults(func=cmd_terrain_cloud)
    return root


def main(argv: list[str] | None = None) -> int:
    args: Any = parser().parse_args(argv)
    if getattr(args, "func", None) is cmd_scene_export and not args.format:
        args.format = ["bt", "ply"]
    try:
        return int(args.func(args))
    except AbyssError as exc:
        print(f"abyss: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
