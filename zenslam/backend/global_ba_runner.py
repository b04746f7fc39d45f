"""When global bundle adjustment runs after a loop, and where: in the backend's own thread, or in a helper process.

ORB-SLAM runs global BA in a thread of its own after each loop, restarting it when another loop
arrives, and merges its result into the map that local mapping kept changing meanwhile. Here the
problem is built from copies of the map's arrays on the backend's worker (the map's owner), then
solved either

- in place (lockstep): the result is applied before the keyframe's answer and correction are
  published, so it lands at the same point of the stream on every run; or
- in a helper process (pipelined, live): gtsam holds the GIL for a whole optimisation, so a
  thread would stall local mapping for its duration; a process does not. The worker polls for the
  result between keyframes and applies it there (``apply_global_ba`` carries keyframes and points
  added meanwhile along with their reference keyframes).

A new loop while one runs makes the running one stale: its result is dropped and a new one starts
from the map as the new loop left it.
"""

from __future__ import annotations

import logging
import multiprocessing
from concurrent.futures import CancelledError, Future, ProcessPoolExecutor

from zenslam.backend.ba_problem import BAResult
from zenslam.backend.global_ba import GlobalBAConfig, GlobalBAProblem, apply_global_ba, global_ba_problem, run_global_ba
from zenslam.backend.local_mapping import BAWindowConfig
from zenslam.backend.map import BackendMap

logger = logging.getLogger(__name__)


class GlobalBARunner:
    """One global BA at a time over the map lent by the backend node."""

    def __init__(self, bmap: BackendMap, config: GlobalBAConfig, window: BAWindowConfig, in_background: bool) -> None:
        self.map = bmap
        self.config = config
        self.window = window
        self.in_background = in_background
        self.runs = 0  # global BAs started
        self.applied = 0  # global BAs whose result reached the map
        self._pool: ProcessPoolExecutor | None = None
        self._running: tuple[GlobalBAProblem, Future[BAResult]] | None = None

    @property
    def running(self) -> bool:
        return self._running is not None

    def start(self) -> bool:
        """Start a global BA on the map as it is now (dropping a running one); in place it is also
        applied before this returns. Returns whether the map changed already (in place)."""
        problem = global_ba_problem(self.map, self.window)
        if problem is None:
            return False
        self.runs += 1
        if not self.in_background:
            self._apply(problem, run_global_ba(problem, self.config))
            return True
        if self._running is not None:
            logger.info("a new loop: the running global BA's result will be dropped")
            self._running[1].cancel()
        self._running = (problem, self._executor().submit(run_global_ba, problem, self.config))
        return False

    def run_in_place(self) -> bool:
        """A global BA on the map as it is now, solved in this process and applied before this
        returns (a running background one is dropped: this one starts from a later map). True when
        the map changed."""
        if self._running is not None:
            self._running[1].cancel()
            self._running = None
        problem = global_ba_problem(self.map, self.window)
        if problem is None:
            return False
        self.runs += 1
        self._apply(problem, run_global_ba(problem, self.config))
        return True

    def poll(self) -> bool:
        """Apply a finished background global BA to the map; True when the map changed."""
        if self._running is None or not self._running[1].done():
            return False
        problem, future = self._running
        self._running = None
        if future.cancelled():
            return False
        self._apply(problem, future.result())
        return True

    def wait(self) -> bool:
        """Wait for a running background global BA and apply it (the map is about to be saved); True
        when the map changed."""
        if self._running is None:
            return False
        try:
            self._running[1].exception()  # blocks until it is done; its error, if any, is raised by poll
        except CancelledError:
            pass
        return self.poll()

    def close(self) -> None:
        """Stop the helper process (a running global BA is abandoned)."""
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None

    def _apply(self, problem: GlobalBAProblem, result: BAResult) -> None:
        counts = apply_global_ba(self.map, problem, result)
        self.map.refresh_points()
        self.applied += 1
        logger.info("global BA applied: %s", counts)

    def _executor(self) -> ProcessPoolExecutor:
        if self._pool is None:
            # spawn: the backend runs zenoh's threads, which a forked child must not inherit; the
            # child inherits the environment, so the same math kernels are pinned in it.
            self._pool = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn"))
        return self._pool
