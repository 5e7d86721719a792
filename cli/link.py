"""`abyss link show | set | netem | shape | profiles`: the links of a running system."""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any

from abyss.cli.args import (
    client,
    connect_args,
    profile_args,
    profile_fields,
)
from abyss.common.errors import ConfigError
from abyss.config import Config
from abyss.config.linkprofile import load_profiles, profile
from abyss.interface import keys
from abyss.interface.messages import (
    LinkControl,
    encode,
)
from abyss.linkemu.control import query_links
from abyss.linkemu.netem import run_tc, tc_command


def cmd_link_show(args: argparse.Namespace) -> int:
    session = client(args)
    try:
        found = query_links(session, args.system, args.hop)
    finally:
        session.close()
    if not found:
        print(f"abyss: no station of system {args.system} answered at {args.connect}", file=sys.stderr)
        return 1
    if args.json:
        print(
            json.dumps(
                [
                    {
                        "hop": s.hop,
                        "direction": s.direction,
                        "profile": s.profile,
                        "fields": s.fields,
                        "stats": s.stats,
                    }
                    for s in found
                ],
                indent=2,
            )
        )
        return 0
    for s in found:
        f, st = s.fields, s.stats
        print(
            f"{s.hop} {s.direction}: profile {s.profile}: rate {f['rate']} delay {f['delay']} "
            f"jitter {f['jitter']} loss {f['loss']} corrupt {f['corrupt']} transport {f['transport']}"
        )
        delays = (
            f"delay p50/p95/p99 {st.get('delay_p50_ms', 0):.1f}/{st.get('delay_p95_ms', 0):.1f}/"
            f"{st.get('delay_p99_ms', 0):.1f} ms"
        )
        print(
            f"    delivered {st['messages_delivered']:.0f}/{st['messages_offered']:.0f} messages, "
            f"{st['bytes_delivered']:.0f} B"
        )
        if "packets_forwarded" in st:  # the TUN shaper: packets, and the kernel's TCP retransmits
            print(
                f"    TUN shaper: {st['packets_forwarded']:.0f}/{st['packets_sent']:.0f} packets out; "
                f"queue drops {st['queue_drops']:.0f}, losses {st['losses']:.0f}, "
                f"outages {st.get('outages', 0):.0f}, corrupted "
                f"{st['packets_corrupted']:.0f}, dropped at the TUN {st['tun_tx_dropped']:.0f}; {delays}"
            )
        elif "netem_drops" in st:  # netem: the kernel's counters of the packets
            print(
                f"    netem: {st['packets_sent']:.0f} packets ({st['bytes_sent']:.0f} B) out; dropped "
                f"{st['netem_drops']:.0f} (losses and over its limit), backlog "
                f"{st['netem_backlog_packets']:.0f} packets"
            )
        else:
            print(
                f"    queue drops {st.get('queue_drops', 0):.0f}, losses {st.get('losses', 0):.0f}, "
                f"outages {st.get('outages', 0):.0f}, "
                f"retransmissions {st.get('retransmissions', 0):.0f}; {delays}"
            )
    return 0


def cmd_link_set(args: argparse.Namespace) -> int:
    fields = profile_fields(args)
    base = profile(args.profile_name) if args.profile_name else None
    (base or profile("ideal")).with_fields(fields)  # fail here, not in the stations
    if base is None and not fields:
        raise ConfigError("link set", "give --profile NAME and/or fields such as --loss 10%")
    session = client(args)
    try:
        session.put(
            keys.link_key(args.system, args.hop),
            encode(LinkControl(args.profile_name or "", fields), 0, time.time()),
        )
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
    p = profile(args.profile_name or _default_profile(args.hop), profile_fields(args))
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


def add_commands(sub: Any) -> None:
    link = sub.add_parser("link", help="show and change the links").add_subparsers(dest="link", required=True)
    for name, func, text in (
        ("show", cmd_link_show, "profiles and live statistics"),
        ("set", cmd_link_set, "change a hop's profile at run time"),
    ):
        p = link.add_parser(name, help=text)
        p.add_argument("hop", nargs="?" if name == "show" else None, choices=keys.HOPS)
        connect_args(p)
        if name == "show":
            p.add_argument("--json", action="store_true")
        else:
            p.add_argument("--profile", dest="profile_name", metavar="NAME")
            profile_args(p)
        p.set_defaults(func=func)
    p = link.add_parser("netem", help="render or apply a profile with tc/netem")
    p.add_argument("hop", choices=keys.HOPS)
    p.add_argument("--dev", required=True, metavar="IFACE")
    p.add_argument("--netns", help="network namespace of the interface")
    p.add_argument("--profile", dest="profile_name", metavar="NAME")
    profile_args(p)
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--print", action="store_true", help="print the tc command (default)")
    mode.add_argument("--apply", action="store_true")
    mode.add_argument("--clear", action="store_true")
    p.set_defaults(func=cmd_link_netem)
    p = link.add_parser(
        "shape",
        help="shape this host's packets to a neighbour with the TUN shaper "
        "(for a host without a station: your own component)",
    )
    p.add_argument("hop", choices=keys.HOPS)
    p.add_argument("--peer", required=True, metavar="HOST", help="the neighbour across HOP (name or address)")
    p.add_argument("--profile", dest="profile_name", metavar="NAME")
    profile_args(p)
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.add_argument("--every", type=float, default=5.0, metavar="S", help="print statistics every S seconds")
    p.set_defaults(func=cmd_link_shape)
    p = link.add_parser("profiles", help="list the named profiles")
    p.set_defaults(func=cmd_link_profiles)


def cmd_link_shape(args: argparse.Namespace) -> int:
    """A host without a station (a real component in a namespace or container): its packets
    towards the neighbour across HOP through the TUN shaper, until Ctrl-C or --duration."""
    import ipaddress
    import signal
    import threading

    import numpy as np

    from abyss.linkemu.route import route_towards
    from abyss.linkemu.tun import TunShaper, tun_name

    p = profile(args.profile_name or _default_profile(args.hop), profile_fields(args))
    route = route_towards(args.peer)
    # one random stream per direction: both ends of a hop drawing the same delays would correlate them
    rng = np.random.default_rng([p.seed, int(ipaddress.IPv4Address(route.address))])
    shaper = TunShaper(f"{args.hop}:->{args.peer}", route, p, rng, tun_name(args.hop))
    stop = threading.Event()
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, lambda *_: stop.set())
    print(
        f"abyss: shaping packets to {route.address} ({args.hop}, profile {p.name}) through "
        f"{shaper.device}, then {route.device}; Ctrl-C to stop",
        flush=True,
    )
    t0 = time.monotonic()
    try:
        while not stop.wait(args.every):
            stats = shaper.snapshot()
            print(
                f"abyss: t={time.monotonic() - t0:5.0f} s  "
                + " ".join(
                    f"{k}={stats[k]:g}"
                    for k in (
                        "packets_sent",
                        "packets_forwarded",
                        "queue_drops",
                        "losses",
                        "packets_corrupted",
                        "tun_tx_dropped",
                    )
                ),
                flush=True,
            )
            if args.duration is not None and time.monotonic() - t0 >= args.duration:
                break
    finally:
        shaper.close()
    print(json.dumps({"hop": args.hop, "peer": route.address, "profile": p.name, **shaper.snapshot()}))
    return 0
