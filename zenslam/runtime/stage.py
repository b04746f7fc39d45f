"""The shared start-up of a stage process: its command line, its configuration sections, stopping, logging.

Every stage (source, frontend, backend, recorder) is started by the ``Supervisor`` as
``python -m <module>`` with the arguments of ``add_process_arguments``; it reads its own section
of the run's resolved YAML with ``load_section`` (the file holds every section; a stage reads
only the ones it needs), polls a ``StopFlag`` (``runtime.stop``) between steps, and logs like every
other stage. ``run_stage`` is that start-up, once for all four: a stage's ``main`` names only its
own arguments and what it runs with the ``StageStart`` it is handed.
"""

from __future__ import annotations

import argparse
import atexit
import dataclasses
import logging
import os
from collections.abc import Callable, Iterable
from contextlib import AbstractContextManager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal, TypeVar, get_args

from zenslam.config import from_mapping, load_yaml
from zenslam.errors import ConfigError, ZenslamError
from zenslam.runtime import bus
from zenslam.runtime.rerun_config import RerunConfig

# The stop flag lives in runtime.stop (the CLI installs it before any heavy import); a stage's
# start-up takes it from here with the rest.
from zenslam.runtime.stop import STOPPED, StopFlag  # noqa: F401

if TYPE_CHECKING:
    from zenslam.runtime.rerun_log import StageRecording

logger = logging.getLogger(__name__)

C = TypeVar("C")

# How a run paces its stages (``mode`` in the run's YAML):
# - lockstep: the source sends a frame once the frontend has taken the previous ones, and the
#   frontend waits for the backend's answer to each keyframe; deterministic.
# - pipelined: frames as in lockstep (nothing dropped), but mapping runs in parallel and its
#   updates are applied as they arrive; results depend on timing.
# - live: frames at their recorded times like a camera; a slow stage skips frames.
RunMode = Literal["lockstep", "pipelined", "live"]
RUN_MODES: tuple[str, ...] = get_args(RunMode)


def add_process_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments every stage process takes (what ``Supervisor.common_args`` passes)."""
    parser.add_argument("--session", required=True, help="the run's session name: keys are zenslam/<session>/...")
    parser.add_argument("--config", type=Path, default=None, help="the run's YAML configuration (default: all defaults)")
    parser.add_argument(
        "--connect", action="append", default=[], metavar="ENDPOINT",
        help="zenoh endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable; added to bus.connect)",
    )
    parser.add_argument(
        "--bus-config", type=Path, default=None, metavar="FILE",
        help="zenoh JSON5 config file (bus.zenoh_config_file): mode, endpoints, TLS, access control; for a stage on "
        "another machine than the run's other stages",
    )
    parser.add_argument("--parent-pid", type=int, default=None, help="stop when this process is no longer our parent")
    parser.add_argument(
        "--restart", type=int, default=0, metavar="N",
        help="this is the stage's N-th restart in its run (0: its first start); the supervisor passes it, and the "
        "stage recovers what its predecessor left (the backend rebuilds its map from its journal)",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")


def load_section(path: Path | None, section: str, cls: type[C]) -> C:
    """The ``section`` of the run's YAML file ``path`` as the frozen dataclass ``cls`` (defaults when
    ``path`` is None or the section is absent)."""
    if path is None:
        return cls()
    data = load_yaml(Path(path)).get(section)
    return from_mapping(cls, data, section)


def load_mode(path: Path | None) -> RunMode:
    """The run mode of the run's YAML file ``path`` (lockstep when ``path`` is None or it says none)."""
    mode = "lockstep" if path is None else load_yaml(Path(path)).get("mode", "lockstep")
    if mode not in RUN_MODES:
        raise ConfigError(f"{path}: mode={mode!r} must be one of {list(RUN_MODES)}")
    return mode


def bus_config_with(config: bus.BusConfig, connect: list[str], zenoh_config_file: Path | None = None) -> bus.BusConfig:
    """``config`` with extra endpoints to connect to, and the zenoh config file ``zenoh_config_file``
    (a stage's ``--bus-config``) in place of the one it names, when given."""
    if zenoh_config_file is not None:
        config = dataclasses.replace(config, zenoh_config_file=str(zenoh_config_file))
    if not connect:
        return config
    return dataclasses.replace(config, connect=tuple(config.connect) + tuple(connect))


def stopped_before_joining(stop: StopFlag) -> bool:
    """True, and logged, when ``stop`` is set before the stage joined the bus: nobody has seen it nor
    waits for its streams yet, so it may exit at once instead of finishing its start-up."""
    if stop():
        logger.info("stopped before joining the bus")
        return True
    return False


def setup_process_logging(verbose: bool, stage: str) -> None:
    """Logging for a stage process's entry point (the only place besides the CLI that configures it)."""
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.INFO, format=f"%(asctime)s {stage} %(levelname)s %(name)s: %(message)s"
    )
    bus.quiet_zenoh_logs()
    atexit.register(log_cpu_times)  # runs before logging's own atexit shutdown (registered earlier)


def yield_cpu(increment: int) -> None:
    """Lower this process's scheduling priority by ``increment`` (a POSIX niceness increment, 0-19; 0
    leaves it as is) and log the niceness it now runs at: the stages whose input waits in a queue
    (mapping, recording) yield the CPU to tracking, which a camera does not wait for."""
    if not increment:
        return
    try:
        logger.info("niceness %d: the CPU goes to tracking first", os.nice(increment))
    except OSError as exc:  # a sandbox without setpriority: run at the priority we have
        logger.warning("could not lower this process's priority by %d (%s); running at its own", increment, exc)


def log_cpu_times(when: str = "at exit") -> None:
    """Log the process's CPU time so far (all its threads, zenoh's included) as
    ``cpu <when>: user U s system S s``; stages log it when their stream starts and at exit."""
    times = os.times()
    logger.info("cpu %s: user %.3f s system %.3f s", when, times.user, times.system)


# The exit status of a stage that stopped on one of the project's errors (a bad configuration, a
# stage it needs that never came up); the error is logged first.
EXIT_STAGE_ERROR = 2


def add_wait_for_argument(parser: argparse.ArgumentParser, before: str) -> None:
    """``--wait-for STAGE`` (repeatable): the stages whose liveliness tokens must be present ``before``
    this one goes on (what ``service.stages.stage_args`` passes)."""
    parser.add_argument(
        "--wait-for", action="append", default=[], metavar="STAGE",
        help=f"stage whose liveliness token must be present before {before} (repeatable)",
    )


@dataclass(frozen=True)
class StageStart:
    """What a stage process's start-up hands to the stage: its name, its parsed command line, its
    installed stop flag and the run's ``bus`` section."""

    name: str
    args: argparse.Namespace
    stop: StopFlag
    bus_config: bus.BusConfig

    def section(self, section: str, cls: type[C]) -> C:
        """The ``section`` of the run's YAML (``--config``) as the frozen dataclass ``cls``."""
        return load_section(self.args.config, section, cls)

    def mode(self) -> RunMode:
        """The run mode of the run's YAML."""
        return load_mode(self.args.config)

    def stopped_before_joining(self) -> bool:
        """True, and logged, when the stage was stopped before it joined the bus."""
        return stopped_before_joining(self.stop)

    def open_session(self, connect: Iterable[str] = ()) -> AbstractContextManager:
        """The stage's zenoh session: the ``bus`` section with the process's ``--connect`` endpoints (and
        ``connect``'s) added and its ``--bus-config`` file in place of the section's, if given."""
        return bus.open_session(bus_config_with(self.bus_config, [*self.args.connect, *connect], self.args.bus_config))

    def require_alive(self, session: bus.Session, stages: Iterable[str]) -> None:
        """Wait for the ``stages``' liveliness tokens on the run's session (``bus.start_timeout_s`` at most,
        BusError naming those missing then), unless the stage is stopped meanwhile."""
        bus.require_alive(session, self.args.session, stages, self.bus_config.start_timeout_s, self.stop.keep_going)

    def rerun_recording(self) -> AbstractContextManager[StageRecording | None]:
        """The stage's rerun recording in the run folder (None when the ``rerun`` section disables it or
        there is no run folder); a restarted stage writes one of its own beside its predecessor's."""
        from zenslam.runtime import rerun_log  # the rerun SDK only in the stages that log to it

        config = self.section("rerun", RerunConfig)
        return rerun_log.open_stage_recording(self.name, self.args.session, self.args.config, config, self.args.restart)


def run_stage(
    name: str,
    doc: str | None,
    run: Callable[[StageStart], None],
    argv: list[str] | None = None,
    add_arguments: Callable[[argparse.ArgumentParser], None] | None = None,
) -> int:
    """Start the stage process ``name`` and run it; returns its exit status.

    Parses the command line (``add_process_arguments`` and those ``add_arguments`` adds; the first
    line of ``doc``, the stage module's docstring, describes it), sets up the process's logging,
    installs its stop flag, reads the run's ``bus`` section and calls ``run``. A ZenslamError is
    logged (by the logger of ``run``'s module) and ends the process with ``EXIT_STAGE_ERROR``; any
    other error propagates, with its traceback, as a bug.
    """
    parser = argparse.ArgumentParser(prog=f"zenslam-{name}", description=(doc or name).splitlines()[0])
    add_process_arguments(parser)
    if add_arguments is not None:
        add_arguments(parser)
    args = parser.parse_args(argv)
    setup_process_logging(args.verbose, name)
    stop = StopFlag(args.parent_pid).install()
    try:
        run(StageStart(name, args, stop, load_section(args.config, "bus", bus.BusConfig)))
    except ZenslamError as exc:
        logging.getLogger(run.__module__).error("%s", exc)
        return EXIT_STAGE_ERROR
    return 0
