"""A recorded station played back in place of a live one (`abyss replay RUN_DIR --as STATION`).

The replay runs in the station's own shell (its Zenoh session, its links, its liveliness token), so
the live stations cannot tell it from the real one: each message the station sent in the recorded
run is published again on its key, through its link, at its recorded time after the run's start
(`--speed` scales the time), stamped anew. All replayed stations share one start: `abyss up` puts
it on `abyss/<system>/replay` once every station is up.

Commands are the one thing a recording cannot hold: the live shore gives its commands new ids, and
the recorded station answered the recorded ones. The replayer pairs the n-th command of each kind
it receives live with the n-th the station received in the recording, and writes the live id into
what it replays (telemetry's `command_id` and `arm_command_id`, the acknowledgements), answering a
command sent again as the station did the first time."""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from abyss.bus.session import Bus, Inbox
from abyss.common.errors import ConfigError
from abyss.config import Config
from abyss.interface import keys
from abyss.interface.messages import (
    ArmGoal,
    CommandAck,
    Message,
    OperatorMode,
    ReplayStart,
    Telemetry,
    Waypoints,
    decode,
)
from abyss.recording.reader import Record, Recording, open_recording
from abyss.recording.store import data_spec

log = logging.getLogger(__name__)

Command = Waypoints | ArmGoal | OperatorMode  # what a replay pairs with the live system's ids
COMMAND_KIND: dict[type[Command], str] = {Waypoints: "waypoints", ArmGoal: "arm", OperatorMode: "mode"}
M = TypeVar("M", bound=Message)
START_WAIT_S = 120.0  # for `abyss up`'s start, which comes once every station is up
START_DELAY_S = 1.0  # from all stations up to the replay's first message


def check_replayable(recording: Recording, stations: tuple[str, ...]) -> None:
    """Each station to replay was recorded (its own file, or what its neighbours received of it)."""
    for station in stations:
        keys.check_station(station)
        if not recording.published((station,)):
            raise ConfigError(
                "--as",
                f"{recording.run_dir} holds no message of {station} (recorded: "
                f"{', '.join(sorted(recording.stations)) or 'none'})",
            )


def origin_s(recording: Recording) -> float:
    """The recorded run's start: its first message's sender stamp (the same in every replayer)."""
    return min(r.sent_s for r in recording.published())


class Commands:
    """The ids of the commands the replayed station was given in the recording, paired in order of
    arrival with those the live system gives it (per kind: waypoints, arm, mode)."""

    def __init__(self, recorded: list[Command]) -> None:
        self.recorded: dict[str, list[int]] = {kind: [] for kind in COMMAND_KIND.values()}
        for message in recorded:
            ids = self.recorded[COMMAND_KIND[type(message)]]
            if message.command_id not in ids:
                ids.append(message.command_id)
        self.live: dict[str, list[int]] = {kind: [] for kind in COMMAND_KIND.values()}
        self.to_live: dict[tuple[str, int], int] = {}

    def given(self, message: Command) -> tuple[str, int] | None:
        """A live command: its kind and the recorded id it stands for (None past the recording's)."""
        kind, live_id = COMMAND_KIND[type(message)], message.command_id
        if live_id not in self.live[kind]:
            self.live[kind].append(live_id)
        n = self.live[kind].index(live_id)
        if n >= len(self.recorded[kind]):
            return None
        self.to_live[(kind, self.recorded[kind][n])] = live_id
        return kind, self.recorded[kind][n]

    def translate(self, message: Message) -> Message | None:
        """`message` with the live ids; None for an acknowledgement of a command not given live yet."""
        if isinstance(message, CommandAck):
            live_id = self.to_live.get((message.command, message.command_id))
            return None if live_id is None else dataclasses.replace(message, command_id=live_id)
        if isinstance(message, Telemetry):
            return dataclasses.replace(
                message,
                command_id=self.to_live.get(("waypoints", message.command_id), message.command_id),
                arm_command_id=self.to_live.get(("arm", message.arm_command_id), message.arm_command_id),
            )
        return message


def check_speed(speed: float) -> float:
    if not speed > 0:
        raise ConfigError("--speed", f"{speed} must be a positive factor (2: twice as fast)")
    return speed


def replayer(run_dir: Path, speed: float) -> Callable[[Config, Bus], None]:
    """The station entry (`run(config, bus)`) that plays `bus.station`'s recorded messages back."""
    check_speed(speed)
    recording = open_recording(run_dir)

    def run(config: Config, bus: Bus) -> None:
        Replay(recording, bus, speed).run()

    return run


def _command_inboxes(
    bus: Bus, given: list[keys.KeySpec]
) -> list[Inbox[Waypoints] | Inbox[ArmGoal] | Inbox[OperatorMode]]:
    """An inbox of its class for each key in `given` that carries a command."""

    def of(cls: type[M]) -> list[Inbox[M]]:
        return [bus.subscribe(s.station, s.topic, cls) for s in given if s.message_class is cls]

    return [*of(Waypoints), *of(ArmGoal), *of(OperatorMode)]


class Replay:
    def __init__(self, recording: Recording, bus: Bus, speed: float) -> None:
        check_replayable(recording, (bus.station,))
        self.bus, self.speed = bus, speed
        self.records = recording.published((bus.station,))
        self.origin_s = origin_s(recording)
        given = [s for s in keys.KEYS if s.to == bus.station and s.message_class in COMMAND_KIND]
        recorded = recording.messages([r for r in recording.published() if data_spec(r.key) in given])
        # the recording is read as whatever it holds: its commands are the messages of a command class
        self.commands = Commands(
            [m for _, m in recorded if isinstance(m, (Waypoints, ArmGoal, OperatorMode))]
        )
        self.inboxes = _command_inboxes(bus, given)
        self.acks: dict[tuple[str, int], CommandAck] = {}  # the recorded answers, once due
        self.start = bus.subscribe_key(keys.replay_key(bus.system), ReplayStart, maxlen=1)
        self.published = 0

    def run(self) -> None:
        start_s = self._wait_start()
        if start_s is None:
            return
        log.info(
            "replaying %d messages of %s from %s (speed %g)",
            len(self.records),
            self.bus.station,
            time.strftime("%H:%M:%S", time.localtime(start_s)),
            self.speed,
        )
        for record in self.records:
            due_s = start_s + (record.sent_s - self.origin_s) / self.speed
            while not self.bus.stop.is_set():
                self._take_commands()
                if self.bus.stop.wait(max(0.0, min(0.02, due_s - time.time()))) or time.time() >= due_s:
                    break
            if self.bus.stop.is_set():
                return
            self._publish(record)
        log.info("replayed %d messages of %s; holding until stopped", self.published, self.bus.station)
        while not self.bus.stop.wait(0.05):
            self._take_commands()

    def _wait_start(self) -> float | None:
        deadline_s = time.monotonic() + START_WAIT_S
        while not self.bus.stop.wait(0.05):
            start = self.start.latest()
            if start is not None:
                return start.message.start_s
            if time.monotonic() > deadline_s:
                log.error("no replay start on %s in %g s", keys.replay_key(self.bus.system), START_WAIT_S)
                return None
        return None

    def _take_commands(self) -> None:
        """Live commands: pair their ids; one whose recorded answer is past is answered again."""
        for inbox in self.inboxes:
            for item in inbox.drain():
                paired = self.commands.given(item.message)
                if paired is not None and paired in self.acks:
                    self._send("ack", self.acks[paired])

    def _publish(self, record: Record) -> None:
        message = decode(record.key, record.payload).message
        if isinstance(message, CommandAck):
            self.acks[(message.command, message.command_id)] = message
        self._send(record.topic.split("/", 1)[1], message)

    def _send(self, topic: str, message: Message) -> None:
        translated = self.commands.translate(message)
        if translated is not None:  # an answer to a command not given live yet waits for it
            self.bus.publish(topic, translated)
            self.published += 1
