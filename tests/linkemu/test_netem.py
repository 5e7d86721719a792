"""The netem backend: rendered commands for every profile, applied where the kernel can."""

from __future__ import annotations

import os
import shutil
import subprocess
import uuid

import pytest

from abyss.common.errors import LinkError
from abyss.config.linkprofile import load_profiles, profile
from abyss.linkemu.netem import netem_counters, netem_limit, run_tc, tc_command

EXPECTED = {
    "ideal": "tc qdisc replace dev veth0 root netem limit 1000",
    "tether": "tc qdisc replace dev veth0 root netem delay 100ms 10ms distribution normal "
    "rate 20mbit limit 1234",
    "satellite": "tc qdisc replace dev veth0 root netem delay 150ms 75ms distribution normal "
    "loss random 5% corrupt 0.1% rate 1mbit limit 238",
    "satellite-geo": "tc qdisc replace dev veth0 root netem delay 280ms 20ms distribution normal "
    "loss random 1% corrupt 0.01% rate 512kbit limit 216",
    "satellite-storm": "tc qdisc replace dev veth0 root netem delay 300ms 150ms distribution normal "
    "loss gemodel 2.8% 25% 100% 0% corrupt 0.5% rate 256kbit limit 120",
    "tether-degraded": "tc qdisc replace dev veth0 root netem delay 200ms 50ms distribution normal "
    "loss random 1% rate 2mbit limit 567",
    "outage": "tc qdisc replace dev veth0 root netem loss random 100% limit 100",
}


@pytest.mark.parametrize("name", sorted(load_profiles()))
def test_rendered_command_for_every_profile(name: str) -> None:
    """Each shipped profile as netem renders it; those netem cannot express (a trace, outages) are
    refused naming what can."""
    p = profile(name)
    if p.trace or p.outage_down_s:
        with pytest.raises(LinkError, match="the emulated and tun links"):
            tc_command("veth0", p)
        return
    assert " ".join(tc_command("veth0", p)) == EXPECTED[name]


def test_limit_covers_packets_in_flight() -> None:
    p = profile("tether")  # 20 Mbit/s x (100 + 4 x 10) ms / 1500 B = 234 packets in flight
    assert netem_limit(p) == p.queue_limit_packets + 234


@pytest.fixture
def netns() -> object:
    if os.geteuid() != 0 or shutil.which("ip") is None:
        pytest.skip("needs root and iproute2 to make a network namespace")
    name = f"abyss-{uuid.uuid4().hex[:8]}"
    subprocess.run(["ip", "netns", "add", name], check=True)
    subprocess.run(
        ["ip", "-n", name, "link", "add", "veth0", "type", "veth", "peer", "name", "veth1"], check=True
    )
    yield name
    subprocess.run(["ip", "netns", "del", name], check=False)


def test_apply_change_and_clear_in_a_namespace(netns: str) -> None:
    try:
        run_tc(tc_command("veth0", profile("satellite"), netns))
    except LinkError as exc:
        if "sch_netem" in str(exc):
            pytest.skip(f"kernel without netem: {exc}")
        raise
    shown = subprocess.run(
        ["ip", "netns", "exec", netns, "tc", "qdisc", "show", "dev", "veth0"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert "netem" in shown and "loss 5%" in shown
    run_tc(tc_command("veth0", profile("tether"), netns))
    run_tc(tc_command("veth0", None, netns))


def test_missing_interface_is_a_clear_error(netns: str) -> None:
    with pytest.raises(LinkError, match=r"sch_netem|no such interface"):
        run_tc(tc_command("nope0", profile("satellite"), netns))


def test_no_netem_on_an_interface_counts_nothing() -> None:
    """Counters come from the root netem qdisc only (inside UML, test_netem_uml.py reads them off
    a running hop): loopback's noqueue and a missing interface give none, and no error."""
    if shutil.which("tc") is None:
        pytest.skip("needs iproute2's tc")
    assert netem_counters("lo") == {} and netem_counters("nope0") == {}
