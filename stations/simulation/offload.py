"""The simulation's sensors rendered in processes of their own. MuJoCo's Python bindings hold the
GIL through a render and a ray cast (up to 16-19 ms at a time here, with the station's 1 ms switch
interval), so in the physics' process a frame set delayed the physics loop: one system alone on
this machine, 40 s, ticks of the physics loop (50 ms) whose work took p99.9 143 ms and at most
263 ms with the cameras in the process, p99.9 37 ms and at most 50 ms with them here. Each sensor
loop keeps its thread, rate and lockstep turn in the simulation; it hands a copy of the physics
state to its own child process, which renders and encodes the message, and waits on the pipe
without the GIL.

The child is this module (`python -m`), started with the station's environment, below the
physics (workers.in_background: the normal scheduler, nice 10), fed length-prefixed pickles over its stdin
and stdout by the process that started it and by nothing else."""

from __future__ import annotations

import contextlib
import os
import pickle
import signal
import struct
import subprocess
import sys
import time
from typing import IO, TYPE_CHECKING, Any, Literal

import numpy as np

from abyss.common.errors import AbyssError
from abyss.common.workers import child_cpu, in_background

if TYPE_CHECKING:
    from abyss.description.robot import Robot

STATE = ("qpos", "qvel", "act", "mocap_pos", "mocap_quat")  # what the sensors' kinematics come from
HEADER = struct.Struct("<Q")
SensorKind = Literal["cameras", "sonar"]  # what a sensor process renders
CLOSE_S = 2.0  # a child that has not gone this long after its stdin closed is killed


class OffloadFailed(AbyssError):
    """The sensor's process died or failed on a request."""


def state_of(data: Any) -> dict[str, Any]:
    """A copy of the physics state the sensors need (take it under the physics' lock)."""
    return {"time": float(data.time), **{name: np.array(getattr(data, name)) for name in STATE}}


def _write(stream: IO[bytes], item: object) -> None:
    payload = pickle.dumps(item, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(HEADER.pack(len(payload)) + payload)
    stream.flush()


def _read(stream: IO[bytes]) -> Any:
    header = stream.read(HEADER.size)
    if len(header) < HEADER.size:
        raise EOFError
    (size,) = HEADER.unpack(header)
    return pickle.loads(stream.read(size))


class Offloaded:
    """A sensor in a child process: `kind` "cameras" (every camera's Image, rendered and encoded
    as simulation.encoding does) or "sonar" (a SonarImage), of `model` with the simulation's
    config and the sensor's own random stream `seed`."""

    def __init__(self, kind: SensorKind, model: Any, config: Any, seed: list[int]) -> None:
        self.kind = kind
        self.process = subprocess.Popen(
            [sys.executable, "-P", "-m", __name__], stdin=subprocess.PIPE, stdout=subprocess.PIPE
        )
        in_background(self.process.pid)  # before it starts threads, which inherit it
        self._topics: tuple[str, ...] | None = None  # of the request submitted, until collected
        self._call("init", kind, model, config, seed)

    def _call(self, *request: object) -> Any:
        self._send(*request)
        return self._reply()

    def _send(self, *request: object) -> None:
        assert self.process.stdin is not None
        try:
            _write(self.process.stdin, request)
        except OSError as exc:
            raise OffloadFailed(
                f"the {self.kind} process ended (exit {self.process.poll()}): {exc!r}"
            ) from None

    def _reply(self) -> Any:
        assert self.process.stdout is not None
        try:
            status, result, cpu_s = _read(self.process.stdout)
        except (EOFError, OSError, pickle.UnpicklingError) as exc:
            raise OffloadFailed(
                f"the {self.kind} process ended (exit {self.process.poll()}): {exc!r}"
            ) from None
        child_cpu(f"{self.kind} {self.process.pid}", cpu_s)
        if status != "ok":
            raise OffloadFailed(f"the {self.kind} process failed: {result}")
        return result

    def submit(
        self,
        state: dict[str, Any],
        blackout: set[str],
        cameras: tuple[str, ...] = (),
        robot: Robot | None = None,
    ) -> None:
        """Start the sensor's messages at `state` (the cameras': those of `cameras`, those in
        `blackout` dark, each on its role's topic: `robot`'s camera_topic); `collect` them. The
        child works on them meanwhile: the caller need not wait."""
        assert self._topics is None, "one request at a time: collect the last one first"
        if self.kind == "cameras":
            assert robot is not None, "the cameras' topics are their roles on the robot"
            self._topics = tuple(robot.camera_topic(camera) for camera in cameras)
            self._send("frames", state, set(blackout), cameras)
        else:
            self._topics = ("sonar",)
            self._send("ping", state)

    def collect(self) -> list[tuple[str, Any]]:
        """The messages `submit` started, each with the topic it goes out on (waits for them)."""
        assert self._topics is not None, "nothing submitted"
        topics, self._topics = self._topics, None
        result = self._reply()
        return list(zip(topics, result if self.kind == "cameras" else [result], strict=True))

    def messages(
        self,
        state: dict[str, Any],
        blackout: set[str],
        cameras: tuple[str, ...] = (),
        robot: Robot | None = None,
    ) -> list[tuple[str, Any]]:
        """The sensor's messages at `state` (`submit`, then `collect`)."""
        self.submit(state, blackout, cameras, robot)
        return self.collect()

    def close(self) -> None:
        assert self.process.stdin is not None and self.process.stdout is not None
        if self._topics is not None:  # a request never collected: its reply read, so the child ends
            with contextlib.suppress(OffloadFailed):
                self.collect()
        try:
            self.process.stdin.close()
            self.process.wait(CLOSE_S)
        except (OSError, subprocess.TimeoutExpired):
            self.process.kill()
            self.process.wait()
        self.process.stdout.close()


class _Sensor:
    """The child's side: the sensor, and a scratch MjData the state is put into."""

    def __init__(self, kind: SensorKind, model: Any, config: Any, seed: list[int]) -> None:
        from abyss.stations.simulation.rendering import choose_gl_backend

        choose_gl_backend()
        import mujoco

        self.mujoco, self.model, self.config = mujoco, model, config
        self.data = mujoco.MjData(model)
        rng = np.random.default_rng(seed)
        if kind == "cameras":
            from abyss.description.robot import robot_at
            from abyss.stations.simulation.rendering import Cameras

            self.cameras = Cameras(
                model,
                config.camera_width_px,
                config.camera_height_px,
                config.water,
                config.marine_snow,
                rng,
                config.camera_samples,
                depth_camera=robot_at(config.robot).depth_camera,
            )
        else:
            from abyss.description.robot import robot_at
            from abyss.stations.simulation.sonar import ImagingSonar, SonarSpec

            self.sonar, self.rng = ImagingSonar(model, SonarSpec(site=robot_at(config.robot).sonar_site)), rng

    def _at(self, state: dict[str, Any]) -> Any:
        self.data.time = state["time"]
        for name in STATE:
            getattr(self.data, name)[:] = state[name]
        self.mujoco.mj_forward(self.model, self.data)
        return self.data

    def frames(self, state: dict[str, Any], blackout: set[str], cameras: tuple[str, ...]) -> list[Any]:
        from abyss.stations.simulation.encoding import encode_image

        self.cameras.blackout = blackout
        data = self._at(state)
        return [encode_image(self.cameras, data, camera, self.config.jpeg_quality) for camera in cameras]

    def ping(self, state: dict[str, Any]) -> Any:
        return self.sonar.message(self._at(state), self.rng)


def serve(requests: IO[bytes], replies: IO[bytes]) -> None:
    """Answer requests until the parent closes the pipe."""
    sensor: _Sensor | None = None
    while True:
        try:
            method, *args = _read(requests)
        except EOFError:
            break
        try:
            if method == "init":
                sensor, result = _Sensor(*args), None
            else:
                assert sensor is not None, "not initialised"
                result = getattr(sensor, method)(*args)
            _write(replies, ("ok", result, time.process_time()))
        except Exception as exc:  # the parent raises it, naming the sensor
            _write(replies, ("error", f"{type(exc).__name__}: {exc}", time.process_time()))
    if sensor is not None and hasattr(sensor, "cameras"):
        sensor.cameras.close()


if __name__ == "__main__":
    # its station ends it (closing the pipe, or going): a Ctrl-C in the station's terminal reaches
    # the whole process group, and the station stops in its own order
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # the replies keep the pipe; anything a library prints goes to the station's log instead
    replies = os.fdopen(os.dup(sys.stdout.fileno()), "wb")
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    serve(sys.stdin.buffer, replies)
