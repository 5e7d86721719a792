"""One profile, three shapers, one table: the emulated link (its TCP model, `linkemu/link.py`),
kernel TCP through the TUN shaper (this host) and kernel TCP through tc/netem (inside Debian's
user-mode Linux, `tests/linkemu/uml.py`: this host's kernel has no sch_netem), each with Reno as
it ships and CUBIC set on the socket, on the TCP comparison's cases (bench/tcp_model.py: bulk
goodput, retransmissions and timeouts per packet; 1, 10 and 100 kB messages' latency p50/p95).
Prints the table with model / kernel and netem / tun ratios, marked * where two differ by more
than 25 % plus twice their standard error; writes tcp_model.json and .png to --out. With
--packets PROFILE instead: pings (mean and deviation of the round trip, loss) and a UDP flow's
delivered rate through PROFILE by netem and by the TUN shaper, both inside UML, against the
profile's own figures (the emulated link carries messages, not packets).

netem's numbers are not seeded (the kernel draws them); UML runs on one CPU with slow system
calls, so at most four of its labs run at once. As root; about 25 minutes for the two default cases.
Run: .venv/bin/python bench/shapers.py [--case NAME]... [--kernel-seeds N] [--out DIR] [--packets PROFILE]"""

from __future__ import annotations

import argparse
import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "linkemu"))
import uml  # noqa: E402  (the tests' UML boot, shared)

from abyss.config.linkprofile import profile  # noqa: E402

PINGS, SPACING_S = 100, 0.5  # spaced wider than the jitter: netem with a rate keeps order
UDP_S, UDP_OFFERED_BPS, UDP_PAYLOAD_BYTES = 10.0, 2e6, 1372
FLOW = ROOT / "tests" / "e2e" / "udpflow.py"


def packets_script(hop: str, name: str) -> str:
    """Both ends of a veth pair shaped with `name`, by netem, then by the TUN shaper (seeded):
    pings, then a UDP flow offered at twice the rate, each shaper in turn."""
    abyss, py = f"{Path(sys.executable).parent}/abyss", sys.executable
    lines = [
        "ip link add va type veth peer name vb; ip netns add a; ip netns add b",
        "ip link set va netns a; ip link set vb netns b",
        "ip -n a addr add 10.79.0.1/24 dev va; ip -n b addr add 10.79.0.2/24 dev vb",
        "ip -n a link set va up; ip -n b link set vb up",
    ]
    for shaper in ("netem", "tun"):
        if shaper == "netem":
            lines += [f"{abyss} link netem {hop} --profile {name} --dev {d} --netns {n} --apply >/dev/null"
                      for d, n in (("va", "a"), ("vb", "b"))]  # fmt: skip
        else:
            lines += [
                f"ip netns exec {n} {abyss} link shape {hop} --profile {name} --peer {peer} --seed {seed} "
                f"--every 3600 > /tmp/shape-{n}.txt 2>&1 & {n.upper()}=$!"
                for n, peer, seed in (("a", "10.79.0.2", 1), ("b", "10.79.0.1", 2))
            ]
            lines.append("for i in $(seq 120); do grep -q shaping /tmp/shape-b.txt && break; sleep 0.5; done")
        lines += [
            f"echo '== {shaper} ping'; ip netns exec a ping -n -c {PINGS} -i {SPACING_S} 10.79.0.2",
            f"ip netns exec b {py} {FLOW} receive 10.79.0.2 5301 {UDP_S} > /tmp/udp.json & R=$!; sleep 1",
            f"ip netns exec a {py} {FLOW} send 10.79.0.2 5301 {UDP_OFFERED_BPS} {UDP_S + 2} "
            f"{UDP_PAYLOAD_BYTES}",
            f"wait $R; echo '== {shaper} udp'; cat /tmp/udp.json",
        ]
        lines.append(
            "ip netns exec a tc qdisc del dev va root; ip netns exec b tc qdisc del dev vb root"
            if shaper == "netem"
            else "kill $A $B; wait $A $B"
        )
    return "\n".join(lines)


def packet_figures(text: str, shaper: str) -> dict[str, float]:
    ping = text.split(f"== {shaper} ping\n", 1)[1].split("\n== ", 1)[0]
    rtts = np.array([float(t) for t in re.findall(r"time=([\d.]+) ms", ping)])
    sent = re.search(r"(\d+) packets transmitted, (\d+) received", ping)
    assert sent is not None, ping[-2000:]
    udp = json.loads(text.split(f"== {shaper} udp\n", 1)[1].splitlines()[0])
    span_s = udp["last_s"] - udp["first_s"]
    return {
        "rtt_mean_ms": float(rtts.mean()),
        "rtt_sd_ms": float(rtts.std(ddof=1)),
        "ping_loss": 1.0 - int(sent.group(2)) / int(sent.group(1)),
        "udp_kbps": udp["ip_bytes"] * 8e-3 / span_s if span_s > 0 else math.nan,
    }


def packets(hop: str, name: str, out: Path) -> None:
    """Ping and UDP through `name` by netem and by the TUN shaper, in one UML boot: a table."""
    p = profile(name)
    expected = {
        "rtt_mean_ms": 2e3 * p.delay_s,
        "rtt_sd_ms": math.sqrt(2) * 1e3 * p.jitter_s,
        "ping_loss": 1 - (1 - p.loss) ** 2,
        "udp_kbps": p.rate_bps * (1 - p.loss) * 1e-3,
    }
    text = uml.boot(packets_script(hop, name), out / f"uml-packets-{name}", timeout_s=900.0)
    netem, tun = packet_figures(text, "netem"), packet_figures(text, "tun")
    print(f"{'':14}{'profile':>10}{'netem':>10}{'tun':>10}{'netem/tun':>12}")
    for key, want in expected.items():
        ratio = netem[key] / tun[key] if tun[key] else math.nan
        mark = "*" if abs(ratio - 1) > 0.25 else " "
        print(f"{key:<14}{want:>10.4g}{netem[key]:>10.4g}{tun[key]:>10.4g}{ratio:>11.2f}{mark}")
    (out / f"packets-{name}.json").write_text(json.dumps({"profile": expected, "netem": netem, "tun": tun}))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--case", action="append", dest="cases", help="default: satellite, tether")
    parser.add_argument("--kernel-seeds", type=int, default=5)
    parser.add_argument("--out", type=Path, default=Path("bench/results/shapers"))
    parser.add_argument("--packets", metavar="PROFILE", help="only pings and a UDP flow through PROFILE")
    args = parser.parse_args()
    if why := uml.why_not():
        print(f"bench/shapers.py: {why}", file=sys.stderr)
        return 2
    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    if args.packets:
        print(f"== ping and UDP through {args.packets}, netem and tun, inside UML", flush=True)
        packets(next(h for h in ("satellite", "tether") if h in args.packets), args.packets, out)
        return 0
    cases = [f"--case={c}" for c in args.cases or ("satellite", "tether")]
    common = [
        sys.executable,
        str(ROOT / "bench" / "tcp_model.py"),
        *cases,
        f"--kernel-seeds={args.kernel_seeds}",
    ]
    print("== the TUN shaper, on this host", flush=True)
    subprocess.run([*common, "--variant=reno", "--variant=cubic", f"--out={out / 'tun'}"], check=True)
    print("== netem, inside UML (its progress in uml/out.txt)", flush=True)
    variants = "--variant=reno --variant=cubic --variant=reno-netem --variant=cubic-netem"
    text = uml.boot(
        f"cd {ROOT}; {' '.join(common)} {variants} --labs=4 --kernel-from={out / 'tun' / 'tcp_model.json'} "
        f"--out={out}",
        out / "uml",
        timeout_s=3600.0,
    )
    print(text[text.find("case ") :] if "case " in text else text[-4000:])
    return 0


if __name__ == "__main__":
    sys.exit(main())
