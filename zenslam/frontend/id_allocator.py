"""Ids handed out in order from one id space (a start and a step), so that stages creating
points or keyframes never collide."""

from __future__ import annotations

import numpy as np


class IdAllocator:
    """Hands out int ids start, start + step, start + 2 step, ... in order."""

    def __init__(self, start: int, step: int = 1) -> None:
        if step <= 0:
            raise ValueError(f"id step must be positive, got {step}")
        self._next = int(start)
        self._step = int(step)

    def next(self) -> int:
        """One new id."""
        value = self._next
        self._next += self._step
        return value

    def take(self, n: int) -> np.ndarray:
        """``n`` new ids as an (n,) int64 array."""
        ids = self._next + self._step * np.arange(n, dtype=np.int64)
        self._next += self._step * n
        return ids
