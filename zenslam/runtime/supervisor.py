"""Starting and supervising a run's processes, and the command line every stage process accepts.

The supervisor starts each stage as ``python -P -m <module>`` in its own process group, with its
output in ``<run>/logs/<stage>.log``. A terminal's Ctrl-C signals the foreground process group, and
``kill -INT -<pgid>`` the group named: either way only the supervisor's own group, never a stage,
so the supervisor decides the order in which the stages stop. A stage starts with SIGINT and
SIGTERM blocked (the mask survives exec) until its ``StopFlag`` is installed, so a stop requested
while it still imports is held, not raised in the middle of an import. Each child gets the shared
session name, the run's resolved config file, the hub endpoint to connect to and the
supervisor's pid: a child whose parent is gone stops by itself, so no process outlives its run.
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path


from zenslam.errors import ConfigError, ProcessError
from zenslam.runtime import bus, cpu_kernels
from zenslam.runtime.stop import EXIT_FAILED, STOP_SIGNALS

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class SupervisionConfig:
    """How a run watches its stages (the ``supervision`` section)."""

    # Seconds without any message from a stage, while it has input waiting, before it counts as hung
    # (stopped, deadlocked) and is killed, then restarted or the run failed as for a crash; 0 never.
    # A stage that has not made progress yet since it (re)started gets bus.start_timeout_s at least.
    # A global BA sends nothing while it runs: keep this above the longest one.
    hang_timeout_s: float = 600.0
    # A stage that can recover what it held (the backend from its journal, the frontend by
    # relocalising, the source where tracking got to) and crashed (a signal, an exit status other
    # than 2) or hung is started again, at most this many times within restart_window_s seconds;
    # one more failure in that window fails the run with its outputs written. A stage that exits
    # with status 2 reported its own error (bad input, a bad setting): starting it again would meet
    # the same, so it fails the run at once. 0: no restarts, any failure fails the run.
    max_restarts: int = 3  # per stage
    restart_window_s: float = 600.0  # seconds

    def __post_init__(self) -> None:
        if not (self.hang_timeout_s >= 0 and self.hang_timeout_s != float("inf")):
            raise ConfigError(f"supervision.hang_timeout_s={self.hang_timeout_s} must be >= 0 seconds (0: never)")
        if self.max_restarts < 0:
            raise ConfigError(f"supervision.max_restarts={self.max_restarts} must be >= 0 (0: no restarts)")
        if not self.restart_window_s > 0:
            raise ConfigError(f"supervision.restart_window_s={self.restart_window_s} must be a positive number of seconds")


@dataclass(frozen=True)
class ProcessSpec:
    """One stage process: ``python -m module`` with the common arguments plus ``args``."""

    name: str  # the stage name; also the name of its liveliness token
    module: str  # the module run with ``python -m``
    args: tuple[str, ...] = ()
    # Whether the stage recovers its state when started again (``--restart N``), so that the
    # supervisor may restart it after a crash; a stage that cannot would rejoin the run empty.
    restartable: bool = False


# glibc malloc settings for the stage processes (bytes): no mmap below 32 MiB, return freed heap
# memory to the system once 16 MiB of it sits unused at the top (a dozen camera frames' churn).
MALLOC_TUNABLES = "glibc.malloc.mmap_threshold=33554432:glibc.malloc.trim_threshold=16777216"


def stage_environment(env: Mapping[str, str], module: str | None = None) -> dict[str, str]:
    """The environment the stage process running ``module`` starts with: ``env`` plus the settings below
    (variables ``env`` already sets keep their values, except the pinned math kernels). They must be
    in place before numpy loads, hence the environment, and hold for a stage started by hand
    (``zenslam stage``) too."""
    stage_env = dict(env)
    # Stages run their own threads where it pays (ORB on left/right); library thread pools stall
    # small BLAS products on a loaded machine with few cores (benchmarks/stage_processes.md), and
    # single-threaded numerics keep lockstep runs deterministic.
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        stage_env.setdefault(var, "1")
    # glibc serves blocks above 128 KiB (a 1 MB camera frame, a BA window's arrays) with fresh
    # mmaps that it unmaps on free, so every frame would fault its pages in again. Keeping them in
    # the heap saves that system CPU (benchmarks/stage_processes.md), for at most trim_threshold
    # of memory held per process.
    stage_env.setdefault("GLIBC_TUNABLES", MALLOC_TUNABLES)
    # same bits on any x86-64 CPU: see cpu_kernels
    return cpu_kernels.with_pinned_kernels(stage_env, opencv=module not in cpu_kernels.OPENCV_DISPATCH_FREE_STAGES)


def stage_command(module: str, args: Iterable[str]) -> list[str]:
    """The command line of a stage process: this interpreter running ``module`` with ``args``."""
    # -P: the current directory is not put on sys.path, so a stage imports the installed zenslam
    # even when started from another checkout's root.
    return [sys.executable, "-P", "-m", module, *args]


@contextmanager
def stop_signals_blocked() -> Iterator[None]:
    """Block SIGINT and SIGTERM in this thread meanwhile: a child forked here inherits the mask
    through exec. One arriving meanwhile for this process stays pending and is handled on exit."""
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def _how(failure: dict[str, object]) -> str:
    """"signal SIGKILL" or "exit status 3", and how long it hung when it was killed as hung."""
    how = f"signal {failure['signal']}" if "signal" in failure else f"exit status {failure['exit_code']}"
    return how + (f" after {failure['hung_s']} s without progress" if "hung_s" in failure else "")


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
        self.env = dict(os.environ if env is None else env)  # each stage's own: stage_environment
        self._children: dict[str, _Child] = {}
        self._hung: dict[str, float] = {}  # stages killed as hung: seconds they made no progress
        self._restarted_at: dict[str, list[float]] = {}  # stage -> monotonic times of its recent restarts
        self._restart_counts: dict[str, int] = {}  # stage -> restarts so far in this run

    def __enter__(self) -> Supervisor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self, spec: ProcessSpec) -> None:
        """Start ``spec`` in its own process group, its output going to ``logs/<name>.log``."""
        if spec.name in self._children:
            raise ProcessError(f"a process named {spec.name!r} is already running in this run")
        self._children[spec.name] = self._launch(spec, restart=0)

    def _launch(self, spec: ProcessSpec, restart: int, resume: Sequence[str] = ()) -> _Child:
        """The process of ``spec``; a restart appends to the log of the processes before it and
        passes ``resume``, the arguments that tell it where its predecessor left off."""
        log_dir = self.run_dir / "logs"
        log_dir.mkdir(parents=True, exist_ok=True)
        log_path = log_dir / f"{spec.name}.log"
        restart_args = ["--restart", str(restart), *resume] if restart else []
        command = stage_command(spec.module, [*self.common_args(), *spec.args, *restart_args])
        logger.debug("starting %s: %s", spec.name, " ".join(command))
        with open(log_path, "ab" if restart else "wb") as log, stop_signals_blocked():
            if restart:
                log.write(f"---- restart {restart} of {spec.name} ----\n".encode())
                log.flush()
            try:
                env = stage_environment(self.env, spec.module)
                popen = subprocess.Popen(
                    command, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=env, process_group=0
                )
            except OSError as exc:
                raise ProcessError(f"cannot start {spec.name} ({' '.join(command)}): {exc}") from exc
        return _Child(spec, popen, log_path)

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

    def failures(self) -> list[dict[str, object]]:
        """Each child that exited with a failure: its stage, and its exit code or the signal that ended it."""
        return [self._failure(name, code) for name, child in self._children.items() if (code := child.popen.poll()) not in (None, 0)]

    def _failure(self, name: str, code: int) -> dict[str, object]:
        if code < 0:
            try:
                how: dict[str, object] = {"signal": signal.Signals(-code).name}
            except ValueError:
                how = {"signal": str(-code)}
        else:
            how = {"exit_code": code}
        if name in self._hung:
            how["hung_s"] = round(self._hung[name], 1)
        return {"stage": name, **how}

    def restart_failed(self, config: SupervisionConfig, resume: Mapping[str, Sequence[str]] | None = None) -> list[dict[str, object]]:
        """Start again each child that exited with a failure, when its spec is restartable and it has
        been restarted fewer than ``config.max_restarts`` times in the last ``config.restart_window_s``
        seconds; returns those failures (as ``failures`` describes them, with the restart's number).
        ``resume``: more arguments for a stage's restart, by stage name (where to resume).
        Raises ProcessError, as ``check`` does, for the first failed child that may not be restarted."""
        restarted = []
        for name, child in list(self._children.items()):
            code = child.popen.poll()
            if code in (None, 0):
                continue
            now = time.monotonic()
            recent = [t for t in self._restarted_at.get(name, []) if now - t <= config.restart_window_s]
            reported = code == EXIT_FAILED and name not in self._hung  # its own error, logged: not a crash
            if not child.spec.restartable or reported or len(recent) >= config.max_restarts:
                why = ""
                if child.spec.restartable and config.max_restarts and not reported:
                    why = f" after {len(recent)} restart(s) within {config.restart_window_s:.0f} s (supervision.max_restarts)"
                raise ProcessError(
                    f"process {name} exited with status {code}{why}; the end of {child.log_path}:\n{self.log_tail(name)}"
                )
            failure = self._failure(name, code)
            self._hung.pop(name, None)
            self._restarted_at[name] = [*recent, now]
            restart = self._restart_counts.get(name, 0) + 1
            self._restart_counts[name] = restart
            self._children[name] = self._launch(child.spec, restart, (resume or {}).get(name, ()))
            logger.warning("%s failed (%s): restart %d; see %s", name, _how(failure), restart, child.log_path)
            restarted.append({**failure, "restart": restart})
        return restarted

    def kill_hung(self, name: str, silent_s: float) -> None:
        """Kill a stage that made no progress for ``silent_s`` seconds (``failures`` says it hung)."""
        child = self._children[name]
        if child.popen.poll() is not None:
            return
        self._hung[name] = silent_s
        logger.error("%s made no progress for %.0f s with input waiting: killing it; see %s", name, silent_s, child.log_path)
        try:
            os.killpg(child.popen.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        child.popen.wait()

    def all_running(self) -> bool:
        return all(child.popen.poll() is None for child in self._children.values())

    def wait_until_alive(
        self, session: bus.Session, names: list[str], timeout_s: float, keep_waiting: Callable[[], bool] = lambda: True
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

    def wait_for_exit(self, name: str, timeout_s: float) -> int | None:
        """Wait up to ``timeout_s`` seconds for the child ``name`` to exit; its status, None if it runs on."""
        try:
            return self._children[name].popen.wait(timeout_s)
        except subprocess.TimeoutExpired:
            return None

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
