"""Stopping a process on SIGINT/SIGTERM: a flag its loops poll between steps, instead of KeyboardInterrupt.

Standard library only: the ``zenslam`` command installs it before importing anything heavy, so a
Ctrl-C during those seconds of imports is held for the command to handle rather than raised in
the middle of an import.
"""

from __future__ import annotations

import logging
import os
import signal
import threading
from types import FrameType

logger = logging.getLogger(__name__)

# The signals that stop a stage. The supervisor starts every stage with them blocked, so one that
# arrives while the stage still imports its modules waits, pending, until ``StopFlag.install``
# unblocks it: it sets the flag then, rather than raising KeyboardInterrupt in an import.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)

# The exit status of a process stopped by Ctrl-C (128 + SIGINT, as shells report it).
EXIT_INTERRUPTED = 130
# The exit status of a run that failed (a bad input, a stage that died); its outputs are still written.
EXIT_FAILED = 2

# The detail of a stage's last "finished" status when it ended before its input's end of stream
# (stopped by a signal, by losing its parent, or by the stage it depends on ending first).
STOPPED = "stopped"


class StopFlag:
    """Set by SIGINT/SIGTERM or by losing the parent process; stage loops poll it between steps.

    ``signals`` counts the signals received (a second Ctrl-C may mean "stop at once"). ``quiet``
    logs their arrival at debug level only, for a command that reports the interruption itself.
    """

    def __init__(self, parent_pid: int | None = None, quiet: bool = False):
        self._event = threading.Event()
        self._parent_pid = parent_pid
        self._quiet = quiet
        self._previous: dict[int, object] = {}
        self.signals = 0

    def install(self) -> StopFlag:
        """Handle SIGINT and SIGTERM by setting the flag (main thread only), then unblock them (a
        signal held back since the process started is handled now); ``uninstall`` restores the handlers."""
        for signum in STOP_SIGNALS:
            self._previous[signum] = signal.signal(signum, self._on_signal)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
        return self

    def uninstall(self) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        self.signals += 1
        level = logging.DEBUG if self._quiet else logging.INFO
        logger.log(level, "received %s: stopping after the current step", signal.Signals(signum).name)
        self._event.set()

    def set(self) -> None:
        self._event.set()

    def __call__(self) -> bool:
        """True when the process should stop."""
        if not self._event.is_set() and self._parent_pid is not None and os.getppid() != self._parent_pid:
            logger.warning("parent process %s is gone: stopping", self._parent_pid)
            self._event.set()
        return self._event.is_set()

    def keep_going(self) -> bool:
        return not self()
