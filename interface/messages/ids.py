"""Ids of commands, boots and scene streams: random, or repeatable from a seed (lockstep)."""

from __future__ import annotations

import secrets
from collections.abc import Callable, Sequence

import numpy as np


def new_id() -> int:
    """An id that no other of its kind has (a command, a station's boot, a scene stream): 53
    random bits (the ids' range). Ids from the clock (milliseconds) collided when two tools
    sent in the same one."""
    return _ids[0]()


def _random_id() -> int:
    return secrets.randbelow(2**53 - 1) + 1


_ids: list[Callable[[], int]] = [_random_id]


def repeatable_ids(seed: Sequence[int]) -> None:
    """This process's ids from a stream of `seed` from now on (lockstep: a run repeats, its ids
    too; the seed holds the station and its boot, so that a restart still differs)."""
    rng = np.random.default_rng(list(seed))
    _ids[0] = lambda: int(rng.integers(1, 2**53))
