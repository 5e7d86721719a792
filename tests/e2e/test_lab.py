"""`abyss lab`: the hops of the four namespaces shaped by the TUN shaper (or netem), measured with
real tools (ping, a UDP flow) against the profiles' own statistics; the whole mission through
`abyss lab up`; a lab left by a killed run, one in use, and a host that cannot make one."""

from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from conftest import ARM_MISSION, ROOT, abyss
from hosts import Hosts, usable

from abyss.config.linkprofile import LinkProfile, profile
from abyss.interface import keys
from abyss.launch.lab import Lab

Z_99 = 2.576  # two-sided 99 % quantile of the normal distribution
PING_BYTES = 84  # IPv4 + ICMP headers + ping's 56 bytes
ABYSS = [sys.executable, "-P", "-m", "abyss.cli"]
PINGS = (("tether", "onboard", "vessel", 100, 0.1), ("satellite", "onshore", "vessel", 120, 0.25))


class Shapers:
    """`abyss link shape` on both ends of hops, as a user shapes hosts that run no station."""

    def __init__(self, hosts: Hosts, profiles: dict[str, str], log_dir: Path) -> None:
        self.processes: list[tuple[subprocess.Popen[str], Path]] = []
        for hop, name in profiles.items():
            for station in keys.HOPS[hop]:
                log = log_dir / f"shape-{hop}-{station}.log"
                with log.open("w") as out:
                    process = subprocess.Popen(
                        hosts.shape(station, hop, name, "--every", "60"),
                        stdout=out,
                        stderr=subprocess.STDOUT,
                        text=True,
                    )
                self.processes.append((process, log))
        deadline = time.monotonic() + 30.0
        for process, log in self.processes:  # each says so once its route goes through it
            while "abyss: shaping packets" not in log.read_text():
                assert process.poll() is None and time.monotonic() < deadline, log.read_text()
                time.sleep(0.05)

    def stop(self) -> list[dict[str, float]]:
        """Their final statistics."""
        for process, _ in self.processes:
            process.send_signal(signal.SIGTERM)
        stats = []
        for process, log in self.processes:
            assert process.wait(timeout=10) == 0, log.read_text()
            stats.append(json.loads(log.read_text().strip().splitlines()[-1]))
        return stats


def ping(
    hosts: Hosts, station: str, address: str, count: int, interval_s: float
) -> tuple[float, float, float]:
    """RTT mean and standard deviation [ms] and the share of pings lost."""
    done = subprocess.run(
        [*hosts.prefix(station), "ping", "-q", "-n", "-c", str(count), "-i", str(interval_s), address],
        capture_output=True,
        text=True,
        timeout=count * interval_s + 30,
    )
    loss = re.search(r"([\d.]+)% packet loss", done.stdout)
    rtt = re.search(r"= [\d.]+/([\d.]+)/[\d.]+/([\d.]+) ms", done.stdout)
    assert loss and rtt, done.stdout + done.stderr
    return float(rtt[1]), float(rtt[2]), float(loss[1]) / 100.0


def one_way_s(p: LinkProfile, size_bytes: int) -> float:
    return p.delay_s + (0.0 if math.isinf(p.rate_bps) else size_bytes * 8.0 / p.rate_bps)


def test_ping_and_a_udp_flow_through_the_shaped_hops(hosts: Hosts, tmp_path: Path) -> None:
    """Ping's RTT mean and deviation within the profile's 99 % bounds, its loss within the
    binomial's; a UDP flow above the tether's rate arrives at that rate within 2 %. The floor
    (both shapers on an ideal profile) is measured in the same run and added."""
    shapers = Shapers(hosts, {"rov": "ideal", "tether": "tether", "satellite": "satellite"}, tmp_path)
    try:
        floor_ms, _, _ = ping(hosts, "simulation", hosts.address("onboard", "rov"), 50, 0.02)
        with ThreadPoolExecutor(2) as pool:
            runs = {
                hop: (
                    pool.submit(ping, hosts, station, hosts.address(neighbour, hop), count, interval_s),
                    count,
                )
                for hop, station, neighbour, count, interval_s in PINGS
            }
            runs["tether"][0].result()  # the tether's pings done: the flow takes the tether, while the
            # satellite's pings (other shapers, 4 a second) go on
            flow = udp_flow(hosts, "onboard", "vessel", "tether", rate_bps=30e6, seconds=4.0)
            pings = {hop: (run.result(), count) for hop, (run, count) in runs.items()}
    finally:
        stats = shapers.stop()
    assert floor_ms < 20.0, floor_ms
    for hop, ((mean_ms, std_ms, lost), count) in pings.items():
        p = profile(hop)
        keep = (1.0 - p.loss) * (1.0 - p.corrupt)  # a corrupt ping fails ICMP's checksum
        expected_loss = 1.0 - keep**2
        received = round(count * (1.0 - lost))
        expected_ms = 2e3 * one_way_s(p, PING_BYTES) + floor_ms
        sigma_ms = math.sqrt(2.0) * p.jitter_s * 1e3
        print(
            f"{hop}: RTT {mean_ms:.1f} +/- {std_ms:.1f} ms (profile {expected_ms:.1f} +/- {sigma_ms:.1f}), "
            f"lost {lost:.1%} (profile {expected_loss:.1%}) of {count}"
        )
        assert abs(mean_ms - expected_ms) < Z_99 * sigma_ms / math.sqrt(received), (hop, mean_ms, expected_ms)
        assert abs(std_ms / sigma_ms - 1.0) < Z_99 / math.sqrt(2.0 * (received - 1)), (hop, std_ms, sigma_ms)
        loss_bound = Z_99 * math.sqrt(expected_loss * keep**2 / count) + 1e-9
        assert abs(lost - expected_loss) < loss_bound, (hop, lost, expected_loss)
    rate_bps = profile("tether").rate_bps
    print(f"UDP flow over the tether: {flow / 1e6:.3f} Mbit/s (profile {rate_bps / 1e6:g})")
    assert abs(flow / rate_bps - 1.0) < 0.02, flow
    to_vessel = ("tether", hosts.address("vessel", "tether"))
    tether_out = next(s for s in stats if (s["hop"], s["peer"]) == to_vessel)
    assert tether_out["queue_drops"] > 0 and tether_out["send_errors"] == 0, tether_out  # offered 1.5x


def udp_flow(hosts: Hosts, sender: str, receiver: str, hop: str, rate_bps: float, seconds: float) -> float:
    """The rate [bit/s of IP packets] at which a flow offered at `rate_bps` arrives."""
    address = hosts.address(receiver, hop)
    with ThreadPoolExecutor(1) as pool:
        received = pool.submit(
            hosts.run,
            receiver,
            ["tests/e2e/udpflow.py", "receive", address, "5001", str(seconds)],
            seconds + 60,
        )
        time.sleep(0.5)  # the receiver binds (its first datagram starts its clock, whenever it comes)
        sent = hosts.run(
            sender,
            ["tests/e2e/udpflow.py", "send", address, "5001", str(rate_bps), str(seconds + 2.0), "1400"],
            seconds + 30,
        )
        assert sent.returncode == 0, sent.stderr
        done = received.result()
    assert done.returncode == 0, done.stderr
    got = json.loads(done.stdout)
    return float((got["ip_bytes"] - 1428) * 8.0 / (got["last_s"] - got["first_s"]))


def test_abyss_lab_up_flies_the_mission_and_takes_a_link_change(tmp_path: Path) -> None:
    """`abyss lab up` as a user runs it: the mission through the shaped namespaces; `abyss lab exec`
    reaches a station's host, and a link change made there reaches both ends of the hop."""
    if reason := usable():
        pytest.skip(reason)
    name = f"t{os.getpid() % 100000}"
    out = tmp_path / "run"
    lab = subprocess.Popen(
        [
            *ABYSS,
            "lab",
            "up",
            "--name",
            name,
            "--out",
            str(out),
            "--keep-running",
            "--duration",
            "150",
            *ARM_MISSION,
        ],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        lines = read_until(lab, "mission complete", 150.0)
        changed = abyss(
            "lab",
            "exec",
            "onshore",
            "--name",
            name,
            "--",
            *ABYSS,
            "link",
            "set",
            "satellite",
            "--loss",
            "10%",
        )
        assert changed.returncode == 0, changed.stderr
        shown = abyss(
            "lab", "exec", "vessel", "--name", name, "--", *ABYSS, "link", "show", "satellite", "--json"
        )
        assert shown.returncode == 0, shown.stderr
        lab.send_signal(signal.SIGINT)
        lines += lab.communicate(timeout=60)[0].splitlines()
    finally:
        if lab.poll() is None:
            lab.kill()
            lab.wait()
    output = "\n".join(lines)
    assert lab.returncode == 0, output
    ends = json.loads(shown.stdout)
    assert {e["direction"] for e in ends} == {"vessel->onshore", "onshore->vessel"}, ends
    assert all(e["fields"]["loss"] == "10%" for e in ends), ends
    summary = json.loads((out / "summary.json").read_text())
    assert summary["verdict"] == "done", output
    modes = {d["mode"] for hop in summary["links"].values() for d in hop.values()}
    assert modes <= {"tun", "netem"} and modes, summary["links"]
    assert not Lab(name).existing(), "the lab outlived its run"


def read_until(process: subprocess.Popen[str], text: str, timeout_s: float) -> list[str]:
    """The process's lines up to the one that holds `text`."""
    assert process.stdout is not None
    lines: list[str] = []
    deadline = time.monotonic() + timeout_s
    for line in process.stdout:  # the run prints a progress line every 5 s
        lines.append(line.rstrip("\n"))
        if text in line:
            return lines
        assert time.monotonic() < deadline and process.poll() is None, "\n".join(lines)
    raise AssertionError("\n".join(lines))


def test_a_killed_runs_lab_is_removed_and_one_in_use_is_not_taken(tmp_path: Path) -> None:
    if reason := usable():
        pytest.skip(reason)
    owner = subprocess.Popen(["sleep", "60"])
    lab = Lab(f"t{os.getpid() % 100000}k")
    try:
        lab.make()
        lab.record.write_text(json.dumps({"pid": owner.pid}))  # as if `sleep` ran it
        taken = abyss("lab", "up", "--name", lab.name, "--duration", "1", cwd=tmp_path)
        assert taken.returncode == 2 and f"in use by process {owner.pid}" in taken.stderr, taken.stderr
        assert f"abyss lab down --name {lab.name}" in taken.stderr
        assert len(lab.existing()) == 4  # left as it was
        down = abyss("lab", "down", "--name", lab.name)
        assert down.returncode == 0 and "was stopped" in down.stdout, down.stdout + down.stderr
        assert owner.wait(timeout=10) == -signal.SIGTERM and not lab.existing()
        lab.make()
        lab.record.write_text(json.dumps({"pid": owner.pid}))  # its owner is dead now: a killed run
        remade: list[str] = []
        lab.make(echo=remade.append)
        assert remade == [f"abyss: removed lab {lab.name!r} left by a run that was killed"]
        assert len(lab.existing()) == 4
        lab.remove()
        # a namespace of the lab's name that no lab made: refused, and left alone
        subprocess.run(["ip", "netns", "add", lab.netns("vessel")], check=True)
        foreign = abyss("lab", "up", "--name", lab.name, "--duration", "1", cwd=tmp_path)
        assert foreign.returncode == 2 and "is no abyss lab's" in foreign.stderr, foreign.stderr
        assert f"ip netns del {lab.netns('vessel')}" in foreign.stderr
        refused = abyss("lab", "down", "--name", lab.name)
        assert refused.returncode == 2 and "is no abyss lab's" in refused.stderr, refused.stderr
        assert lab.existing() == [lab.netns("vessel")]
    finally:
        owner.kill()
        lab.remove()


def test_without_root_or_a_tun_device_the_error_names_the_fix(tmp_path: Path) -> None:
    """Not root: the lab and the shaper refuse with the fix; no TUN device: the same; nothing is
    left behind."""
    if os.geteuid() != 0:
        pytest.skip("needs root to drop to another user and to hide /dev/net/tun")
    nobody = "setpriv --reuid=nobody --regid=nogroup --clear-groups --inh-caps=-all"
    as_nobody = [*nobody.split(), *ABYSS]
    env = {**os.environ, "HOME": str(tmp_path)}
    lab = subprocess.run(
        [*as_nobody, "lab", "up", "--name", "nobody"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env=env,
        timeout=60,
    )
    assert lab.returncode == 2 and "run it as root" in lab.stderr, lab.stderr
    shape = subprocess.run(
        [*as_nobody, "link", "shape", "tether", "--peer", "127.0.0.2"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env=env,
        timeout=60,
    )
    assert shape.returncode == 2 and "on this host" in shape.stderr, shape.stderr  # loopback: refused first
    # a host of its own with a neighbour on a veth: the shaper gets as far as the TUN device
    host = "ip link add d0 type veth peer name d1 && ip addr add 10.9.0.1/24 dev d0 && ip link set d0 up"
    shape_cmd = f"{' '.join(ABYSS)} link shape tether --peer 10.9.0.2"
    hidden = subprocess.run(
        [
            "unshare",
            "--mount",
            "--net",
            "sh",
            "-c",
            f"mount -t tmpfs none /dev/net && {host} && exec {shape_cmd}",
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
    )
    assert hidden.returncode == 2, hidden.stderr
    assert "no /dev/net/tun" in hidden.stderr and "modprobe tun" in hidden.stderr, hidden.stderr
    no_cap = subprocess.run(
        ["unshare", "--net", "sh", "-c", f"{host} && exec {nobody} {shape_cmd}"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env=env,
        timeout=60,
    )
    assert no_cap.returncode == 2 and "CAP_NET_ADMIN" in no_cap.stderr, no_cap.stderr
