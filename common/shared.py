"""State that one thread of a station writes and others read: one small locked type instead of
one-element lists passed between threads."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Generic, TypeVar

T = TypeVar("T")


class Latest(Generic[T]):
    """The latest value of something, set by one thread and read by others; `get()` returns
    what the last `set()` stored (or the initial value), never a torn update."""

    def __init__(self, initial: T) -> None:
        self._lock = threading.Lock()
        self._value = initial

    def set(self, value: T) -> None:
        with self._lock:
            self._value = value

    def get(self) -> T:
        with self._lock:
            return self._value

    def update(self, value: T, keep: Callable[[T, T], T]) -> T:
        """Store `keep(old, value)` atomically (for example `max` for a clock that never goes
        back) and return it."""
        with self._lock:
            self._value = keep(self._value, value)
            return self._value
