"""The shipped packages (`robots/`: description.robot; `sites/`: description.site) and what holds for any
world composed of them: which camera sets feed stereo. What a robot names
(its joints, thrusters, cameras, sensors) is its package's, and the panel is its site's; nothing
here names a part of either."""

from __future__ import annotations

from pathlib import Path

MODELS_DIR = Path(__file__).parent
PACKAGE_FILES = {"robot": "robot.toml", "site": "site.toml"}  # a package's kind -> the file it holds


def package_dir(kind: str, value: str) -> Path:
    """Where `simulation.robot` or `simulation.site` (`kind`) points: the name of a package the
    testbed ships (`robots/<name>`, `sites/<name>`, e.g. "bluerov2_heavy_alpha5"), else a
    directory's path as given (relative to the current directory); "" is the shipped default's
    name for neither, so it is the caller's to handle."""
    shipped = MODELS_DIR / f"{kind}s" / value
    if value and "/" not in value and (shipped / PACKAGE_FILES[kind]).is_file():
        return shipped
    return Path(value).expanduser()


def shipped_names(kind: str) -> tuple[str, ...]:
    """The names of the `kind` ("robot", "site") packages the testbed ships."""
    return tuple(
        sorted(d.name for d in (MODELS_DIR / f"{kind}s").iterdir() if (d / PACKAGE_FILES[kind]).is_file())
    )


def stereo_set(sim_time_s: float, camera_rate_hz: float, stereo_every: int) -> bool:
    """Whether the frame set taken at `sim_time_s` [s] is one the stereo matcher uses: every
    `stereo_every`-th by the set's index on the simulated clock (sets at `camera_rate_hz`, the
    index `round(t * rate)`, so a set taken a little early or late keeps its index), from the set
    at index 1, the first onboard can place (at 0 s it has no navigation estimate yet). The
    simulation renders the stereo pair's right camera for these sets alone, and onboard waits for
    it on these alone."""
    return round(sim_time_s * camera_rate_hz) % stereo_every == 1 % stereo_every
