"""One profile, three shapers, one table: the emulated link (its TCP model, `linkemu/link.py`),
kernel TCP through the TUN shaper (this host) and kernel TCP through tc/netem (inside Debian's
user-mode Linux, `tests/linkemu/uml.py`: this host's kernel has no sch_netem), each with Reno as
it ships and CUBIC set on the socket, on the TCP comparison's cases (bench/tcp_model.py: bulk
goodput, retransmissions and timeouts per packet; 1, 10 and 100 kB messages' latency p50/p95).
Prints the table with model / kernel and netem / tun ratios, marked * where two differ by more
than 25 % plus twice their standard error; writes tcp_model.json and .png to --out.

netem's numbers are not seeded (the kernel draws them); UML runs on one CPU with slow system
calls, so at most four of its labs run at once. As root; about 25 minutes for the two default cases.
Run: .venv/bin/python bench/shapers.py [--case NAME]... [--kernel-seeds N] [--out DIR]"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "linkemu"))
import uml  # noqa: E402  (the tests' UML boot, shared)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--case", action="append", dest="cases", help="default: satellite, tether")
    parser.add_argument("--kernel-seeds", type=int, default=5)
    parser.add_argument("--out", type=Path, default=Path("bench/results/shapers"))
    args = parser.parse_args()
    if why := uml.why_not():
        print(f"bench/shapers.py: {why}", file=sys.stderr)
        return 2
    out = args.out.resolve()
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
