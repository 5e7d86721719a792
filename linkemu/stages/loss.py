from __future__ import annotations

from abyss.linkemu.stages.base import Packet, Stage


class Loss(Stage):
    """Bernoulli loss, or Gilbert-Elliott bursts as netem's `loss gemodel p r 1-h 1-k`:
    a two-state chain stepped once per packet, each state with its own loss probability."""

    drops = "losses"
    bad = False

    def process(self, packet: Packet) -> list[Packet]:
        p = self.profile
        if p.loss_model == "bernoulli":
            lost = p.loss > 0.0 and self.rng.random() < p.loss
        else:
            self.bad = (self.rng.random() >= p.ge_r) if self.bad else (self.rng.random() < p.ge_p)
            lost = self.rng.random() < (p.ge_loss_bad if self.bad else p.ge_loss_good)
        return [] if lost else [packet]
