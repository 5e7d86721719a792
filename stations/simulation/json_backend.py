"""The simulation's World as ArduPilot's JSON physics backend (mavlink/sitl_json.py has the
protocol): ArduSub's servo outputs in, one of its frames stepped on abyss's physics (the marine
model, the thrusters' rotors, the site), its sensors' state out. `abyss sitl` serves it; a team's
ArduSub build connects with `--model JSON:HOST`."""

from __future__ import annotations

import logging
import socket
import threading

import mujoco
import numpy as np

from abyss.common.errors import BadInput, ConfigError
from abyss.mavlink.geodesy import Geodesy
from abyss.mavlink.sitl_json import FrameCounter, ServoPacket, frame_thrusters, state_line, thrusts_n
from abyss.stations.simulation.lowlevel import References
from abyss.stations.simulation.world import STATE, World

log = logging.getLogger(__name__)


class JsonBackend:
    def __init__(self, world: World) -> None:
        self.world = world
        self.mapping = frame_thrusters(world.robot)
        self.geodesy = Geodesy(world.site.spec.datum)
        self.counter = FrameCounter()
        spec = world.robot.marine.thrusters
        self._limits = (spec.forward_max_n, spec.reverse_max_n, len(spec.names))
        self._start = np.empty(mujoco.mj_stateSize(world.model, STATE))
        mujoco.mj_getState(world.model, world.data, self._start, STATE)
        self.frame_time_s = float(world.data.time)  # where ArduPilot's frames have brought the physics
        self.thrust_n = np.zeros(self._limits[2])
        self.arm: References | None = None  # onboard's arm and gripper velocities, in a whole system
        self.lock = threading.Lock()  # held while a frame steps (the station's loops read the world)

    def answer(self, data: bytes) -> bytes:
        """The state line for one servo packet (BadInput for anything else)."""
        packet = ServoPacket.parse(data)
        with self.lock:
            return self._answer(packet)

    def _answer(self, packet: ServoPacket) -> bytes:
        taken = self.counter.take(packet.frame_count)
        w = self.world
        if taken == "restart":  # ArduPilot started again: so does the vehicle
            mujoco.mj_setState(w.model, w.data, self._start, STATE)
            mujoco.mj_forward(w.model, w.data)
            self.frame_time_s = float(w.data.time)
            log.info("ArduPilot restarted (frame %d): the vehicle back at its start", packet.frame_count)
        if taken != "again":
            self.thrust_n = thrusts_n(packet.pwm_us, self.mapping, *self._limits)
            self.frame_time_s += 1.0 / packet.frame_rate_hz
            dt = w.model.opt.timestep
            steps = round((self.frame_time_s - w.data.time) / dt)  # whole physics steps, tracking the frames'
            if steps > 0:
                w.step_thrusts(self.thrust_n, steps * dt, self.arm)
        return self.state()

    def state(self) -> bytes:
        d, p = self.world.data, self.world.plant
        quat = d.qpos[p.qpos + 3 : p.qpos + 7] / np.linalg.norm(d.qpos[p.qpos + 3 : p.qpos + 7])
        return state_line(
            float(d.time),
            d.qpos[p.qpos : p.qpos + 3].copy(),
            quat,
            d.qvel[p.qvel : p.qvel + 3].copy(),  # the free joint's: the world frame
            d.qvel[p.qvel + 3 : p.qvel + 6].copy(),  # the body frame
            d.qacc[p.qvel : p.qvel + 3].copy(),
            self.geodesy,
        )


def bind(host: str, port: int, field: str) -> socket.socket:
    """The backend's UDP socket, bound before anything says it serves (an ArduPilot started on
    that word loses no first frame); a port taken is a ConfigError naming `field`."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise ConfigError(field, f"cannot serve UDP {host}:{port}: {exc}") from None
    return sock


def serve(backend: JsonBackend, sock: socket.socket, stop: threading.Event) -> None:
    """Answer each servo packet on the bound `sock` to its sender, until `stop`; what is not one
    is dropped, counted and logged."""
    with sock:
        sock.settimeout(0.1)
        host, port = sock.getsockname()
        log.info("ArduPilot's JSON physics on udp %s:%d (%s)", host, port, backend.world.robot.name)
        dropped = 0
        while not stop.is_set():
            try:
                data, address = sock.recvfrom(1024)
            except TimeoutError:
                continue
            try:
                sock.sendto(backend.answer(data), address)
            except BadInput as exc:
                dropped += 1
                if dropped == 1 or dropped % 100 == 0:
                    log.warning("%s (%d dropped)", exc, dropped)
