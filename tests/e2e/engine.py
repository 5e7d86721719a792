"""A Docker engine on this machine, the images and compose, as the deployment's test
(test_compose_up.py) and bench/deploy.py drive them.

- the engine: dockerd started in the background when none answers (its log in DOCKERD_LOG), and
  left running for the next run, as a service would be;
- the base image: abyss-base:bookworm made from Debian's packages by deploy/base-image.sh, as no
  container registry may be reachable;
- the project's image: built only when its inputs changed, labelled with their digest (the base
  image's id, the Dockerfile and every file it copies); the CA bundle that lets pip through a TLS
  proxy is a BuildKit secret, mounted for the pip step alone and in no layer;
- compose: `docker compose` where the plugin is installed, else docker-compose (v1)."""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import signal
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import zenoh

from abyss.bus.session import client_config, message_of, open_session
from abyss.interface import keys
from abyss.interface.messages import MissionStatus

ROOT = Path(__file__).resolve().parents[2]
BASE_IMAGE = "abyss-base:bookworm"
IMAGE = "abyss:latest"
INPUTS_LABEL = "org.abyss.inputs"
CA_BUNDLE = Path("/etc/ssl/certs/ca-certificates.crt")  # this machine's, with its proxy's CA
DOCKERD_LOG = Path(tempfile.gettempdir()) / "abyss-dockerd.log"


def say(text: str) -> None:
    print(f"[compose] {text}", flush=True)


def docker_cli() -> str | None:
    """The engine package's own client (docker.io's builds with BuildKit without the buildx
    plugin, which Debian does not package), else the first on PATH."""
    return "/usr/bin/docker" if os.access("/usr/bin/docker", os.X_OK) else shutil.which("docker")


def docker(*args: str, timeout_s: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [docker_cli() or "docker", *args], capture_output=True, text=True, timeout=timeout_s, check=False
    )


def compose_command() -> list[str] | None:
    cli = docker_cli()
    if cli and subprocess.run([cli, "compose", "version"], capture_output=True, check=False).returncode == 0:
        return [cli, "compose"]
    v1 = shutil.which("docker-compose")
    return [v1] if v1 else None


def unusable() -> str | None:
    """Why no Docker engine can run the deployment here, or None."""
    if os.geteuid() != 0:
        return "a Docker engine needs root here (setup.sh installs docker.io as root)"
    if shutil.which("dockerd") is None or docker_cli() is None:
        return "no Docker engine: docker.io is not installed (setup.sh installs it as root)"
    if compose_command() is None:
        return "neither the compose plugin nor docker-compose is installed (setup.sh installs docker-compose)"
    return None


def answers() -> bool:
    try:
        return docker("version", "--format", "{{.Server.Version}}", timeout_s=10).returncode == 0
    except subprocess.TimeoutExpired:
        return False


def running(pid: int) -> bool:
    """Whether `pid` runs (neither gone nor a zombie no one has reaped yet)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (FileNotFoundError, ProcessLookupError):
        return False


def start_engine(timeout_s: float = 60.0) -> str | None:
    """dockerd, started unless one answers already; None once it answers, else why not."""
    if answers():
        return None
    say(f"starting dockerd (log: {DOCKERD_LOG})")
    # detached by a shell that exits at once: dockerd outlives the test and is no child of it
    started = subprocess.run(
        ["sh", "-c", 'dockerd >"$1" 2>&1 </dev/null & echo $!', "sh", str(DOCKERD_LOG)],
        capture_output=True,
        text=True,
        check=True,
        start_new_session=True,
    )
    pid = int(started.stdout)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and running(pid):
        if answers():
            say(f"dockerd {pid} answers")
            return None
        time.sleep(0.2)
    tail = "\n".join(DOCKERD_LOG.read_text(errors="replace").splitlines()[-10:])
    if running(pid):
        os.kill(pid, signal.SIGTERM)
        return f"dockerd did not answer within {timeout_s:.0f} s; its log ends:\n{tail}"
    return f"dockerd exited; its log ends:\n{tail}"


def image_id(name: str) -> str | None:
    done = docker("image", "inspect", "--format", "{{.Id}}", name)
    return done.stdout.strip() if done.returncode == 0 else None


def image_label(name: str, label: str) -> str | None:
    done = docker("image", "inspect", "--format", f'{{{{index .Config.Labels "{label}"}}}}', name)
    return done.stdout.strip() if done.returncode == 0 else None


def image_size_bytes(name: str) -> int:
    return int(docker("image", "inspect", "--format", "{{.Size}}", name).stdout)


def run_logged(
    command: list[str],
    log: Path,
    timeout_s: float,
    show: Callable[[str], str | None],
    env: dict[str, str] | None = None,
) -> int:
    """`command`'s exit code; its output in `log`, what `show` makes of each line printed as it
    comes, and the command killed after `timeout_s`."""
    with (
        log.open("w") as out,
        subprocess.Popen(
            command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env
        ) as process,
    ):
        watchdog = threading.Timer(timeout_s, process.kill)
        watchdog.start()
        try:
            assert process.stdout is not None
            for line in process.stdout:
                out.write(line)
                if text := show(line.rstrip()):
                    say(text)
        finally:
            watchdog.cancel()
        return process.wait()


class BuildSteps:
    """From BuildKit's plain output, the steps that run rather than come from the cache: each
    when its first output comes, and when done if it took a second or more."""

    def __init__(self) -> None:
        self.names: dict[str, str] = {}
        self.running: set[str] = set()

    def __call__(self, line: str) -> str | None:
        if m := re.match(r"#(\d+) (\[.*)", line):
            self.names[m[1]] = m[2][:100]
        elif (m := re.match(r"#(\d+) \d+\.\d+ ", line)) and m[1] in self.names and m[1] not in self.running:
            self.running.add(m[1])
            return f"running {self.names[m[1]]}"
        elif (m := re.match(r"#(\d+) DONE (\d+\.\d+)s", line)) and m[1] in self.names and float(m[2]) >= 1:
            return f"done in {float(m[2]):.0f} s: {self.names[m[1]]}"
        return None


def build_base(timeout_s: float = 600.0) -> float:
    """deploy/base-image.sh, when BASE_IMAGE is absent; the seconds it took (0: it was there)."""
    if image_id(BASE_IMAGE):
        return 0.0
    if shutil.which("debootstrap") is None:
        raise FileNotFoundError("debootstrap, to make the base image (setup.sh installs it as root)")
    say(f"making {BASE_IMAGE} with debootstrap (a minute or two)")
    start = time.monotonic()
    log = Path(tempfile.gettempdir()) / "abyss-base-image.log"
    code = run_logged(
        ["bash", str(ROOT / "deploy" / "base-image.sh"), BASE_IMAGE], log, timeout_s, lambda line: line
    )
    if code != 0:
        raise RuntimeError(f"deploy/base-image.sh failed ({code}); see {log}")
    seconds = time.monotonic() - start
    say(f"{BASE_IMAGE} made in {seconds:.0f} s")
    return seconds


def copied_sources(dockerfile: Path) -> list[Path]:
    """What the Dockerfile's COPY instructions take from the build context (not from a stage)."""
    found = []
    for line in dockerfile.read_text().splitlines():
        words = line.split()
        if words[:1] == ["COPY"] and not any(w.startswith("--from") for w in words):
            found += [dockerfile.parent / w for w in words[1:-1] if not w.startswith("--")]
    return found


def files_of(paths: list[Path]) -> Iterator[Path]:
    for path in paths:
        if path.is_dir():
            yield from sorted(p for p in path.rglob("*") if p.is_file() and "__pycache__" not in p.parts)
        else:
            yield path


def inputs_digest(base: str, context: Path = ROOT) -> str:
    """A digest of what makes the image: the base image's id, the Dockerfile and the files it copies."""
    digest = hashlib.sha256(f"{base}={image_id(base)}\0".encode())
    dockerfile = context / "Dockerfile"
    for path in [dockerfile, *files_of(copied_sources(dockerfile))]:
        digest.update(path.relative_to(context).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def build_image(
    base: str = BASE_IMAGE,
    tag: str = IMAGE,
    context: Path = ROOT,
    timeout_s: float = 900.0,
    force: bool = False,
) -> float | None:
    """The project's image, built unless `tag` holds one of the same inputs (unless `force`);
    the seconds the build took, or None when the image was reused."""
    digest = inputs_digest(base, context)
    if not force and image_label(tag, INPUTS_LABEL) == digest:
        say(f"{tag} is up to date (inputs {digest[:12]})")
        return None
    say(f"building {tag} on {base} (inputs {digest[:12]}; a cold build downloads ~1 GB of wheels)")
    secret = ["--secret", f"id=ca,src={CA_BUNDLE}"] if CA_BUNDLE.is_file() else []
    log = Path(tempfile.gettempdir()) / "abyss-image-build.log"
    start = time.monotonic()
    code = run_logged(
        [
            docker_cli() or "docker",
            "build",
            "--progress=plain",
            *secret,
            "--build-arg",
            f"BASE={base}",
            "--label",
            f"{INPUTS_LABEL}={digest}",
            "-t",
            tag,
            str(context),
        ],
        log,
        timeout_s,
        BuildSteps(),
        env={**os.environ, "DOCKER_BUILDKIT": "1"},
    )
    if code != 0:
        raise RuntimeError(f"docker build failed ({code}); its log ends:\n{log.read_text()[-3000:]}")
    seconds = time.monotonic() - start
    say(f"{tag} built in {seconds:.0f} s")
    docker("image", "prune", "-f", "--filter", f"label={INPUTS_LABEL}")  # the images it replaced
    return seconds


class Compose:
    """compose.yaml as one project: its own name, networks and volume; `directory` holds what the
    file names relative to itself (./certs)."""

    def __init__(self, project: str, directory: Path, env: dict[str, str]) -> None:
        command = compose_command()
        assert command is not None
        self.project = project
        self.command = [
            *command,
            "-p",
            project,
            "-f",
            str(ROOT / "compose.yaml"),
            "--project-directory",
            str(directory),
        ]
        clean = {k: v for k, v in os.environ.items() if not k.startswith("ABYSS_")}
        self.env = {**clean, **env}

    def __call__(self, *args: str, timeout_s: float = 120.0) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [*self.command, *args],
            capture_output=True,
            text=True,
            env=self.env,
            timeout=timeout_s,
            check=False,
        )

    def states(self) -> dict[str, str]:
        """Each service's container state: its health where it has one (starting, healthy,
        unhealthy), else its status (running, exited ...)."""
        ids = docker("ps", "-aq", "--filter", f"label=com.docker.compose.project={self.project}").stdout
        if not ids.split():
            return {}
        shown = docker(
            "inspect",
            "--format",
            '{{index .Config.Labels "com.docker.compose.service"}} '
            "{{if .State.Health}}{{.State.Health.Status}}{{else}}{{.State.Status}}{{end}}",
            *ids.split(),
        )
        return dict(line.split(" ", 1) for line in shown.stdout.splitlines() if " " in line)

    def container(self, service: str) -> str:
        return self("ps", "-q", service).stdout.strip()

    def exit_codes(self) -> dict[str, int]:
        return {
            s: int(docker("inspect", "--format", "{{.State.ExitCode}}", self.container(s)).stdout)
            for s in keys.STATIONS
        }

    def logs(self, tail: int | str = 40) -> str:
        """The services' logs: their last `tail` lines each ("all": every line)."""
        return self("logs", "--no-color", "--tail", str(tail)).stdout

    def wait_healthy(self, timeout_s: float) -> float:
        """Seconds until every station's container is healthy; AssertionError with the logs when
        one exits, turns unhealthy or the deadline passes."""
        start = time.monotonic()
        shown: dict[str, str] = {}
        while time.monotonic() - start < timeout_s:
            states = self.states()
            if states != shown:
                say(
                    f"{time.monotonic() - start:5.1f} s: "
                    + ", ".join(f"{s} {states.get(s, '-')}" for s in keys.STATIONS)
                )
                shown = states
            if [states.get(s) for s in keys.STATIONS] == ["healthy"] * len(keys.STATIONS):
                return time.monotonic() - start
            broken = [s for s, state in states.items() if state in ("unhealthy", "exited", "dead")]
            assert not broken, f"{broken} {states}\n{self.logs()}"
            time.sleep(0.5)
        raise AssertionError(f"not all healthy within {timeout_s:.0f} s: {shown}\n{self.logs()}")

    def wait_mission(self, endpoint: str, system: str, timeout_s: float) -> float:
        """Seconds until shore reports the mission done (MissionStatus, 1 Hz, on its key), as a
        tool on the host sees it through shore's published port."""
        done = threading.Event()
        reached = [-1]

        def on_status(sample: zenoh.Sample) -> None:
            status = message_of(sample, MissionStatus)
            if status is not None:
                if status.waypoint_index != reached[0]:
                    reached[0] = status.waypoint_index
                    say(
                        f"mission: waypoint {status.waypoint_index}/{status.waypoints_total}, "
                        f"mode {status.mode}, arm {status.arm_mode}"
                    )
                if status.done:
                    done.set()

        start = time.monotonic()
        session = open_session(client_config(endpoint), "compose-test")
        subscriber = session.declare_subscriber(keys.mission_key(system), on_status)
        try:
            while not done.wait(2.0):
                states = self.states()
                broken = [s for s in keys.STATIONS if states.get(s) != "healthy"]
                assert not broken, f"{broken} {states}\n{self.logs()}"
                assert time.monotonic() - start < timeout_s, (
                    f"mission not done within {timeout_s:.0f} s (waypoint {reached[0]})\n{self.logs()}"
                )
        finally:
            subscriber.undeclare()
            session.close()
        return time.monotonic() - start
