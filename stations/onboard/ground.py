"""Onboard's MAVLink side's I/O shell (mavlink.enabled): the ground stations' frames in from the
vessel, what goes back out on each ground link, and the core's part in it. Onboard is either the
vehicle ArduSub-like itself (`AsVehicle`: mavlink.vehicle) or, with a team's ArduSub as the
autopilot (mavlink.autopilot), its companion computer (`AsCompanion`: mavlink.companion)."""

from __future__ import annotations

from typing import Protocol

from abyss.bus.session import Bus, Inbox
from abyss.config import Config
from abyss.interface.messages import GROUND_LINKS, MAVLINK_FRAMES_MAX_BYTES, CommandAck, MavlinkFrames
from abyss.stations.onboard.core import Command, Onboard, OnboardOutputs
from abyss.stations.onboard.modes import ControlMode


class Ground(Protocol):
    def take(self, now_s: float) -> list[Command]:
        """The ground side's commands for the core this period."""
        ...

    def answer(self, core_out: OnboardOutputs, now_s: float) -> list[CommandAck]:
        """The period's MAVLink out; the core's answers that are not the ground side's returned."""
        ...


def ground_of(config: Config, bus: Bus, core: Onboard) -> Ground:
    inbox = bus.subscribe("vessel", "mavlink/in", MavlinkFrames, maxlen=256)
    if config.mavlink.autopilot:
        return AsCompanion(config, bus, core, inbox)
    return AsVehicle(config, bus, core, inbox)


class AsVehicle:
    """Onboard answers as ArduSub does; the ground stations' commands become the core's."""

    def __init__(self, config: Config, bus: Bus, core: Onboard, inbox: Inbox[MavlinkFrames]) -> None:
        from abyss.mavlink.vehicle import MavlinkVehicle, VehicleOutputs  # pymavlink's, only when asked

        self.bus, self.core, self.inbox = bus, core, inbox
        self.vehicle = MavlinkVehicle(config, bus.clock.now_s())
        self.outputs = VehicleOutputs
        self.out = VehicleOutputs()

    def take(self, now_s: float) -> list[Command]:
        """The commands the vehicle decided last period (the goal of its mode then), and what the
        ground stations said since (answered this period)."""
        decided = self.out.commands
        self.out = out = self.outputs()
        for received in self.inbox.drain():
            for reason in self.vehicle.receive(received.message.link, received.message.data, now_s, out):
                self.bus.reject(received.key, reason)
        self.core.pilot_goals = set(self.vehicle.pilot_goals)
        return [*decided]  # widened to the core's commands

    def answer(self, core_out: OnboardOutputs, now_s: float) -> list[CommandAck]:
        acks = self.vehicle.answered(core_out.acks)
        self.vehicle.step(now_s, core_out.telemetry, core_out.estimates, self.out)
        for link, data in self.out.frames.items():
            if data:
                self.bus.publish("mavlink/out", MavlinkFrames(link, bytes(data)))
        return acks


class AsCompanion:
    """ArduSub is the vehicle: its MAVLink routed to and from the ground links, onboard's goals
    handed to it."""

    def __init__(self, config: Config, bus: Bus, core: Onboard, inbox: Inbox[MavlinkFrames]) -> None:
        from abyss.mavlink.companion import Companion, Goal  # pymavlink's, only when asked

        self.bus, self.core, self.inbox = bus, core, inbox
        self.companion = Companion(config)
        self.goal = Goal

    def take(self, now_s: float) -> list[Command]:
        for received in self.inbox.drain():
            self.companion.to_autopilot(received.message.data)
        return []

    def answer(self, core_out: OnboardOutputs, now_s: float) -> list[CommandAck]:
        for run in self.companion.from_autopilot(MAVLINK_FRAMES_MAX_BYTES):
            for link in GROUND_LINKS:
                self.bus.publish("mavlink/out", MavlinkFrames(link, run))
        vehicle = self.core.vehicle
        waypoint = (
            vehicle.waypoints[min(vehicle.index, len(vehicle.waypoints) - 1)]
            if len(vehicle.waypoints)
            else None
        )
        self.companion.hand(self.goal(self.core.operator_mode == ControlMode.AUTO, waypoint), now_s)
        return core_out.acks
