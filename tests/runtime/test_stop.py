"""The stop flag: signals set it instead of raising, and one held back (blocked) is handled once installed."""

from __future__ import annotations

import signal
import threading

from zenslam.runtime.stop import STOP_SIGNALS, StopFlag


def test_a_signal_blocked_before_install_sets_the_flag_once_installed():
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    stop = StopFlag()
    try:
        # Sent to this thread (a test runner may have others that do not block it): pending, as in a
        # stage still importing.
        signal.pthread_kill(threading.get_ident(), signal.SIGINT)
        assert signal.SIGINT in signal.sigpending() and not stop()
        stop.install()  # unblocks: the pending signal reaches the flag's handler, not KeyboardInterrupt
        assert stop() and stop.signals == 1
        signal.pthread_kill(threading.get_ident(), signal.SIGTERM)
        assert stop.signals == 2
    finally:
        stop.uninstall()
        signal.pthread_sigmask(signal.SIG_SETMASK, previous - set(STOP_SIGNALS))


def test_uninstall_restores_the_previous_handlers():
    before = signal.getsignal(signal.SIGINT)
    stop = StopFlag().install()
    assert signal.getsignal(signal.SIGINT) != before
    stop.uninstall()
    assert signal.getsignal(signal.SIGINT) == before

