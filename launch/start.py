"""`abyss up`'s start: the options it refuses, the endpoint it listens on, the run's config as the
stations get it, and one station started as an OS process."""

from __future__ import annotations

import contextlib
import dataclasses
import os
import shutil
import subprocess
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from abyss.common.errors import ConfigError
from abyss.common.ports import free_port, port_free
from abyss.common.runfiles import CARRIED_OVER
from abyss.config import Config
from abyss.config.stations import OnshoreConfig
from abyss.config.system import Ros2Config, TimeConfig
from abyss.interface import keys
from abyss.launch.cpu import CpuCaps
from abyss.launch.station import BOOT_ENV, NATIVE_POOLS, SUPERVISOR_ENV
from abyss.recording.store import RECORD_DIR

DEFAULT_PORT = 7447
CONFIG_FILE = "config.json"  # what the stations (and a replay of the run) are given
SIMULATION_STATE_FILE = "simulation-state.npy"  # a restarted simulation resumes from it
# lockstep: one thread in every native pool whatever the user's environment says (a station's own
# default otherwise, single_threaded_native_pools), the order of floating-point sums fixed
SINGLE_THREADED = dict.fromkeys(NATIVE_POOLS, "1")


@dataclass
class Station:
    name: str
    process: subprocess.Popen[bytes]
    log_path: Path
    status_path: Path
    restarts: int = 0
    died: int | None = None  # exit code if it ended before it was asked to stop


class Placement(Protocol):
    """Where the stations run and how they reach each other and the supervisor."""

    def prefix(self, station: str) -> list[str]: ...
    def args(self, station: str, endpoint: str) -> list[str]: ...


class Local:
    """Every station a process of this host on loopback, a peer under the supervisor's router."""

    def prefix(self, station: str) -> list[str]:
        return []

    def args(self, station: str, endpoint: str) -> list[str]:
        return ["--listen", "tcp/127.0.0.1:0", "--connect", endpoint, "--zenoh-mode", "peer"]


@dataclass(frozen=True)
class Replayed:
    """Stations played back from a recorded run instead of run (`abyss replay`)."""

    run_dir: Path
    stations: tuple[str, ...]
    speed: float = 1.0

    def args(self, station: str) -> list[str]:
        return ["--replay", str(self.run_dir), "--speed", str(self.speed)] if station in self.stations else []


def checked_external(
    config: Config, external: Sequence[str], restart: bool, replayed: Replayed | None
) -> tuple[str, ...]:
    """The stations the user starts, once the options that cannot go together are refused."""
    external = tuple(keys.check_station(name) for name in external)
    if config.ros2.station in external:
        raise ConfigError(
            "--ros2",
            f"{config.ros2.station} is --external too: the gateway stands for a station that abyss up starts",
        )
    uncappable = sorted(set(config.cpu.capped()) & set(external))
    if uncappable:
        raise ConfigError(
            "--cpu", f"{uncappable[0]} is --external: abyss up does not start it, so cannot cap its CPU"
        )
    if config.time.simulated:
        _check_simulated(config, external, restart, replayed)
    return external


def _check_simulated(
    config: Config, external: tuple[str, ...], restart: bool, replayed: Replayed | None
) -> None:
    """What simulated time cannot run with."""
    for refused, what in (("--external", external), ("--replay", replayed)):
        if what:
            raise ConfigError(
                refused,
                "a real component or a replay runs on the wall clock, which "
                "--time sim cannot speed up; use --time real with it",
            )
    if config.time.mode == "lockstep" and restart and not (config.time.holds_s or config.time.phase_holds):
        raise ConfigError(
            "--restart",
            "a station restarted mid-period leaves lockstep's counted periods behind: in lockstep "
            "a station is restarted only at a hold (time.holds_s, as `abyss scenario run` sets for "
            "a scenario's kills); use --time sim or real with it",
        )
    if config.cpu.capped():
        raise ConfigError(
            "--cpu",
            "a CPU cap is a share of wall time, and with --time sim the "
            "simulation waits for a station that needs more: use --time real with it",
        )


def endpoint_of(config: Config, port: int | None) -> str:
    """The supervisor's router: `DEFAULT_PORT` unless taken (or the ROS 2 gateway's), any free
    port for 0."""
    if port is None:
        ros2_ports = {e.rpartition(":")[2] for e in config.ros2.listen} if config.ros2.station else set()
        taken = str(DEFAULT_PORT) in ros2_ports  # the gateway's router: rmw_zenohd's port, by default
        port = DEFAULT_PORT if not taken and port_free(DEFAULT_PORT) else free_port()
    elif port == 0:
        port = free_port()
    return f"tcp/127.0.0.1:{port}"


def port_holder(port: int) -> str:
    """Who listens on TCP `port` on this machine: 'pid N (its command line)', or '' when it cannot
    be found (another user's process, or another namespace)."""
    inodes = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with contextlib.suppress(OSError), open(table) as lines:
            for line in list(lines)[1:]:
                fields = line.split()
                if int(fields[1].rsplit(":", 1)[1], 16) == port and fields[3] == "0A":  # LISTEN
                    inodes.add(f"socket:[{fields[9]}]")
    for fd_dir in Path("/proc").glob("[0-9]*/fd"):
        with contextlib.suppress(OSError):
            if any(os.readlink(fd) in inodes for fd in fd_dir.iterdir()):
                command = (fd_dir.parent / "cmdline").read_bytes().replace(b"\0", b" ").decode().strip()
                return f"pid {fd_dir.parent.name} ({command})"
    return ""


def viewer_port(port: int, what: str, say: Callable[[str], None]) -> int:
    """`port` when it is free; else a free one, and who holds `port` said (an old run's viewer
    server, say, which the user may want to stop)."""
    if port_free(port):
        return port
    other = free_port()
    say(f"abyss: the {what} port {port} is held by {port_holder(port) or 'another process'}; using {other}")
    return other


def run_config(
    config: Config, out_dir: Path, duration_s: float | None, say: Callable[[str], None] = lambda _: None
) -> Config:
    """The config as the stations get it: the recordings, the simulation's state and the viewer's
    free ports (a held one said) in the run directory; lockstep's end on the run's duration."""
    onshore = config.onshore
    web_port, grpc_port = onshore.viewer_web_port, onshore.viewer_grpc_port
    if onshore.viewer in ("web", "spawn"):
        web_port = viewer_port(onshore.viewer_web_port, "web viewer's", say)
        grpc_port = viewer_port(onshore.viewer_grpc_port, "viewer's gRPC", say)
    return dataclasses.replace(
        config,
        onshore=dataclasses.replace(
            onshore, record_dir=str(out_dir), viewer_web_port=web_port, viewer_grpc_port=grpc_port
        ),
        simulation=dataclasses.replace(config.simulation, state_file=str(out_dir / SIMULATION_STATE_FILE)),
        # lockstep ends on the same period however late the stop comes
        time=dataclasses.replace(config.time, end_s=duration_s or 0.0)
        if config.time.mode == "lockstep"
        else config.time,
        record=dataclasses.replace(config.record, directory=str(out_dir / RECORD_DIR)),
    )


def prepare_run_dir(out_dir: Path, config: Config) -> None:
    """Clear an earlier run's recordings and carried-over files (restarts read them) and write
    the config the stations are given."""
    out_dir.mkdir(parents=True, exist_ok=True)
    shutil.rmtree(out_dir / RECORD_DIR, ignore_errors=True)
    for name in (SIMULATION_STATE_FILE, *CARRIED_OVER):
        (out_dir / name).unlink(missing_ok=True)
    (out_dir / CONFIG_FILE).write_text(config.to_json())


@dataclass
class Starter:
    """Starts one station as a process of its own: its log and status file in the run
    directory, its CPU capped, its pid in the run's state."""

    out_dir: Path
    endpoint: str
    time: TimeConfig
    cpu: CpuCaps
    change_state: Callable[..., None]
    placement: Placement = dataclasses.field(default_factory=Local)
    replayed: Replayed | None = None

    def command(self, name: str) -> list[str]:
        # -P: the stations' own directory (the run directory) never shadows abyss's modules
        return [
            *self.placement.prefix(name),
            sys.executable,
            "-P",
            "-m",
            "abyss.cli",
            "station",
            name,
            "--config",
            str(self.out_dir / CONFIG_FILE),
            "--status-file",
            str(self.out_dir / f"{name}.json"),
            *self.placement.args(name, self.endpoint),
            *(self.replayed.args(name) if self.replayed else []),
        ]

    def start(self, name: str, boot: int = 0) -> Station:
        log_path = self.out_dir / f"{name}.log"
        env: dict[str, Any] = {
            **os.environ,
            SUPERVISOR_ENV: str(os.getpid()),
            BOOT_ENV: str(boot),
            **(SINGLE_THREADED if self.time.mode == "lockstep" else {}),
        }
        with log_path.open("wb") as log:
            process = subprocess.Popen(
                self.command(name),
                stdout=log,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                start_new_session=True,
                cwd=self.out_dir,
                env=env,
            )
        self.cpu.apply(name, process.pid)
        self.change_state(name, pid=process.pid)
        return Station(name, process, log_path, self.out_dir / f"{name}.json")


def viewer_line(cfg: OnshoreConfig) -> str:
    from abyss.stations.onshore.viewer import RECORDING_FILE, web_viewer_url

    recording = Path(cfg.record_dir) / RECORDING_FILE
    return {
        "save": f"abyss: recording to {recording} (abyss view {cfg.record_dir})",
        "web": f"abyss: web viewer at {web_viewer_url(cfg.viewer_web_port, cfg.viewer_grpc_port)} "
        f"(recording to {recording})",
        "spawn": f"abyss: rerun viewer spawned (recording to {recording})",
        "none": "abyss: no rerun viewer, no rerun recording (the bus recording, --record, is apart)",
    }[cfg.viewer]


def ros2_line(ros2: Ros2Config) -> str:
    """How a ROS 2 node joins the gateway that stands for a station (docs/ros2.md)."""
    endpoint = (ros2.connect or ros2.listen)[0]
    where = "its router" if not ros2.connect else "the router it joined"
    return (
        f"abyss: {ros2.station} is a ROS 2 gateway (domain {ros2.domain}, topics under "
        f"{ros2.namespace}); start your node with RMW_IMPLEMENTATION=rmw_zenoh_cpp "
        f"ROS_DOMAIN_ID={ros2.domain} "
        f"ZENOH_CONFIG_OVERRIDE='connect/endpoints=[\"{endpoint}\"]' ({where})"
        + ("" if ros2.station == "simulation" else " and use_sim_time:=true")  # a vehicle keeps its own time
    )
