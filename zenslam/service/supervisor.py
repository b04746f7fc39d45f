"""Starting and supervising a run's processes, and the command line every stage process accepts.

The supervisor starts each stage as ``python -m <module>`` in its own process group (so a Ctrl-C
in the terminal reaches only the supervisor, which then stops the stages in order), with its
output in ``<run>/logs/<stage>.log``. Each child gets the shared session name, the run's resolved
config file, the hub endpoint to connect to and the supervisor's pid: a child whose parent is gone
stops by itself, so no process outlives its run.
"""

from __future__ import annotations

import argparse
import atexit
import dataclasses
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from types import FrameType

import zenoh

from zenslam.errors import ProcessError, ZenslamError
from zenslam.service import bus

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class ProcessSpec:
    """One stage process: ``python -m module`` with the common arguments plus ``args``."""

    name: str  # the stage name; also the name of its liveliness token
    module: str  # the module run with ``python -m``
    args: tuple[str, ...] = ()


# glibc malloc settings for the stage processes (bytes): no mmap below 32 MiB, return freed heap
# memory to the system once 16 MiB of it sits unused at the top (a dozen camera frames' churn).
MALLOC_TUNABLES = "glibc.malloc.mmap_threshold=33554432:glibc.malloc.trim_threshold=16777216"


@dataclass
class _Child:
    spec: ProcessSpec
    popen: subprocess.Popen
    log_path: Path


class Supervisor:
    """Starts stage processes and keeps them accountable; use as a context manager (stops all on exit)."""

    def __init__(self, run_dir: Path, session_name: str, config_path: Path, hub_endpoint: str | None, env: dict[str, str] | None = None):
        self.run_dir = Path(run_dir)
        self.session_name = session_name
        self.config_path = Path(config_path)
        self.hub_endpoint = hub_endpoint
        self.env = dict(os.environ if env is None else env)
        # Stages run their own threads where it pays (ORB on left/right); library thread pools on a
        # 2-core machine stalled small BLAS products for 10-60 ms under load, and single-threaded
        # numerics keep lockstep runs deterministic. Must be set before numpy loads: hence the env.
        for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            self.env.setdefault(var, "1")
        # glibc serves blocks above 128 KiB (a 1 MB camera frame, a BA window's arrays) with fresh
        # mmaps that it unmaps on free, so every frame faults its pages in again. Keeping them in
        # the heap cut the stages' system CPU on the KITTI clip (lockstep) from 1.41 s to 0.64 s,
        # for at most trim_threshold of memory held per process.
        self.env.setdefault("GLIBC_TUNABLES", MALLOC_TUNABLES)
        self._children: dict[str, _Child] = {}

    def __enter__(self) -> Supervisor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self, spec: ProcessSpec) -> None:
        """Start ``spec`` in its own process group, its output going to ``logs/<name>.log``."""
        if spec.name in self._children:
            raise ProcessError(f"a process named {spec.name!r} is already running in this run")
        log_dir = self.run_dir / "logs"
        log_dir.mkdir(parents=True, exist_ok=True)
        log_path = log_dir / f"{spec.name}.log"
        command = [sys.executable, "-m", spec.module, *self.common_args(), *spec.args]
        logger.debug("starting %s: %s", spec.name, " ".join(command))
        with open(log_path, "wb") as log:
            try:
                popen = subprocess.Popen(
                    command, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=self.env, process_group=0
                )
            except OSError as exc:
                raise ProcessError(f"cannot start {spec.name} ({' '.join(command)}): {exc}") from exc
        self._children[spec.name] = _Child(spec, popen, log_path)

    def common_args(self) -> list[str]:
        """The arguments every stage gets (see ``add_process_arguments``)."""
        args = ["--session", self.session_name, "--config", str(self.config_path), "--parent-pid", str(os.getpid())]
        if self.hub_endpoint:
            args += ["--connect", self.hub_endpoint]
        return args

    @property
    def names(self) -> list[str]:
        return list(self._children)

    def returncode(self, name: str) -> int | None:
        """The exit status of a child, None while it runs."""
        return self._children[name].popen.poll()

    def log_tail(self, name: str, lines: int = 25) -> str:
        """The last ``lines`` lines of a child's output."""
        path = self._children[name].log_path
        try:
            text = path.read_text(errors="replace")
        except OSError:
            return f"(no output: {path} unreadable)"
        return "\n".join(text.splitlines()[-lines:])

    def check(self) -> None:
        """Raise ProcessError naming the first child that exited with a failure, with its output's tail."""
        for name, child in self._children.items():
            code = child.popen.poll()
            if code not in (None, 0):
                raise ProcessError(
                    f"process {name} exited with status {code}; the end of {child.log_path}:\n{self.log_tail(name)}"
                )

    def all_running(self) -> bool:
        return all(child.popen.poll() is None for child in self._children.values())

    def wait_until_alive(
        self, session: zenoh.Session, names: list[str], timeout_s: float, keep_waiting: Callable[[], bool] = lambda: True
    ) -> None:
        """Wait for the named children's liveliness tokens; raise if one dies or the time runs out.

        Returns early, without raising, when ``keep_waiting()`` turns false (e.g. on Ctrl-C).
        """
        missing = bus.wait_for_alive(
            session, self.session_name, names, timeout_s, keep_waiting=lambda: self.all_running() and keep_waiting()
        )
        self.check()
        if missing and keep_waiting():
            raise ProcessError(
                f"process(es) {sorted(missing)} did not come up within {timeout_s:.0f} s; see {self.run_dir / 'logs'}"
            )

    def wait_exit(self, timeout_s: float) -> dict[str, int | None]:
        """Wait up to ``timeout_s`` seconds for every child to exit by itself; returns their statuses."""
        deadline = time.monotonic() + timeout_s
        for child in self._children.values():
            try:
                child.popen.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
        return {name: child.popen.poll() for name, child in self._children.items()}

    def request_stop(self, names: Iterable[str] | None = None) -> None:
        """Send SIGINT to the named running children (all when None) without waiting; they end their
        streams and exit."""
        chosen = set(self._children if names is None else names)
        for name, child in self._children.items():
            if name in chosen and child.popen.poll() is None:
                try:
                    os.killpg(child.popen.pid, signal.SIGINT)
                except ProcessLookupError:
                    pass

    def stop(self, grace_s: float = 10.0, term_s: float = 3.0) -> None:
        """Stop every running child's process group: SIGINT (the stage ends its streams and closes its
        session), after ``grace_s`` seconds SIGTERM, after ``term_s`` more SIGKILL."""
        for signum, wait_s in ((signal.SIGINT, grace_s), (signal.SIGTERM, term_s), (signal.SIGKILL, 3.0)):
            running = [c for c in self._children.values() if c.popen.poll() is None]
            if not running:
                return
            for child in running:
                logger.debug("sending %s to %s", signal.Signals(signum).name, child.spec.name)
                try:
                    os.killpg(child.popen.pid, signum)
                except ProcessLookupError:
                    pass
            deadline = time.monotonic() + wait_s
            for child in running:
                try:
                    child.popen.wait(max(0.0, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    logger.warning("%s did not exit within %.0f s of %s", child.spec.name, wait_s, signal.Signals(signum).name)


# ---- the child's side: the command line the supervisor passes, and stopping on request ----


def add_process_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments every stage process takes (what ``Supervisor.common_args`` passes)."""
    parser.add_argument("--session", required=True, help="the run's session name: keys are zenslam/<session>/...")
    parser.add_argument("--config", type=Path, default=None, help="the run's YAML configuration (default: all defaults)")
    parser.add_argument(
        "--connect", action="append", default=[], metavar="ENDPOINT",
        help="zenoh endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable; added to bus.connect)",
    )
    parser.add_argument("--parent-pid", type=int, default=None, help="stop when this process is no longer our parent")
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")


def bus_config_with(config: bus.BusConfig, connect: list[str]) -> bus.BusConfig:
    """``config`` with extra endpoints to connect to."""
    if not connect:
        return config
    return dataclasses.replace(config, connect=tuple(config.connect) + tuple(connect))


class StopFlag:
    """Set by SIGINT/SIGTERM or by losing the parent process; stage loops poll it between steps."""

    def __init__(self, parent_pid: int | None = None):
        self._event = threading.Event()
        self._parent_pid = parent_pid
        self._previous: dict[int, object] = {}

    def install(self) -> StopFlag:
        """Handle SIGINT and SIGTERM by setting the flag (main thread only); ``uninstall`` restores."""
        for signum in (signal.SIGINT, signal.SIGTERM):
            self._previous[signum] = signal.signal(signum, self._on_signal)
        return self

    def uninstall(self) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        logger.info("received %s: stopping after the current step", signal.Signals(signum).name)
        self._event.set()

    def set(self) -> None:
        self._event.set()

    def __call__(self) -> bool:
        """True when the process should stop."""
        if not self._event.is_set() and not bus.parent_alive(self._parent_pid):
            logger.warning("parent process %s is gone: stopping", self._parent_pid)
            self._event.set()
        return self._event.is_set()

    def keep_going(self) -> bool:
        return not self()


def setup_process_logging(verbose: bool, stage: str) -> None:
    """Logging for a stage process's entry point (the only place besides the CLI that configures it)."""
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.INFO, format=f"%(asctime)s {stage} %(levelname)s %(name)s: %(message)s"
    )
    bus.quiet_zenoh_logs()
    atexit.register(log_cpu_times)  # runs before logging's own atexit shutdown (registered earlier)


def log_cpu_times(when: str = "at exit") -> None:
    """Log the process's CPU time so far (all its threads, zenoh's included) as
    ``cpu <when>: user U s system S s``; stages log it when their stream starts and at exit."""
    times = os.times()
    logger.info("cpu %s: user %.3f s system %.3f s", when, times.user, times.system)
