"""MAVLink's parameter protocol on the vehicle's parameters (ardusub.PARAMS): the list, a read by
name or index, a set within the parameter's range (out of it: refused, said, the value kept)."""

from __future__ import annotations

from collections.abc import Mapping

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from abyss.mavlink.ardusub import PARAMS, Param

Say = list[mavlink.MAVLink_message]


class Params:
    def __init__(self, overrides: Mapping[str, float]) -> None:
        """ArduSub's defaults, with `overrides` (the configuration's system ids, the robot's frame)."""
        self.table: dict[str, Param] = {p.name: p for p in PARAMS}
        self.values: dict[str, float] = {p.name: float(overrides.get(p.name, p.default)) for p in PARAMS}
        self.names = [p.name for p in PARAMS]

    def __getitem__(self, name: str) -> float:
        return self.values[name]

    def _value(self, name: str) -> mavlink.MAVLink_param_value_message:
        return mavlink.MAVLink_param_value_message(
            name.encode(), self.values[name], self.table[name].type, len(self.names), self.names.index(name)
        )

    def handle(self, msg: mavlink.MAVLink_message) -> tuple[Say, str]:
        """The answer to a parameter message, and a text to say ("" none)."""
        kind = msg.get_type()
        if kind == "PARAM_REQUEST_LIST":
            return [self._value(name) for name in self.names], ""
        if kind == "PARAM_REQUEST_READ":
            name = msg.param_id if msg.param_index < 0 else None
            if name is None and 0 <= msg.param_index < len(self.names):
                name = self.names[msg.param_index]
            return ([self._value(name)], "") if name in self.values else ([], "")
        if kind == "PARAM_SET":
            name = msg.param_id
            param = self.table.get(name)
            if param is None:  # ArduPilot stays silent on a name it does not have
                return [], ""
            value = float(msg.param_value)
            if not param.lo <= value <= param.hi:
                return [self._value(name)], f"{name}: {value:g} out of range {param.lo:g} to {param.hi:g}"
            self.values[name] = value
            return [self._value(name)], f"{name} takes effect at the next start" if param.reboot else ""
        return [], ""
