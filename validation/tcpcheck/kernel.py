"""The TCP comparison's kernel side: a phase through kernel TCP between two namespaces of a lab
of its own, each direction shaped at its sender by the TUN shaper or by tc/netem (the variant's
`shaper`), the `programs` at either end."""

from __future__ import annotations

import json
import secrets
import select
import signal
import subprocess
import sys
import threading
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from abyss.common.errors import LinkError
from abyss.interface import keys
from abyss.launch.lab import Lab, usable
from abyss.linkemu.netem import netem_available, netem_counters, run_tc, tc_command
from abyss.validation.tcpcheck import programs
from abyss.validation.tcpcheck.programs import START_TIMEOUT_S
from abyss.validation.tcpcheck.workload import COMMON_SYSCTLS, VARIANTS, Case, Phase, Run

ACK_SEED_OFFSET = 1_000_003  # the acknowledgement direction's shaper draws its own numbers


def kernel_unusable(variants: Iterable[str] = ("reno",)) -> str:
    """Why kernel runs of `variants` cannot be made here ('' when they can)."""
    if reason := usable():
        return reason
    shapers = {VARIANTS[v].shaper for v in variants}
    if "netem" in shapers and not netem_available():
        return "no sch_netem in this kernel (netem variants run inside UML: bench/shapers.py)"
    if "tun" in shapers and not Path("/dev/net/tun").exists():
        return "no /dev/net/tun (modprobe tun) for the TUN shaper"
    available = Path("/proc/sys/net/ipv4/tcp_available_congestion_control").read_text().split()
    wanted = {VARIANTS[v].congestion_control for v in variants}
    if missing := wanted - set(available):
        return f"congestion control {', '.join(sorted(missing))} not loaded (modprobe tcp_{min(missing)})"
    return ""


_starting = threading.Lock()


def run_kernel(case: Case, variant: str, phase: Phase, seed: int, timeout_s: float = 120.0) -> Run:
    """The phase through kernel TCP in a lab of its own, made and removed here."""
    lab = Lab(f"tcp{secrets.token_hex(4)}")
    sender, receiver = keys.HOPS[case.hop]
    started: list[subprocess.Popen[str]] = []
    window = [f"--window={phase.window_s}"] if phase.window_s is not None else []

    def start(command: list[str]) -> subprocess.Popen[str]:
        process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        started.append(process)
        _first_line(process, START_TIMEOUT_S)
        return process

    try:
        with _starting:  # one lab at a time: starting programs takes a CPU from the labs running
            lab.make(echo=None)
            sysctls = [f"net.ipv4.{k}={v}" for k, v in (*COMMON_SYSCTLS, *VARIANTS[variant].sysctls)]
            for station in (sender, receiver):
                _check([*lab.prefix(station), "sysctl", "-q", "-w", *sysctls])
            netem = VARIANTS[variant].shaper == "netem"
            if netem:
                for station in (sender, receiver):  # netem draws its own numbers: no seed
                    device = lab.device(station, case.hop)
                    run_tc(tc_command(device, case.link_profile(seed), lab.netns(station)))
            shapers = [] if netem else [start(c) for c in _shaper_commands(lab, case, seed, timeout_s)]
            listening = start(
                [*lab.prefix(receiver), *_program("receive", f"--timeout={timeout_s}", *window)]
            )
        report = _send(lab, case, variant, phase, timeout_s, window)
        received = json.loads(_finish(listening)[-1])
        shaped = (
            [_netem_shaped(lab, station, case.hop) for station in (sender, receiver)]
            if netem
            else [json.loads(_finish(shaper, signal.SIGTERM)[-1]) for shaper in shapers]
        )
    finally:
        for process in started:
            if process.poll() is None:
                process.kill()
                process.wait()
        lab.remove()
    return _kernel_run(phase, report, received, shaped)


def _netem_shaped(lab: Lab, station: str, hop: str) -> dict[str, float]:
    """netem's counts in the TUN shaper's names: netem's drops are its losses and its queue's."""
    counters = netem_counters(lab.device(station, hop), lab.netns(station))
    return {
        "losses": counters.get("netem_drops", 0.0),
        "queue_drops": 0.0,
        "packets_corrupted": 0.0,
        "tun_tx_dropped": 0.0,
    }


def _program(*args: str) -> list[str]:
    """The command line of one of `programs`, in this interpreter."""
    return [sys.executable, "-P", "-m", programs.__name__, *args]


def _shaper_commands(lab: Lab, case: Case, seed: int, timeout_s: float) -> list[list[str]]:
    """The TUN shapers of the case's hop: the data direction's at the sender, the
    acknowledgements' at the receiver, each with its own seed."""
    sender, receiver = keys.HOPS[case.hop]
    fields = [f"--{k}={v}" for k, v in case.overrides]
    return [
        lab.shape(
            station,
            case.hop,
            case.profile,
            *fields,
            f"--seed={shaper_seed}",
            "--every=3600",
            f"--duration={timeout_s}",
        )
        for station, shaper_seed in ((sender, seed), (receiver, seed + ACK_SEED_OFFSET))
    ]


def _send(
    lab: Lab, case: Case, variant: str, phase: Phase, timeout_s: float, window: list[str]
) -> dict[str, Any]:
    """The sender's run through the phase's schedule: its report (start time, counters)."""
    sender, receiver = keys.HOPS[case.hop]
    sent = subprocess.run(
        [
            *lab.prefix(sender),
            *_program(
                "send",
                f"--to={lab.address(receiver, case.hop)}",
                f"--timeout={timeout_s}",
                f"--congestion-control={VARIANTS[variant].congestion_control}",
                *window,
            ),
        ],
        input=json.dumps(phase.schedule),
        capture_output=True,
        text=True,
        timeout=timeout_s + START_TIMEOUT_S,
        check=False,
    )
    if sent.returncode != 0:
        raise LinkError(
            f"kernel {variant} {case.name} {phase.name}: the sender failed: {sent.stderr.strip()[-2000:]}"
        )
    report: dict[str, Any] = json.loads(sent.stdout)
    return report


def _kernel_run(
    phase: Phase,
    report: dict[str, Any],
    received: list[tuple[float, int, float]],
    shaped: list[dict[str, float]],
) -> Run:
    """The run as the sender's counters, the receiver's deliveries and the shapers' counts tell it,
    times from the sender's start."""
    t0_s, counters = report["t0_s"], report["counters"]
    extra = {
        **{f"kernel_{k}": float(v) for k, v in counters.items()},
        **{
            f"{way}_{k}": shaped[i][k]
            for i, way in enumerate(("data", "ack"))
            for k in ("losses", "queue_drops", "packets_corrupted", "tun_tx_dropped")
        },
    }
    return Run(
        phase,
        [(due - t0_s, size, at - t0_s) for due, size, at in received],
        counters["TcpExtTCPOrigDataSent"],
        counters["TcpRetransSegs"],
        counters["TcpExtTCPTimeouts"],
        extra,
    )


def _check(command: list[str]) -> None:
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise LinkError(f"`{' '.join(command)}` failed: {done.stderr.strip()}")


def _command_line(process: subprocess.Popen[str]) -> str:
    args = process.args
    return " ".join(map(str, args)) if isinstance(args, list | tuple) else str(args)


def _first_line(process: subprocess.Popen[str], timeout_s: float) -> str:
    """The first line a program prints (it says it is ready), within `timeout_s`."""
    assert process.stdout is not None
    ready, _, _ = select.select([process.stdout], [], [], timeout_s)
    line = process.stdout.readline() if ready else ""
    if not line:
        process.kill()
        _, err = process.communicate()
        raise LinkError(f"`{_command_line(process)}` did not start: {err.strip()[-2000:]}")
    return line


def _finish(process: subprocess.Popen[str], stop: signal.Signals | None = None) -> list[str]:
    """The rest of a program's output, line by line, once it has ended (after `stop`, if given)."""
    if stop is not None:
        process.send_signal(stop)
    out, err = process.communicate(timeout=10.0)
    if process.returncode != 0:
        raise LinkError(f"`{_command_line(process)}` failed: {err.strip()[-2000:]}")
    return out.splitlines() or [""]
