"""`abyss campaign run | merge | replay`: the scenario library times seeds times variations on
Ray, judged as pass rates, every failing run replayable."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any


def say(line: str) -> None:
    print(f"abyss: {line}", flush=True)


def cmd_campaign_run(args: argparse.Namespace) -> int:
    from abyss.validation.campaign.drive import run_campaign
    from abyss.validation.campaign.plan import parse_shard
    from abyss.validation.campaign.spec import load_campaign

    campaign = load_campaign(args.file)  # every file checked before anything starts
    shard = parse_shard(args.shard) if args.shard else None
    out = args.out or Path("runs") / f"campaign-{campaign.name}-{time.strftime('%Y%m%d-%H%M%S')}"
    return run_campaign(campaign, out, args.address, args.resume, shard, say)


def cmd_campaign_merge(args: argparse.Namespace) -> int:
    from abyss.validation.campaign.drive import conclude
    from abyss.validation.campaign.report import merge

    report = merge(args.dirs, args.out)
    return conclude(report, args.out, say)


def cmd_campaign_replay(args: argparse.Namespace) -> int:
    from abyss.validation.campaign.replay import replay

    return replay(args.dir, args.run_id, say)


def add_commands(sub: Any) -> None:
    campaign = sub.add_parser(
        "campaign", help="scenarios x seeds x variations on Ray, judged as pass rates"
    ).add_subparsers(dest="campaign", required=True)
    p = campaign.add_parser("run", help="run a campaign file's runs on Ray (local, or a cluster) and report")
    p.add_argument("file", type=Path, metavar="CAMPAIGN.toml")
    p.add_argument(
        "--address",
        metavar="HOST:PORT",
        help="a Ray cluster's address (its head's GCS, e.g. 10.0.0.1:6379); default: a local Ray "
        "on this machine's cores, started and stopped by the command",
    )
    p.add_argument(
        "--out", type=Path, metavar="DIR", help="the campaign directory (default runs/campaign-<name>-<time>)"
    )
    p.add_argument("--resume", action="store_true", help="go on in --out: run only what has no result there")
    p.add_argument("--shard", metavar="K/N", help="run only the K-th of N slices of the plan (CI matrices)")
    p.set_defaults(func=cmd_campaign_run)

    p = campaign.add_parser("merge", help="one report from the directories of a campaign's shards")
    p.add_argument("dirs", nargs="+", type=Path, metavar="DIR")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="where the merged report goes")
    p.set_defaults(func=cmd_campaign_merge)

    p = campaign.add_parser("replay", help="run one of a campaign's runs again, and compare it byte for byte")
    p.add_argument("dir", type=Path, metavar="DIR", help="the campaign directory")
    p.add_argument("run_id", metavar="RUN_ID", help="the run's id (a unique prefix will do)")
    p.set_defaults(func=cmd_campaign_replay)
