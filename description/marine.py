"""The vehicle's marine model as data, typed once from robot.toml's marine sections (`[added_mass]`,
`[damping]`, `[buoyancy]`, `[thrusters]`) when the robot package loads (description/robot.py:
`Robot.marine`): what the simulation's Fossen terms (stations/simulation/hydrodynamics.py), its
thrusters, the derived gains and `abyss robot check` all read. The coefficients are about the
body's origin, in its frame; docs/vehicle.md lists the fields with their units. A missing or bad
field raises ConfigError naming robot.toml and the field."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from abyss.common.errors import ConfigError
from abyss.description.robot_file import RobotFile, ThrustersSection


@dataclass(frozen=True)
class VehicleModel:
    name: str
    source: str
    added_mass: np.ndarray  # M_A (6, 6) [kg, kg m, kg m^2], body frame about the origin
    linear_damping: np.ndarray  # (6,) [N s/m, N m s/rad]
    quadratic_damping: np.ndarray  # (6,) [N s^2/m^2, N m s^2/rad^2]
    volume_m3: float  # displaced [m^3]
    centre_of_buoyancy_m_body: np.ndarray  # (3,) [m]
    thrusters: ThrustersSection


# the marine sections' fields: each with what it holds; docs/vehicle.md lists them with their units
MARINE_FIELDS = {
    "added_mass": {
        "diagonal": "6 numbers [kg, kg, kg, kg m^2, kg m^2, kg m^2]",
        "matrix": "36 numbers, row by row, M_A about the body origin",
    },
    "damping": {
        "linear": "6 numbers [N s/m, N m s/rad]",
        "quadratic": "6 numbers [N s^2/m^2, N m s^2/rad^2]",
    },
    "buoyancy": {"volume_m3": "the displaced volume [m^3]", "centre_m_body": "3 numbers [m, body]"},
    "thrusters": {
        "names": "the model's thruster sites and motors, in allocation order",
        "time_constant_s": "the rotor's first-order lag [s]",
        "deadband": "the command share [0, 0.5) below which the rotor does not turn",
        "forward_max_n": "the thrust at full command ahead [N]",
        "reverse_max_n": "the thrust at full command astern [N]",
    },
}


def marine_model(spec: RobotFile, path: Path) -> VehicleModel:
    """The marine model of robot.toml's typed sections (`spec`, read from `path`)."""
    sections = {"added_mass": spec.added_mass, "damping": spec.damping, "buoyancy": spec.buoyancy}
    for section, table in sections.items():
        allowed = MARINE_FIELDS[section]
        for key in table:
            if key not in allowed:
                shown = "; ".join(f"{name} ({what})" for name, what in allowed.items())
                raise ConfigError(f"{section}.{key}", f"not a field of [{section}]: {shown}", str(path))
    if len({"diagonal", "matrix"} & set(spec.added_mass)) != 1:
        raise ConfigError(
            "added_mass", "needs one of diagonal (6 numbers) or matrix (36, row by row)", str(path)
        )

    def numbers(section: str, key: str, sizes: tuple[int, ...], non_negative: bool) -> np.ndarray:
        value = sections[section].get(key)
        if value is None:
            raise ConfigError(f"{section}.{key}", "missing", str(path))
        array = np.asarray(value, dtype=float) if _is_numbers(value) else None
        if (
            array is None
            or array.size not in sizes
            or not np.all(np.isfinite(array))
            or (non_negative and np.any(array < 0))
        ):
            sign = "non-negative " if non_negative else ""
            raise ConfigError(
                f"{section}.{key}", f"needs {' or '.join(map(str, sizes))} {sign}numbers", str(path)
            )
        return array

    mass = (
        numbers("added_mass", "diagonal", (6, 36), True)
        if "diagonal" in spec.added_mass
        else numbers("added_mass", "matrix", (36,), False)
    )
    added_mass = np.diag(mass) if mass.size == 6 else mass.reshape(6, 6)
    if not np.allclose(added_mass, added_mass.T) or np.min(np.linalg.eigvalsh(added_mass)) <= 0:
        raise ConfigError("added_mass", "must be symmetric and positive definite", str(path))
    thrusters = spec.thrusters
    if not thrusters.names:
        raise ConfigError("thrusters.names", "needs a list of the model's thruster names", str(path))
    _positive(path, "thrusters.time_constant_s", thrusters.time_constant_s)
    _positive(path, "thrusters.deadband", thrusters.deadband, upper=0.5, zero=True)
    _positive(path, "thrusters.forward_max_n", thrusters.forward_max_n)
    _positive(path, "thrusters.reverse_max_n", thrusters.reverse_max_n)
    volume = sections["buoyancy"].get("volume_m3")
    if volume is None:
        raise ConfigError("buoyancy.volume_m3", "missing", str(path))
    return VehicleModel(
        name=spec.name,
        source=spec.source,
        added_mass=added_mass,
        linear_damping=numbers("damping", "linear", (6,), True),
        quadratic_damping=numbers("damping", "quadratic", (6,), True),
        volume_m3=_positive(path, "buoyancy.volume_m3", volume),
        centre_of_buoyancy_m_body=numbers("buoyancy", "centre_m_body", (3,), False),
        thrusters=thrusters,
    )


def _is_numbers(value: Any) -> bool:
    return isinstance(value, list) and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) for v in value
    )


def _positive(path: Path, where: str, value: Any, upper: float = float("inf"), zero: bool = False) -> float:
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not (0 <= value <= upper if zero else 0 < value <= upper)
    ):
        bound = f"[0, {upper}]" if zero else (f"(0, {upper}]" if upper < float("inf") else "> 0")
        raise ConfigError(where, f"{value!r}: needs a number {bound}", str(path))
    return float(value)
