from __future__ import annotations

import math

from abyss.linkemu.stages.base import Packet, Stage

_PARETO_SHAPE = 3.0
# A Pareto (type I) variable with shape 3 and scale 1 has mean 1.5 and std sqrt(3)/2.
_PARETO_MEAN, _PARETO_STD = 1.5, math.sqrt(3.0) / 2.0


class Delay(Stage):
    """Propagation after serialisation: delay + jitter * z, z drawn from the distribution
    with zero mean and unit standard deviation (netem's `delay D J distribution X`).

    Unlike netem, jitter never reorders: a packet leaves no earlier than the one before it,
    as on a real link. `reorder` sends that share of packets with no delay, so they overtake
    (netem's `reorder`). `correlation` makes z an AR(1) series with the same variance."""

    _z = 0.0
    _last_s = 0.0

    def _standard(self) -> float:
        kind = self.profile.distribution
        if kind == "normal":
            return float(self.rng.standard_normal())
        if kind == "uniform":  # half-width = jitter, as netem's uniform
            return float(self.rng.uniform(-1.0, 1.0))
        pareto = ((1.0 - self.rng.random()) ** (-1.0 / _PARETO_SHAPE) - _PARETO_MEAN) / _PARETO_STD
        if kind == "pareto":
            return float(pareto)
        # paretonormal: netem's table is 1/4 normal + 3/4 pareto; rescaled to unit variance.
        return float((0.25 * self.rng.standard_normal() + 0.75 * pareto) / math.sqrt(0.625))

    def process(self, packet: Packet) -> list[Packet]:
        p = self.profile
        if p.reorder > 0.0 and self.rng.random() < p.reorder:
            return [packet]
        if p.jitter_s > 0.0:
            rho = p.correlation
            self._z = rho * self._z + math.sqrt(1.0 - rho * rho) * self._standard()
            delay_s = max(0.0, p.delay_s + p.jitter_s * self._z)
        else:
            delay_s = p.delay_s
        packet.t_s = max(packet.t_s + delay_s, self._last_s)
        self._last_s = packet.t_s
        return [packet]
