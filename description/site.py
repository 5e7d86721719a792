"""The work site as data: a package (a directory) holding `site.toml` and the MJCF it names (the
water, the light, the seabed), with the panel and its parts described in site.toml and built into
the world from there (description/models/panel.py), and a partial configuration (`[config]`: where the
vehicle starts, the default mission) layered under the user's (config).

A world is composed of a robot package and a site (`world_spec`): the site's MJCF, the robot's base
body attached to it first (so the vehicle's free joint leads qpos, whatever the site), then the
site's own bodies, then the panel. `site_of(config)` is the one way a station gets the site it
runs (`simulation.site`; "" the shipped one), loaded once per package."""

from __future__ import annotations

import contextlib
import functools
import tomllib
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from abyss.common.errors import ConfigError
from abyss.common.reading import read_table
from abyss.description.models import package_dir
from abyss.description.models.panel import Panel

if TYPE_CHECKING:
    import mujoco

    from abyss.description.robot import Robot

SITES_DIR = Path(__file__).parent / "models" / "sites"
SHIPPED_SITE_DIR = SITES_DIR / "valve_panel"
SITE_FILE_NAME = "site.toml"
_PREFIX_WARNING = "Attaching a spec with an empty prefix"


@dataclass(frozen=True)
class SiteModelSection:
    file: str  # the site's MJCF, relative to the package: options, lights, the seabed
    seabed_cloud: str = ""  # the point cloud its terrain was built from (`abyss terrain build`)
    terrain: str = "terrain"  # the height field the terrain is written into


@dataclass(frozen=True)
class SiteDatum:
    """Where the site's world frame sits on the Earth, for what speaks in geodetic coordinates (a
    MAVLink ground station: GLOBAL_POSITION_INT, mission items): its origin (WGS-84 latitude and
    longitude [deg], the height of the sea's surface above mean sea level [m]) and the bearing of
    its x axis from true north, clockwise [deg] (90: x east, y north)."""

    latitude_deg: float = 0.0
    longitude_deg: float = 0.0
    surface_amsl_m: float = 0.0
    x_bearing_deg: float = 90.0

    def __post_init__(self) -> None:
        if not -89.0 <= self.latitude_deg <= 89.0:
            raise ConfigError("datum.latitude_deg", f"{self.latitude_deg}: -89 to 89 (flat near the origin)")
        if not -180.0 <= self.longitude_deg <= 180.0:
            raise ConfigError("datum.longitude_deg", f"{self.longitude_deg}: -180 to 180")
        if not 0.0 <= self.x_bearing_deg < 360.0:
            raise ConfigError("datum.x_bearing_deg", f"{self.x_bearing_deg}: 0 to 360")


@dataclass(frozen=True)
class SiteFile:
    name: str
    source: str
    model: SiteModelSection
    panel: Panel
    datum: SiteDatum = field(default_factory=SiteDatum)
    config: dict[str, Any] = field(default_factory=dict)  # a partial configuration, under the user's


@dataclass(frozen=True)
class Site:
    directory: Path
    spec: SiteFile

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def file(self) -> Path:
        return self.directory / SITE_FILE_NAME

    @property
    def model_file(self) -> Path:
        return self.directory / self.spec.model.file

    @property
    def panel(self) -> Panel:
        return self.spec.panel

    @property
    def face_texture_file(self) -> Path:
        return self.directory / self.spec.panel.face_texture

    @property
    def seabed_cloud_file(self) -> Path | None:
        return self.directory / self.spec.model.seabed_cloud if self.spec.model.seabed_cloud else None

    @property
    def shipped(self) -> bool:
        return self.directory == SHIPPED_SITE_DIR.resolve()


def site_at(package: str) -> Site:
    """The site package at `package` (a directory's path, or a shipped package's name; "" the
    shipped default), loaded once."""
    return load_site(package_dir("site", package) if package else SHIPPED_SITE_DIR)


def shipped_sites() -> tuple[Site, ...]:
    """The sites the testbed ships (description/models/sites), the default first."""
    others = sorted(
        d for d in SITES_DIR.iterdir() if (d / SITE_FILE_NAME).is_file() and d != SHIPPED_SITE_DIR
    )
    return tuple(load_site(d) for d in (SHIPPED_SITE_DIR, *others))


def load_site(directory: Path) -> Site:
    """The site package in `directory`; ConfigError naming the file and the field for a bad one
    (a site MJCF that does not compile, a panel whose parts are named twice or clash with the
    site's names). Cached per package (its resolved path)."""
    return _load(Path(directory).expanduser().resolve())


@functools.cache
def _load(directory: Path) -> Site:
    path = directory / SITE_FILE_NAME
    try:
        table = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError("simulation.site", f"cannot read {path}: {exc}") from None
    try:
        site = Site(directory, read_table(SiteFile, table))
    except ConfigError as exc:
        raise ConfigError(exc.field, exc.reason, str(path)) from None
    names = site.panel.part_names
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ConfigError("panel.parts", f"named twice: {', '.join(twice)}", str(path))
    for field_name, file in (("model.file", site.model_file), ("panel.face_texture", site.face_texture_file)):
        if not file.is_file():
            raise ConfigError(field_name, f"no such file: {file}", str(path))
    try:
        _site_spec(site).compile()
    except ValueError as exc:
        raise ConfigError(
            "model.file", f"the site with its panel does not compile: {exc}", str(path)
        ) from None
    return site


def _site_spec(site: Site) -> mujoco.MjSpec:
    import mujoco

    try:
        spec = mujoco.MjSpec.from_file(str(site.model_file))
    except ValueError as exc:
        raise ConfigError("model.file", f"{site.model_file} does not parse: {exc}", str(site.file)) from None
    site.panel.build(spec, site.face_texture_file)
    return spec


@contextlib.contextmanager
def _names_kept() -> Iterator[None]:
    """MuJoCo's warning that names attached without a prefix may not save, silenced: a world is
    composed with every name as its package has it, and never saved."""
    import mujoco

    before = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(
        lambda text: None if text.startswith(_PREFIX_WARNING) else warnings.warn(text, stacklevel=1)
    )
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", _PREFIX_WARNING)
            yield
    finally:
        mujoco.set_mju_user_warning(before)


def world_spec(robot: Robot, site: Site) -> mujoco.MjSpec:
    """The world MuJoCo compiles to fly `robot` at `site`: the site's MJCF with the robot's base
    body attached first, then the site's bodies and the panel (names must not clash: MuJoCo's
    compiler names a clash)."""
    from abyss.description.robot import robot_spec

    world = _site_spec(site)
    site_bodies = world.copy()  # the site's own bodies, attached again after the robot's
    tops = [body.name for body in world.worldbody.bodies]
    for name in tops:
        world.delete(world.body(name))
    if tops:  # attaching them brings their assets back, once
        for asset in (*world.textures, *world.materials, *world.hfields, *world.meshes):
            world.delete(asset)
    with _names_kept():
        world.worldbody.add_frame().attach_body(robot_spec(robot).body(robot.base), "", "")
        for name in tops:
            world.worldbody.add_frame().attach_body(site_bodies.body(name), "", "")
    return world


def world_model(robot: Robot, site: Site) -> mujoco.MjModel:
    """The compiled world (`world_spec`); ConfigError naming both packages where it does not compile."""
    try:
        with _names_kept():
            return world_spec(robot, site).compile()
    except ValueError as exc:
        raise ConfigError(
            "simulation.site", f"{site.directory} with the robot {robot.directory} does not compile: {exc}"
        ) from None
