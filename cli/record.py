"""`abyss replay | view`: a recorded run played back in place of stations, or opened in rerun."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from abyss.cli.args import load_config
from abyss.cli.system import run_args, up_config
from abyss.common.errors import ConfigError
from abyss.config import Config
from abyss.interface import keys

COMPARE_FILE = "compare.json"


def cmd_view(args: argparse.Namespace) -> int:
    from abyss.console.view import view

    return view(run_directory(args.run_dir), args.web_port)


def run_directory(path: Path) -> Path:
    """RUN_DIR as given: a run's directory (`abyss up`'s, a scenario's, one a campaign kept), or
    the one campaign run whose id starts with its name (`runs/<campaign>/<run id>`); ConfigError
    saying what it is instead (nothing, or a campaign directory)."""
    from abyss.validation.campaign.store import PLAN_FILE, RUNS_DIR

    def kept(campaign: Path, prefix: str = "") -> list[Path]:
        runs = campaign / RUNS_DIR
        return (
            sorted(p for p in runs.iterdir() if p.is_dir() and p.name.startswith(prefix))
            if runs.is_dir()
            else []
        )

    if (path / PLAN_FILE).is_file():
        some = ", ".join(p.name for p in kept(path)[:3]) or "it kept none"
        raise ConfigError(
            "RUN_DIR",
            f"{path} is a campaign directory: give one of the runs it kept, {path / RUNS_DIR}/<run id> "
            f"({some}), or run one again with `abyss campaign replay {path} RUN_ID`",
        )
    if path.is_dir():
        return path
    if (path.parent / PLAN_FILE).is_file() and len(matches := kept(path.parent, path.name)) == 1:
        return matches[0]  # runs/<campaign>/<run id>, as the campaign's report names a run
    raise ConfigError("RUN_DIR", f"no such run directory: {path}")


def replay_config(args: argparse.Namespace, run_dir: Path) -> Config:
    """The recorded run's configuration (its `config.json`; --config in its place), --set and the
    other options on top, on the wall clock: a replay plays the recording back in real time,
    however the run kept its time (a scenario's or a campaign's lockstep, with its holds)."""
    from abyss.launch.start import CONFIG_FILE

    recorded = run_dir / CONFIG_FILE
    if args.config is not None or not recorded.is_file():
        return load_config(args)
    try:
        table = json.loads(recorded.read_text())
    except (OSError, ValueError) as exc:
        raise ConfigError("config", f"cannot read: {exc}", str(recorded)) from None
    mode = table.pop("time", {}).get("mode", "real")
    if mode != "real" and args.time is None:
        print(
            f"abyss: {run_dir} ran in {mode} time; its replay runs on the wall clock, the recording's "
            "seconds as seconds",
            flush=True,
        )
    return load_config(args, base=table)


def cmd_replay(args: argparse.Namespace) -> int:
    args.run_dir = run_directory(args.run_dir)
    if not args.as_station and not args.compare:  # what `abyss replay` was before recordings
        print(
            f"abyss: `abyss replay RUN_DIR` opening the rerun recording is now "
            f"`abyss view {args.run_dir}`; `abyss replay RUN_DIR --as STATION` plays stations back",
            file=sys.stderr,
        )
        return cmd_view(args)
    from abyss.launch.start import Replayed
    from abyss.launch.up import run_up
    from abyss.recording.compare import compare, differing, render
    from abyss.recording.reader import open_recording
    from abyss.recording.replay import check_replayable, check_speed

    if not args.as_station:
        raise ConfigError(
            "--compare", "needs the stations to replay: --as STATION (the others run live and are compared)"
        )
    check_speed(args.speed)
    run_dir = args.run_dir.resolve()
    recording = open_recording(run_dir)
    stations = tuple(dict.fromkeys(args.as_station))
    check_replayable(recording, stations)
    config = up_config(args, replay_config(args, run_dir))
    out = args.out or Path("runs") / f"{config.system}-replay-{time.strftime('%Y%m%d-%H%M%S')}"
    if out.resolve() == run_dir:
        raise ConfigError("--out", f"{out} is the recorded run; give the replay a run directory of its own")
    duration_s = args.duration
    if duration_s is None:  # the recording's length; a live shore ends the run at the mission's end
        stamps = [r.sent_s for r in recording.published()]
        duration_s = (max(stamps) - min(stamps)) / args.speed + (2.0 if "onshore" in stations else 15.0)
    # with shore replayed, no live shore judges the mission: the run is the recording's length
    keep_running = args.keep_running or "onshore" in stations
    code = run_up(
        config, out, duration_s, keep_running, args.port, replayed=Replayed(run_dir, stations, args.speed)
    )
    if not args.compare:
        return code
    live = [s for s in keys.STATIONS if s not in stations]
    diffs = compare(recording, open_recording(out), live, args.tolerance)
    print(f"abyss: {', '.join(live)} on the recorded inputs of {', '.join(stations)}, against {run_dir}:")
    print(render(diffs))
    (out / COMPARE_FILE).write_text(json.dumps([d.row() for d in diffs], indent=2))
    changed = differing(diffs)
    print(
        f"abyss: {len(changed)} of {len(diffs)} keys differ{': ' + ', '.join(changed) if changed else ''} "
        f"(tolerance {args.tolerance:g} of each field's recorded spread; {out / COMPARE_FILE})"
    )
    return 1 if changed else code


def add_commands(sub: Any) -> None:
    p = sub.add_parser("view", help="open a run's rerun recording (onshore.rrd) in the rerun viewer")
    p.add_argument("run_dir", type=Path, metavar="RUN_DIR")
    web_port_arg(p)
    p.set_defaults(func=cmd_view)

    p = sub.add_parser(
        "replay",
        help="play recorded stations back in place of live ones (the rest run live); --compare: "
        "how the live stations' outputs differ from the recording",
    )
    p.add_argument("run_dir", type=Path, metavar="RUN_DIR")
    p.add_argument(
        "--as",
        dest="as_station",
        action="append",
        default=[],
        choices=keys.STATIONS,
        metavar="STATION",
        help="a station to play back from the recording (repeatable)",
    )
    p.add_argument("--speed", type=float, default=1.0, metavar="X", help="recorded time scale (default 1)")
    p.add_argument(
        "--compare",
        action="store_true",
        help="then compare the live stations' outputs with the recording, per key; exit 1 if one differs",
    )
    p.add_argument(
        "--tolerance",
        type=float,
        default=0.1,
        metavar="FRACTION",
        help="with --compare: a field differs past this share of its recorded spread",
    )
    run_args(p, speed=False)  # a replay runs in real time, --speed scales the recording
    web_port_arg(p)
    p.set_defaults(func=cmd_replay)


def web_port_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--web-port",
        type=int,
        metavar="PORT",
        help="serve rerun's web viewer on this port instead of opening the native viewer",
    )
