"""The shared start-up of a stage process: its command line, its configuration sections, stopping, logging.

Every stage (source, frontend, backend, recorder) is started by the ``Supervisor`` as
``python -m <module>`` with the arguments of ``add_process_arguments``; it reads its own section
of the run's resolved YAML with ``load_section`` (the file holds every section; a stage reads
only the ones it needs), polls a ``StopFlag`` (``runtime.stop``) between steps, and logs like every
other stage.
"""

from __future__ import annotations

import argparse
import atexit
import dataclasses
import logging
import os
from pathlib import Path
from typing import Literal, TypeVar, get_args

from zenslam.config import from_mapping, load_yaml
from zenslam.errors import ConfigError
from zenslam.runtime import bus

# The stop flag lives in runtime.stop (the CLI installs it before any heavy import); a stage's
# start-up takes it from here with the rest.
from zenslam.runtime.stop import STOPPED, StopFlag  # noqa: F401

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
