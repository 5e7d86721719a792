"""The netem backend: a profile rendered as `tc qdisc ... netem ...` for an interface,
applied, changed and removed.

netem differs from the in-process emulator in ways it cannot be told out of:
- netem's `limit` counts every packet it holds, delayed ones included, so the rendered
  limit is the profile's queue plus the packets in flight over the delay (rate x delay);
- with jitter, netem reorders packets whose spacing is below the jitter unless `rate` is
  set; when it is (always, below, unless the rate is unlimited), netem keeps order but
  adds each packet's jitter to its queueing time rather than after serialisation;
- netem has no transport model: TCP retransmission and congestion control are the
  kernel's own, which is the real thing;
- `correlation` in netem mixes the previous value in and shrinks the variance; the
  in-process emulator keeps the variance.
"""

from __future__ import annotations

import json
import logging
import math
import os
import shutil
import subprocess
from pathlib import Path

from abyss.common.errors import LinkError
from abyss.common.units import format_fraction, format_rate, format_time
from abyss.config.linkprofile import LinkProfile

log = logging.getLogger(__name__)


def netem_args(profile: LinkProfile) -> list[str]:
    """The netem options for `profile` (after `netem`); LinkError for what netem cannot express."""
    if profile.outage_down_s > 0.0:
        raise LinkError(
            f"profile {profile.name}: netem has no on-off outages (outage_up, outage_down); "
            "the emulated and tun links replay them (--link emulated or tun), or switch the hop "
            "to the outage profile at run time (abyss link set HOP outage)"
        )
    if profile.trace:
        raise LinkError(
            f"profile {profile.name}: netem cannot replay a delivery trace ({profile.trace}); "
            "the emulated and tun links do (--link emulated or tun)"
        )
    args: list[str] = []
    if profile.delay_s or profile.jitter_s:
        args += ["delay", format_time(profile.delay_s)]
        if profile.jitter_s:
            args += [format_time(profile.jitter_s)]
            if profile.correlation:
                args += [format_fraction(profile.correlation)]
            args += ["distribution", profile.distribution]
    if profile.loss_model == "gilbert-elliott":
        args += [
            "loss",
            "gemodel",
            format_fraction(profile.ge_p),
            format_fraction(profile.ge_r),
            format_fraction(profile.ge_loss_bad),
            format_fraction(profile.ge_loss_good),
        ]
    elif profile.loss:
        args += ["loss", "random", format_fraction(profile.loss)]
    if profile.corrupt:
        args += ["corrupt", format_fraction(profile.corrupt)]
    if profile.duplicate:
        args += ["duplicate", format_fraction(profile.duplicate)]
    if profile.reorder:
        args += ["reorder", format_fraction(profile.reorder)]
    if not math.isinf(profile.rate_bps):
        args += ["rate", format_rate(profile.rate_bps)]
    args += ["limit", str(netem_limit(profile))]
    return args


def netem_limit(profile: LinkProfile) -> int:
    """netem's limit counts delayed packets too: the queue plus what is in flight."""
    if math.isinf(profile.rate_bps):
        return profile.queue_limit_packets
    worst_delay_s = profile.delay_s + 4.0 * profile.jitter_s
    in_flight = math.ceil(profile.rate_bps * worst_delay_s / (8.0 * profile.mtu_bytes))
    return profile.queue_limit_packets + in_flight


def in_netns(netns: str | None) -> list[str]:
    """What runs a command in `netns` (nothing: this namespace)."""
    return ["ip", "netns", "exec", netns] if netns else []


def tc_command(dev: str, profile: LinkProfile | None, netns: str | None = None) -> list[str]:
    """`tc qdisc replace dev DEV root netem ...`, or `tc qdisc del dev DEV root` for None."""
    prefix = in_netns(netns)
    if profile is None:
        return [*prefix, "tc", "qdisc", "del", "dev", dev, "root"]
    return [*prefix, "tc", "qdisc", "replace", "dev", dev, "root", "netem", *netem_args(profile)]


def run_tc(command: list[str]) -> None:
    """Run a tc command; translate the kernel's refusals into errors that say the fix."""
    if shutil.which("tc") is None:
        raise LinkError("tc not found: install iproute2 (apt-get install iproute2)")
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode == 0:
        return
    message = (done.stderr or done.stdout).strip()
    if "qdisc kind is unknown" in message:
        raise LinkError(
            f"the kernel has no sch_netem module ({message}); load it with "
            "`modprobe sch_netem` (Debian/Ubuntu: linux-modules-extra-$(uname -r))"
        )
    if "Operation not permitted" in message:
        raise LinkError(
            f"changing a qdisc needs CAP_NET_ADMIN ({message}); run as root or give "
            "the container cap_add: [NET_ADMIN]"
        )
    if "Cannot find device" in message:
        raise LinkError(f"no such interface: {message}")
    raise LinkError(f"{' '.join(command)} failed: {message}")


# netem's counters as `tc -s -j qdisc show` names them, and as the link statistics do. netem
# counts its random losses among its drops, with what overflowed its limit.
NETEM_COUNTERS = {
    "packets": "packets_sent",
    "bytes": "bytes_sent",
    "drops": "netem_drops",
    "overlimits": "netem_overlimits",
    "requeues": "netem_requeues",
    "backlog": "netem_backlog_bytes",
    "qlen": "netem_backlog_packets",
}


def netem_available() -> bool:
    """Whether this kernel has sch_netem (loaded, or a module to load)."""
    if Path("/sys/module/sch_netem").exists():
        return True
    modules = Path("/lib/modules") / os.uname().release
    return any(modules.glob("kernel/net/sched/sch_netem.ko*"))


def netem_counters(dev: str, netns: str | None = None) -> dict[str, float]:
    """The root netem qdisc's counters on `dev` (in `netns`, else this namespace), as
    NETEM_COUNTERS names them; empty when there is none or tc cannot say (logged)."""
    done = subprocess.run(
        [*in_netns(netns), "tc", "-s", "-j", "qdisc", "show", "dev", dev],
        capture_output=True,
        text=True,
        check=False,
    )
    try:
        qdiscs = json.loads(done.stdout) if done.returncode == 0 else []
    except json.JSONDecodeError as exc:
        log.warning("tc's counters on %s unreadable: %s", dev, exc)
        return {}
    for qdisc in qdiscs:
        if qdisc.get("kind") == "netem" and qdisc.get("root"):
            return {ours: float(qdisc.get(theirs, 0)) for theirs, ours in NETEM_COUNTERS.items()}
    log.info("no netem on %s to count (%s)", dev, done.stderr.strip() or "another qdisc")
    return {}


class NetemShaper:
    """A hop's profile as tc/netem on the interface towards the neighbour; removed at close."""

    def __init__(self, name: str, device: str, profile: LinkProfile) -> None:
        self.name = name
        self.device = device
        self.counters: dict[str, float] = {}
        self.closed = False
        self.reconfigure(profile)

    def reconfigure(self, profile: LinkProfile) -> None:
        run_tc(tc_command(self.device, profile))
        log.info("netem on %s (%s): %s", self.device, self.name, " ".join(netem_args(profile)))

    def snapshot(self) -> dict[str, float]:
        """netem's own counters on the device (`tc -s qdisc show`): the last read once closed;
        none if tc cannot say."""
        if not self.closed:
            self.counters = netem_counters(self.device) or self.counters
        return dict(self.counters)

    def close(self) -> None:
        self.snapshot()  # the final counts, before the qdisc and its counters go
        self.closed = True
        try:
            run_tc(tc_command(self.device, None))
        except LinkError as exc:
            log.warning("could not remove netem from %s (%s): %s", self.device, self.name, exc)
