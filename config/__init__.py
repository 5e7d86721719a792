"""Typed configuration: frozen dataclasses loaded from TOML (or the JSON that `abyss up`
hands its stations), overridable from the command line with `--set section.field=value`.
Every error names the file, the field and what is allowed. The sections live beside this module
(simulation, stations, system, and the field checks in fields); this one holds the whole and its loading."""

from __future__ import annotations

import dataclasses
import json
import re
import tomllib
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from abyss.common.errors import BadInput, ConfigError
from abyss.common.reading import read_table
from abyss.config.hybrid import ROS2_VEHICLE, HybridConfig
from abyss.config.mavlink import MavlinkConfig
from abyss.config.simulation import SimulationConfig
from abyss.config.stations import OnboardConfig, OnshoreConfig, VesselConfig
from abyss.config.system import (
    CpuConfig,
    LinksConfig,
    MissionConfig,
    RecordConfig,
    Ros2Config,
    TimeConfig,
)
from abyss.description.models import PACKAGE_FILES, package_dir
from abyss.description.robot import Robot, robot_at
from abyss.description.site import Site, site_at
from abyss.interface import keys


@dataclass(frozen=True)
class Config:
    system: str = "default"
    seed: int = 0
    links: LinksConfig = field(default_factory=LinksConfig)
    simulation: SimulationConfig = field(default_factory=SimulationConfig)
    onboard: OnboardConfig = field(default_factory=OnboardConfig)
    vessel: VesselConfig = field(default_factory=VesselConfig)
    onshore: OnshoreConfig = field(default_factory=OnshoreConfig)
    mission: MissionConfig = field(default_factory=MissionConfig)
    record: RecordConfig = field(default_factory=RecordConfig)
    ros2: Ros2Config = field(default_factory=Ros2Config)
    cpu: CpuConfig = field(default_factory=CpuConfig)
    time: TimeConfig = field(default_factory=TimeConfig)
    hybrid: HybridConfig = field(default_factory=HybridConfig)
    mavlink: MavlinkConfig = field(default_factory=MavlinkConfig)

    def __post_init__(self) -> None:
        keys.check_system_id(self.system)
        if self.mavlink.enabled and self.time.mode != "real":
            raise ConfigError(
                "mavlink.enabled",
                f"time.mode {self.time.mode}: a ground station keeps the wall clock's time (its heartbeats, "
                "the failsafes' timeouts); use --time real with it",
            )

        panel = site_at(self.simulation.site).panel
        for i, (part, amount) in enumerate(self.mission.interventions):
            try:
                panel.intent(part, amount)
            except BadInput as exc:
                raise ConfigError(f"mission.interventions[{i}]", str(exc)) from None
        if self.time.simulated and self.ros2.station:
            raise ConfigError(
                "time.mode",
                "sim: a ROS 2 node (ros2.station, --ros2) runs on the wall clock; use --time real with it",
            )
        camera_rate_hz = self.simulation.camera_rate_hz
        if camera_rate_hz > 0 and self.onboard.perception_latency_s * camera_rate_hz >= 1.0:
            raise ConfigError(
                "onboard.perception_latency_s",
                f"{self.onboard.perception_latency_s} s must stay below the cameras' period "
                f"({1.0 / camera_rate_hz:g} s at simulation.camera_rate_hz = {camera_rate_hz}): "
                "a set's clouds go out before the next set is taken",
            )
        if self.simulation.sonar_rate_hz > 0:
            robot = robot_of(self)
            if not robot.has_sonar:
                raise ConfigError(
                    "simulation.sonar_rate_hz",
                    f"{self.simulation.sonar_rate_hz} Hz, but robot {robot.name!r} has no site "
                    f"{robot.sonar_site!r} for the sonar: name its site in {robot.file}'s [sonar] "
                    "site, or set simulation.sonar_rate_hz = 0 for a robot without one",
                )
        self._check_hybrid()

    def _check_hybrid(self) -> None:
        """A real vehicle runs on the wall clock; a ROS 2 node in the simulation's place is the
        real vehicle of a hybrid run, and provides what the gateway parses (its navigation, its joints)."""
        hybrid = self.hybrid
        if hybrid.on and self.time.simulated:
            raise ConfigError(
                "time.mode",
                f"{self.time.mode}: a real vehicle (hybrid.vehicle, --hybrid) runs on the wall clock; "
                "use --time real",
            )
        if self.ros2.station == "simulation":
            parsed = ROS2_VEHICLE
            if not hybrid.on or not set(hybrid.vehicle) <= set(parsed):
                raise ConfigError(
                    "hybrid.vehicle",
                    f"{', '.join(hybrid.vehicle) or 'none'}: a ROS 2 node in the simulation's place (--ros2 "
                    f"simulation) is a hybrid run's real vehicle, and provides {', '.join(parsed)} at most",
                )

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), indent=2)


def merge(under: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """`over` on top of `under`, table by table (a field `over` sets replaces `under`'s)."""
    out = dict(under)
    for key, value in over.items():
        out[key] = (
            merge(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
        )
    return out


def _under_packages(table: dict[str, Any]) -> tuple[dict[str, Any], list[tuple[dict[str, Any], str]]]:
    """The table with the configuration its robot and site packages carry (`[config]` of
    robot.toml and site.toml: a robot's gains, a site's start and mission) under it: the robot's
    own, then the site's,
    then the table's own on top; and those layers with their files, lowest
    first. A robot's may name the site it flies by default (`simulation.site`), which the
    table's own still overrides."""

    layers: list[tuple[dict[str, Any], str]] = []
    under: dict[str, Any] = {}
    for field_name, package_at in (("robot", robot_at), ("site", site_at)):
        simulation = merge(under, table).get("simulation", {})
        package = simulation.get(field_name, "") if isinstance(simulation, dict) else ""
        directory = package_dir(field_name, package) if isinstance(package, str) and package else None
        # one that is no package at all, the field's own check says so (config/simulation.py)
        if directory is not None and (directory / PACKAGE_FILES[field_name]).is_file():
            loaded = package_at(package)  # a ConfigError names its file and field
            layers.append((loaded.spec.config, f"{loaded.file}: config"))
            under = merge(under, loaded.spec.config)
    return merge(under, table), layers


def _sets(table: dict[str, Any], field_name: str) -> bool:
    """Whether `table` sets the field `field_name` (dotted, list indices aside)."""
    node: Any = table
    for part in re.sub(r"\[\d+\]", "", field_name).split("."):
        if not isinstance(node, dict) or part not in node:
            return False
        node = node[part]
    return True


def load(
    path: Path | None = None,
    overrides: typing.Sequence[str] = (),
    base: dict[str, Any] | None = None,
    options: dict[str, str] | None = None,
) -> Config:
    """Defaults, then the file (TOML or JSON), then `section.field=value` overrides. An error
    names where its field's value came from: the option in `options` (field -> the option the
    user typed, e.g. "time.speed" -> "--speed"), else --set, else the file."""
    table: dict[str, Any] = dict(base or {})
    source = str(path) if path else "--set"
    overridden: dict[str, str] = {}
    if path is not None:
        try:
            text = path.read_text()
            table = json.loads(text) if path.suffix == ".json" else tomllib.loads(text)
        except (OSError, ValueError) as exc:
            raise ConfigError("config", f"cannot read: {exc}", source) from None
    for item in overrides:
        name, sep, value = item.partition("=")
        if not sep or not name:
            raise ConfigError("--set", f"{item!r} is not section.field=value")
        *sections, leaf = name.split(".")
        node = table
        for section in sections:
            node = node.setdefault(section, {})
            if not isinstance(node, dict):
                raise ConfigError(name, "is not a section")
        node[leaf] = value
        overridden[name] = (options or {}).get(name, "--set")
    own = table
    table, layers = _under_packages(table)
    try:
        return typing.cast(Config, read_table(Config, table))
    except ConfigError as exc:  # named where the field was set: an option, the user's, a package's
        packages = [file for layer, file in reversed(layers) if _sets(layer, exc.field)]
        where = overridden.get(exc.field) or (
            source if _sets(own, exc.field) or not packages else packages[0]
        )
        raise ConfigError(exc.field, exc.reason, where) from None
    except json.JSONDecodeError as exc:
        raise ConfigError("config", f"bad list value: {exc}", source) from None


def robot_of(config: Config) -> Robot:
    """The robot the configuration runs (`simulation.robot`; "" the shipped one), loaded once."""
    return robot_at(config.simulation.robot)


def site_of(config: Config) -> Site:
    """The site the configuration runs (`simulation.site`; "" the shipped one), loaded once."""
    return site_at(config.simulation.site)
