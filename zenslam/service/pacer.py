"""Playing frames at their recorded times: the source process in live mode and ``zenslam publish``."""

from __future__ import annotations

import time
from collections.abc import Callable


class Pacer:
    """Sleeps until each frame's recorded time, scaled by ``rate`` (0: never sleeps).

    ``clock`` (seconds, monotonic) and ``sleep`` are the time module's unless a test plays on a fake clock.
    """

    def __init__(
        self,
        rate: float,
        should_stop: Callable[[], bool],
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ):
        self._rate = rate
        self._should_stop = should_stop
        self._clock = clock
        self._sleep = sleep
        self._origin: tuple[float, int] | None = None  # (clock s, stamp ns) of the first frame

    def wait_for(self, stamp_ns: int) -> None:
        if self._rate == 0:
            return
        if self._origin is None:
            self._origin = (self._clock(), stamp_ns)
            return
        due = self._origin[0] + (stamp_ns - self._origin[1]) * 1e-9 / self._rate
        while not self._should_stop():
            remaining = due - self._clock()
            if remaining <= 0:
                return
            self._sleep(min(remaining, 0.05))
