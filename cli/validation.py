"""`abyss scenario | check | plot | stress`: verdicts and figures."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from abyss.cli.args import (
    config_args,
    connect_args,
    load_config,
    package_args,
)
from abyss.common.errors import ConfigError
from abyss.config.linkprofile import profile
from abyss.config.system import TIME_MODES
from abyss.interface import keys

if TYPE_CHECKING:
    from abyss.validation.scenario.spec import Scenario


def cmd_scenario_run(args: argparse.Namespace) -> int:
    from abyss.validation.scenario import capacity
    from abyss.validation.scenario.report import junit, markdown
    from abyss.validation.scenario.runner import run_all
    from abyss.validation.scenario.spec import load_scenario

    scenarios = [load_scenario(path) for path in args.files]  # every file checked before anything runs
    if args.robot or args.site:
        scenarios = [on_packages(s, args.robot, args.site) for s in scenarios]
    if args.time is not None or args.time_speed is not None:
        scenarios = [on_time(s, args.time or "sim", args.time_speed) for s in scenarios]
    speeds = {s.time.speed_factor if s.time.simulated else 1.0 for s in scenarios}
    if args.parallel == "auto":
        parallel, why = capacity.auto_parallel(len(scenarios), max(speeds))
        print(f"abyss: {why}", flush=True)
    elif args.parallel.isdigit() and int(args.parallel) >= 1:
        parallel = int(args.parallel)
    else:
        raise ConfigError("--parallel", f"{args.parallel!r}: a whole number, at least 1, or auto")
    report_dir = args.report or Path("runs") / f"scenarios-{time.strftime('%Y%m%d-%H%M%S')}"
    results = run_all(scenarios, report_dir, parallel)
    capacity.record(
        json.loads(path.read_text()) for r in results if (path := r.out_dir / "summary.json").exists()
    )
    if args.junit:
        junit(results, args.junit)
    print(
        f"abyss: {sum(r.passed for r in results)}/{len(results)} scenarios passed; report "
        f"{markdown(results, report_dir)}" + (f", JUnit {args.junit}" if args.junit else "")
    )
    for r in results:  # last, where a CI log's tail shows them
        if not r.passed:
            print(f"abyss: FAIL {r.scenario.name} ({r.out_dir}): {r.why_failed}")
    return 0 if all(r.passed for r in results) else 1


def on_packages(scenario: Scenario, robot: str, site: str) -> Scenario:
    """The scenario flown by the robot and site packages asked for (--robot, --site: a shipped
    one's name, or a directory here), each checked as its configuration is."""
    import dataclasses

    from abyss.config import merge
    from abyss.description.models import package_dir
    from abyss.validation.scenario.fields import configured

    packages = {
        kind: str(package_dir(kind, value).resolve())
        for kind, value in (("robot", robot), ("site", site))
        if value
    }
    config = merge(scenario.config, {"simulation": packages})
    configured(config, f"--robot/--site ({scenario.name})")
    return dataclasses.replace(scenario, config=config)


def on_time(scenario: Scenario, mode: str, speed: str | None) -> Scenario:
    """The scenario on the time source asked for, or said why not."""
    timed, why = scenario.on_time(mode, speed)
    if why:
        print(f"abyss: {scenario.name} {why}", flush=True)
    return timed


def cmd_check(args: argparse.Namespace) -> int:
    from abyss.validation.check import run_check

    if not 0 < args.duration <= 600:
        raise ConfigError("--duration", f"{args.duration} s outside (0, 600]")
    return run_check(args.connect, args.system, args.station, args.duration)


def cmd_plot(args: argparse.Namespace) -> int:
    from abyss.validation.plot import plot_run

    for line in plot_run(args.run_dir):
        print(line)
    return 0


def cmd_stress_satellite(args: argparse.Namespace) -> int:
    from abyss.stations.simulation.rendering import choose_gl_backend

    choose_gl_backend()  # it renders in this process: before anything imports MuJoCo
    from abyss.validation.stress import stress_satellite

    try:
        resolutions = sorted({float(r) for r in args.resolutions.split(",")})
    except ValueError:
        raise ConfigError(
            "--resolutions", f"{args.resolutions!r} is not a comma-separated list of metres"
        ) from None
    if not resolutions or not all(0.02 <= r <= 2.0 for r in resolutions):
        raise ConfigError("--resolutions", "each resolution must lie in [0.02, 2] m")
    if not 2.0 <= args.duration <= 3600.0:
        raise ConfigError("--duration", f"{args.duration} s: allowed 2 to 3600 s")
    profile(args.link_profile)  # an unknown name fails here, with the names there are
    out = args.out or Path("runs") / f"stress-satellite-{time.strftime('%Y%m%d-%H%M%S')}"
    stress_satellite(
        load_config(args),
        resolutions,
        args.duration,
        out,
        args.budget_ms,
        args.link_profile,
        echo=lambda line: print(f"abyss: {line}", flush=True),
    )
    return 0


def add_commands(sub: Any) -> None:
    scenario = sub.add_parser("scenario", help="validation scenarios").add_subparsers(
        dest="scenario", required=True
    )
    p = scenario.add_parser("run", help="run scenario files, each as a whole isolated system, and judge them")
    p.add_argument("files", nargs="+", type=Path, metavar="FILE")
    p.add_argument(
        "--parallel",
        default="1",
        metavar="N|auto",
        help="systems at once (default 1); auto: as many as this machine runs in real time, from "
        "what a system measured here costs (it says how many and why)",
    )
    p.add_argument(
        "--time",
        choices=TIME_MODES,
        help="every scenario's time source (default: each one's own, real unless it says): "
        "sim runs faster than real time where the CPU allows (a scenario with an external "
        "station stays real, and says so)",
    )
    p.add_argument(
        "--speed",
        dest="time_speed",
        metavar="X|max",
        help="with --time sim: simulated seconds per wall second, or max",
    )
    package_args(p)
    p.add_argument("--junit", type=Path, metavar="PATH", help="write JUnit XML here")
    p.add_argument(
        "--report",
        type=Path,
        metavar="DIR",
        help="report and run directories (default runs/scenarios-<time>)",
    )
    p.set_defaults(func=cmd_scenario_run)

    p = sub.add_parser("check", help="interface test of a running station: each of its keys' rate and schema")
    p.add_argument("station", choices=keys.STATIONS)
    p.add_argument("--duration", type=float, default=10.0, metavar="S", help="listen this long (default 10)")
    connect_args(p)
    p.set_defaults(func=cmd_check)

    p = sub.add_parser("plot", help="the paper's four figures of controller errors from a run")
    p.add_argument("run_dir", type=Path, metavar="RUN_DIR")
    p.set_defaults(func=cmd_plot)
    stress = sub.add_parser("stress", help="load evaluations").add_subparsers(dest="stress", required=True)
    p = stress.add_parser("satellite", help="scene data per octree resolution over the satellite link")
    config_args(p)
    p.add_argument("--resolutions", default="0.05,0.1,0.2", metavar="M,M,...", help="octree resolutions [m]")
    p.add_argument(
        "--duration", type=float, default=30.0, metavar="S", help="simulated seconds per resolution"
    )
    p.add_argument("--budget-ms", type=float, default=2000.0, help="latency budget of the p95 [ms]")
    p.add_argument("--link-profile", default="satellite", help="the link's profile (default satellite)")
    p.add_argument("--out", type=Path, help="directory for the JSON and the plot")
    p.set_defaults(func=cmd_stress_satellite)
