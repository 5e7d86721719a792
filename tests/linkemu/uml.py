"""A Linux kernel with sch_netem for the tests, where the host's has none: Debian's user-mode
Linux (`linux.uml`, package user-mode-linux) booted as a process with the host's file system as
its root (hostfs), so that abyss's own virtual environment runs inside it unchanged. Its init is
a shell script: /proc, /sys and /run mounted, netem's and veth's modules loaded from
/usr/lib/uml/modules (UML's own; no modprobe, whose module tree is the host kernel's), then the
test's commands, their output to a file on the host, then power off. One CPU, slow system
calls (an abyss command starts in about 4 s in it): measure what fits in it."""

from __future__ import annotations

import functools
import shutil
import subprocess
import tempfile
from pathlib import Path

UML = shutil.which("linux.uml")
MODULES = ("kernel/net/sched/sch_netem.ko", "kernel/drivers/net/veth.ko", "kernel/drivers/net/tun.ko")


# UML before Linux 6.3 saves a process's FPU state in a buffer of a fixed size; on a CPU with AMX
# the host's XSAVE area is larger, ptrace refuses the buffer (EFAULT) and UML's init dies at once
FP_REGS_REFUSED = "ptrace set fp regs failed"


@functools.cache
def why_not() -> str:
    """Why this machine cannot boot it ('' if it can)."""
    if UML is None:
        return "no linux.uml (Debian's user-mode-linux; setup.sh installs it as root)"
    if not list(Path("/usr/lib/uml/modules").glob(f"*/{MODULES[0]}")):
        return "user-mode-linux's modules have no sch_netem"
    if "amx_tile" in Path("/proc/cpuinfo").read_text().split():  # a boot tells, in about 3 s
        with tempfile.TemporaryDirectory() as probe:
            try:
                boot("true", Path(probe), timeout_s=120.0)
            except RuntimeError as exc:
                if FP_REGS_REFUSED in str(exc):
                    return (
                        "this UML kernel cannot run on this CPU: its XSAVE area (AMX) is larger than "
                        f"UML saves before Linux 6.3, and its init dies ('{FP_REGS_REFUSED}, errno = 14')"
                    )
                raise
    return ""


def boot(commands: str, directory: Path, timeout_s: float = 300.0, mem: str = "1G") -> str:
    """Boot UML, run `commands` (sh) as root inside it, power off; their output (stdout and
    stderr). The script and the output live in `directory`, on the host's file system."""
    directory.mkdir(parents=True, exist_ok=True)
    out, init = directory / "out.txt", directory / "init.sh"
    modules = "; ".join(f'insmod "$M/{m}"' for m in MODULES)
    init.write_text(
        "#!/bin/sh\n"
        "export PATH=/usr/sbin:/usr/bin:/sbin:/bin HOME=/root\n"
        "mount -t proc proc /proc; mount -t sysfs sys /sys; mount -t tmpfs run /run\n"
        "mkdir -p /dev/shm; mount -t tmpfs shm /dev/shm\n"  # devtmpfs has no shm/: Zenoh wants one
        f"M=/usr/lib/uml/modules/$(uname -r); {modules}\n"
        f"( {commands}\n) > {out} 2>&1\n"
        "sync\npoweroff -f\n"
    )
    init.chmod(0o755)
    console = directory / "console.txt"
    with console.open("w") as log:
        subprocess.run(
            [str(UML), f"mem={mem}", "root=/dev/root", "rootfstype=hostfs", "rootflags=/", "rw",
             f"init={init}", "con=null", "con0=null,fd:1"],
            stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, timeout=timeout_s, check=False,
        )  # fmt: skip
    if not out.exists():
        raise RuntimeError(f"UML ran nothing; its console:\n{console.read_text()[-3000:]}")
    return out.read_text()
