"""The last N values of a measurement, and their percentiles."""

from __future__ import annotations

from collections import deque

import numpy as np


class Samples:
    def __init__(self, maxlen: int = 4096) -> None:
        self._values: deque[float] = deque(maxlen=maxlen)

    def add(self, value: float) -> None:
        self._values.append(value)

    def __len__(self) -> int:
        return len(self._values)

    def percentiles(
        self, prefix: str, scale: float = 1.0, unit: str = "", qs: tuple[int, ...] = (50, 95, 99)
    ) -> dict[str, float]:
        """`{prefix}_p50_{unit}` ... of the values times `scale`; empty when there are none."""
        if not self._values:
            return {}
        values = np.percentile(np.fromiter(self._values, float), qs) * scale
        suffix = f"_{unit}" if unit else ""
        return {f"{prefix}_p{q}{suffix}": float(v) for q, v in zip(qs, values, strict=True)}
