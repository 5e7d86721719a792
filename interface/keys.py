"""Key expressions and the table of every key the system uses.

`abyss/<system>/<station>/<topic>`: `<station>` is the publisher. `key()` is the only
function that formats a key; everything else asks it. `KEYS` is the one table of data
keys: publisher, topic, message class, rate, reliability and the hop it crosses. The key
table in docs/links.md and `abyss keys` are both generated from it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Literal

from abyss.common.errors import ConfigError
from abyss.interface import faults
from abyss.interface.messages import (
    ArmGoal,
    ArmVelocityRef,
    CommandAck,
    Heartbeat,
    Image,
    Intervention,
    InterventionGoal,
    JointState,
    MavlinkFrames,
    Message,
    NavState,
    OperatorMode,
    PerceptionStatus,
    PointCloud,
    RecognisedObjects,
    SceneAck,
    SceneRequest,
    SceneUpdate,
    SonarImage,
    Telemetry,
    VelocityRef,
    Waypoints,
)

PREFIX = "abyss"
STATIONS: tuple[str, ...] = ("simulation", "onboard", "vessel", "onshore")
# hop name -> the two stations it joins, in the order of the chain.
HOPS: dict[str, tuple[str, str]] = {
    "rov": ("simulation", "onboard"),
    "tether": ("onboard", "vessel"),
    "satellite": ("vessel", "onshore"),
}
_SYSTEM_ID = re.compile(r"^[A-Za-z0-9_-]{1,64}$")

Reliability = Literal["reliable", "best-effort"]
Priority = Literal["control", "telemetry", "bulk"]  # Zenoh priority, highest first


def check_system_id(system: str) -> str:
    if not _SYSTEM_ID.match(system):
        raise ConfigError("system", f"{system!r} is not 1-64 characters of [A-Za-z0-9_-]")
    return system


def check_station(station: str) -> str:
    if station not in STATIONS:
        raise ConfigError("station", f"unknown station {station!r}; allowed: {', '.join(STATIONS)}")
    return station


def check_hop(hop: str) -> str:
    if hop not in HOPS:
        raise ConfigError("hop", f"unknown hop {hop!r}; allowed: {', '.join(HOPS)}")
    return hop


def key(system: str, *parts: str) -> str:
    """The key `abyss/<system>/<part>/...`; the only place keys are formatted."""
    return "/".join((PREFIX, system, *parts))


def hops_of(station: str) -> dict[str, str]:
    """Hops adjacent to `station`, each mapped to the neighbour at its other end."""
    return {hop: (b if a == station else a) for hop, (a, b) in HOPS.items() if station in (a, b)}


def hop_between(a: str, b: str) -> str:
    for hop, ends in HOPS.items():
        if set(ends) == {a, b}:
            return hop
    raise ConfigError("hop", f"{a} and {b} are not neighbours; hops: {HOPS}")


@dataclass(frozen=True)
class KeySpec:
    """One data key: who publishes it, what it carries, how often, over which hop."""

    station: str
    topic: str
    message_class: type[Message]  # what it carries: `bus.subscribe` hands out an inbox of it
    rate_hz: float  # nominal rate; 0 for event-driven keys
    reliability: Reliability  # reliable: congestion control BLOCK; best-effort: DROP
    to: str  # the neighbour that subscribes
    priority: Priority  # control: commands, navigation, heartbeats; telemetry; bulk: images, clouds, scene
    # the configuration's section that turns it on ("mavlink": only with mavlink.enabled); "" always
    feature: str = ""

    @property
    def message(self) -> str:
        """The name of the message type it carries, as the tables and recordings write it."""
        return self.message_class.TYPE

    @property
    def hop(self) -> str:
        return hop_between(self.station, self.to)

    def key(self, system: str) -> str:
        return key(system, self.station, self.topic)


KEYS: tuple[KeySpec, ...] = (
    KeySpec("simulation", "nav", NavState, 20.0, "best-effort", "onboard", "control"),
    KeySpec("simulation", "joints", JointState, 20.0, "best-effort", "onboard", "control"),
    # the cameras by their role, whatever the robot names them (Robot.camera_topic; each Image
    # says its camera): the stereo pair's left and right, and the depth camera
    KeySpec("simulation", "camera/left", Image, 1.0, "best-effort", "onboard", "bulk"),
    # on the stereo matcher's sets alone (description.models.stereo_set: 1 in onboard.stereo_every)
    KeySpec("simulation", "camera/right", Image, 0.5, "best-effort", "onboard", "bulk"),
    KeySpec("simulation", "camera/depth", Image, 1.0, "best-effort", "onboard", "bulk"),
    KeySpec("simulation", "sonar", SonarImage, 2.0, "best-effort", "onboard", "bulk"),
    KeySpec("onboard", "cmd/vehicle_velocity", VelocityRef, 20.0, "best-effort", "simulation", "control"),
    KeySpec("onboard", "cmd/arm_velocity", ArmVelocityRef, 20.0, "best-effort", "simulation", "control"),
    # onboard's navigation estimate, once settled: what a hybrid run's twin renders at
    KeySpec("onboard", "nav/estimate", NavState, 20.0, "best-effort", "simulation", "control"),
    KeySpec("onboard", "telemetry", Telemetry, 10.0, "best-effort", "vessel", "telemetry"),
    KeySpec("onboard", "cloud", PointCloud, 2.0, "best-effort", "vessel", "bulk"),
    KeySpec("onboard", "image", Image, 1.0, "best-effort", "vessel", "bulk"),
    KeySpec("onboard", "sonar", SonarImage, 2.0, "best-effort", "vessel", "bulk"),
    KeySpec("onboard", "ack", CommandAck, 0.0, "reliable", "vessel", "control"),
    KeySpec("vessel", "goal/waypoints", Waypoints, 0.0, "reliable", "onboard", "control"),
    KeySpec("vessel", "goal/arm", ArmGoal, 0.0, "reliable", "onboard", "control"),
    KeySpec("vessel", "goal/mode", OperatorMode, 0.0, "reliable", "onboard", "control"),
    KeySpec("vessel", "goal/intervene", InterventionGoal, 0.0, "reliable", "onboard", "control"),
    KeySpec("vessel", "heartbeat", Heartbeat, 2.0, "best-effort", "onboard", "control"),
    KeySpec("vessel", "telemetry", Telemetry, 2.0, "best-effort", "onshore", "telemetry"),
    KeySpec("vessel", "scene", SceneUpdate, 0.0, "reliable", "onshore", "bulk"),
    KeySpec("vessel", "objects", RecognisedObjects, 0.5, "best-effort", "onshore", "bulk"),
    KeySpec("vessel", "image", Image, 0.2, "best-effort", "onshore", "bulk"),
    KeySpec("vessel", "sonar", SonarImage, 0.2, "best-effort", "onshore", "bulk"),
    KeySpec("vessel", "perception", PerceptionStatus, 0.5, "best-effort", "onshore", "telemetry"),
    KeySpec("vessel", "ack", CommandAck, 0.0, "reliable", "onshore", "control"),
    KeySpec("onshore", "op/waypoints", Waypoints, 0.0, "reliable", "vessel", "control"),
    KeySpec("onshore", "op/arm", ArmGoal, 0.0, "reliable", "vessel", "control"),
    KeySpec("onshore", "op/mode", OperatorMode, 0.0, "reliable", "vessel", "control"),
    KeySpec("onshore", "op/intervene", Intervention, 0.0, "reliable", "vessel", "control"),
    KeySpec("onshore", "heartbeat", Heartbeat, 1.0, "best-effort", "vessel", "control"),
    KeySpec("onshore", "scene_request", SceneRequest, 0.0, "reliable", "vessel", "control"),
    KeySpec("onshore", "scene_ack", SceneAck, 0.0, "reliable", "vessel", "control"),
    # MAVLink (the mavlink/ room), as BlueOS's mavlink-server names its Zenoh keys: the vehicle's
    # frames out to its ground stations, theirs in; the vessel relays the satellite's side
    KeySpec("onboard", "mavlink/out", MavlinkFrames, 10.0, "best-effort", "vessel", "telemetry", "mavlink"),
    KeySpec("vessel", "mavlink/in", MavlinkFrames, 0.0, "reliable", "onboard", "control", "mavlink"),
    KeySpec("vessel", "mavlink/out", MavlinkFrames, 0.2, "best-effort", "onshore", "telemetry", "mavlink"),
    KeySpec("onshore", "mavlink/in", MavlinkFrames, 0.0, "reliable", "vessel", "control", "mavlink"),
)


def spec(station: str, topic: str) -> KeySpec:
    for s in KEYS:
        if s.station == station and s.topic == topic:
            return s
    raise ConfigError("key", f"no key {station}/{topic} in interface.keys.KEYS")


# Control and observation keys: not carried over an emulated hop.
def link_key(system: str, hop: str) -> str:
    """Profile of a hop: queryable (current profile and stats), settable (LinkControl)."""
    return key(system, "link", check_hop(hop))


def linkstats_key(system: str, station: str, hop: str) -> str:
    return key(system, station, "linkstats", hop)


def alive_key(system: str, station: str) -> str:
    """Liveliness token of a running station."""
    return key(system, station, "alive")


def truth_key(system: str) -> str:
    """The vehicle's true state, for scoring only: no station may steer by it."""
    return key(system, "simulation", "truth")


def panel_truth_key(system: str) -> str:
    """The panel's true state (valve and lever angles, the fingers' contact forces), for
    scoring only: an intervention is judged by it, not by what onboard believes."""
    return key(system, "simulation", "truth", "panel")


def simulation_control_key(system: str) -> str:
    return key(system, "simulation", "control")


def simulation_status_key(system: str) -> str:
    return key(system, "simulation", "status")


def clock_key(system: str) -> str:
    """The simulation's clock, with `--time sim` (timing.clock)."""
    return key(system, "clock")


def progress_key(system: str, station: str) -> str:
    """How far a station's loops are done in simulated time, with `--time sim`: the
    simulation waits for the slowest (timing.clock.Holdback)."""
    return key(system, station, "progress")


def lockstep_key(system: str, station: str) -> str:
    """A station's progress through each period, with `--time lockstep` (timing.lockstep)."""
    return key(system, station, "lockstep")


def operator_key(system: str, topic: str) -> str:
    """Commands of an operator's tool (`abyss teleop`, `abyss op`, a console) to the onshore
    station, handed over by query and each signed with its sender in the query's attachment
    (console.op.hand_command), on shore's own network; the onshore station answers that it took
    one (bus.session.Bus.take_key), puts it on this key as taken for every console, sends it down
    the satellite as op/<topic> until onboard answers, and hands onboard's acknowledgements back on
    operator/ack."""
    return key(system, "onshore", "operator", topic)


def description_key(system: str, station: str) -> str:
    """The running system's description (interface.system_description: the robot's and the site's
    package files it runs by), which the testbed's shell of each station serves to a query, past
    no emulated link, for the operator's tools; `station` "*" for any of them."""
    return key(system, station, "description")


def onboard_state_key(system: str) -> str:
    """The onboard controllers' state at the source, past no emulated link: for scoring (the
    scenario runner times the failsafe by it) only, as the truth is."""
    return key(system, "onboard", "state")


def shore_event_key(system: str) -> str:
    """What shore saw of the stations and did about it (ShoreEvent: a restart), as it happens, for
    the operator's tools on shore's own network."""
    return key(system, "onshore", "event")


def mission_key(system: str) -> str:
    """Mission status as the operator sees it, published on shore."""
    return key(system, "onshore", "mission")


def replay_key(system: str) -> str:
    """The start of a replay (`abyss replay`), put by `abyss up` for the replayed stations."""
    return key(system, "replay")


def observation_keys(system: str) -> tuple[str, ...]:
    """The testbed's keys that `abyss up` records beside the stations' data (as key expressions)."""
    return (
        truth_key(system),
        panel_truth_key(system),
        simulation_status_key(system),
        onboard_state_key(system),
        mission_key(system),
        key(system, "*", "linkstats", "*"),
        operator_key(system, "*"),
        simulation_control_key(system),
        key(system, "link", "*"),
        replay_key(system),
    )


CONTROL_KEYS: tuple[tuple[str, str, str, str], ...] = (
    # (key pattern, message, rate, note)
    (
        "abyss/<system>/link/<hop>",
        "LinkControl",
        "event",
        "put: change a hop's profile; get: profiles and stats",
    ),
    ("abyss/<system>/<station>/linkstats/<hop>", "LinkStats", "1 Hz", "what each emulator measured"),
    ("abyss/<system>/<station>/alive", "liveliness", "-", "token held while the station runs"),
    (
        "abyss/<system>/<station>/description",
        "JSON (queryable)",
        "on query",
        "the robot's and site's package files the system runs by, for the operator's tools",
    ),
    ("abyss/<system>/simulation/truth", "NavState", "20 Hz", "true vehicle state, for scoring only"),
    (
        "abyss/<system>/simulation/truth/panel",
        "PanelState",
        "10 Hz",
        "true valve and lever angles and finger forces, for scoring only",
    ),
    (
        "abyss/<system>/simulation/control",
        "SimulationControl",
        "event",
        faults.key_note(),
    ),
    ("abyss/<system>/simulation/status", "SimulationStatus", "1 Hz", "sim time, real-time factor, faults"),
    ("abyss/<system>/clock", "SimTime", "20 Hz simulated", "the simulation's clock, with --time sim"),
    (
        "abyss/<system>/<station>/progress",
        "SimTime",
        "event",
        "how far the station's loops are done in simulated time; the simulation waits for the slowest",
    ),
    (
        "abyss/<system>/<station>/lockstep",
        "LockstepReport",
        "2 per period",
        "a station's links delivered what was due, then it is done (--time lockstep)",
    ),
    (
        "abyss/<system>/onshore/operator/<waypoints|arm|mode|intervene>",
        "Waypoints, ArmGoal, OperatorMode, Intervention",
        "event",
        "operator tools hand them to the onshore station by query (signed with the sender); shore "
        "answers, puts each out as taken, and sends it down until onboard answers",
    ),
    (
        "abyss/<system>/onshore/operator/ack",
        "CommandAck",
        "event",
        "onboard's answers to operator commands, handed back to the tools",
    ),
    ("abyss/<system>/onboard/state", "Telemetry", "10 Hz", "onboard's state at the source, for scoring only"),
    ("abyss/<system>/onshore/mission", "MissionStatus", "1 Hz", "mission state seen on shore"),
    (
        "abyss/<system>/onshore/event",
        "ShoreEvent",
        "event",
        "a station's restart as shore saw it and what shore did, for the operator's tools",
    ),
    ("abyss/<system>/replay", "ReplayStart", "1 Hz", "when replayed stations begin (`abyss replay`)"),
)


PROVIDERS = {"vehicle": "the real vehicle", "twin": "the twin (simulation)"}


def keys_table(providers: dict[str, str] | None = None) -> str:
    """The Markdown table of every key; `abyss keys` prints it, docs/links.md holds it. With a
    hybrid run's `providers` (simulation topic -> "vehicle" or "twin": HybridConfig.providers), a
    column says who provides each data key in that run."""
    extra = " provided by |" if providers else ""
    rows = [
        "| key | message | rate | reliability | priority | hop |" + extra,
        "| --- | --- | --- | --- | --- | --- |" + (" --- |" if providers else ""),
    ]
    for s in KEYS:
        rate = f"{s.rate_hz:g} Hz" if s.rate_hz else "event"
        by = (
            PROVIDERS.get(providers.get(s.topic, ""), s.station)
            if providers and s.station == "simulation"
            else s.station
        )
        if s.feature:
            rate += f", with {s.feature}.enabled"
        rows.append(
            f"| `abyss/<system>/{s.station}/{s.topic}` | {s.message} | {rate} | {s.reliability} "
            f"| {s.priority} | {s.hop} ({s.station} -> {s.to}) |" + (f" {by} |" if providers else "")
        )
    for pattern, message, rate, note in CONTROL_KEYS:
        rows.append(
            f"| `{pattern}` | {message} | {rate} | reliable | - | none: {note} |"
            + (" testbed |" if providers else "")
        )
    return "\n".join(rows)
