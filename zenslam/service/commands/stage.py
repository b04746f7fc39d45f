"""``zenslam stage ROLE --session ID [--bus-config FILE] [--config RUN_YAML] ...``: one stage of a run, started by hand.

``zenslam run`` starts every stage on one machine; this starts one, on any machine of the zenoh
network, as the same process ``zenslam run`` would start (the module, the environment that pins
the math kernels, the arguments of ``service.stages``), so a run split over machines behaves as
the single-machine one and gives the same lockstep bytes. The process replaces this one (exec):
Ctrl-C reaches the stage itself, which ends its stream and exits. Every option after ROLE goes
to the stage (``zenslam stage frontend --help`` lists them): ``--session`` (the run id, the same
on every machine), ``--bus-config`` (a zenoh JSON5 file: mode, endpoints, TLS, access control),
``--config`` (the run's YAML: every machine should use the same file), ``--connect``, ``-v``.

Defaults beyond ``zenslam run``'s: the source sends its ground truth for the recorder
(``--publish-ground-truth``); the recorder, unless given ``--output``, records into the run folder
``--run-dir`` (default ``recordings/<session>``) and writes the run's outputs there at the end.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
from pathlib import Path

from zenslam.errors import ProcessError
from zenslam.runtime.stop import STOP_SIGNALS
from zenslam.runtime.supervisor import stage_command, stage_environment
from zenslam.service.run_config import RunConfig, load_run_config, run_config_to_yaml
from zenslam.service.stages import STAGE_MODULES, STAGE_NAMES, stage_args

logger = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "stage",
        help="start one stage of a run (source, frontend, backend, recorder) by hand, e.g. on another machine",
        description=__doc__.split("\n\n")[1].replace("\n", " "),
    )
    parser.add_argument("role", choices=STAGE_NAMES, help="the stage to start")
    parser.add_argument(
        "stage_args", nargs=argparse.REMAINDER, metavar="...",
        help="the stage's own options: --session ID (required), --bus-config FILE, --config RUN_YAML, ... "
        "(`zenslam stage ROLE --help` lists them)",
    )
    parser.set_defaults(handler=run)


def _given_options(given: list[str]) -> argparse.Namespace:
    """The options among a stage's arguments that decide what ``zenslam stage`` adds to them."""
    known = argparse.ArgumentParser(add_help=False)
    known.add_argument("--config", type=Path, default=None)
    known.add_argument("--session", default=None)
    known.add_argument("--output", default=None)
    known.add_argument("--run-dir", default=None)
    known.add_argument("-h", "--help", action="store_true")
    return known.parse_known_args(given)[0]


def stage_argv(role: str, given: list[str], config: RunConfig) -> list[str]:
    """The stage's arguments: those ``zenslam run`` would add for ``role`` with the run's ``config``, then ``given``."""
    options = _given_options(given)
    argv = list(stage_args(role, config.recorder.enabled))
    if role == "source":
        argv.append("--publish-ground-truth")
    if role == "recorder" and options.output is None and options.run_dir is None and options.session is not None:
        argv += ["--run-dir", str(Path("recordings") / options.session)]
    return argv + list(given)


def _with_resolved_config(given: list[str], path: Path | None, config: RunConfig) -> list[str]:
    """``given`` with ``--config`` naming the resolved run config: a stage reads its sections as
    written, so a file with keys of earlier versions (migrated by ``load_run_config``) or with the
    ``map`` section alone (copied into the stages' sections) is passed on resolved, as ``zenslam run``
    does. The resolved file sits beside the given one (the backend keeps its journal in that folder)."""
    if path is None:
        return given
    resolved_text = run_config_to_yaml(config)
    if path.read_text() == resolved_text:
        return given
    resolved = path.with_name(f"{path.stem}.resolved.yaml")
    resolved.write_text(resolved_text)
    logger.info("the stage reads %s: %s resolved (earlier keys migrated, shared sections copied)", resolved, path)
    out, k = [], 0
    while k < len(given):
        if given[k] == "--config" and k + 1 < len(given):
            out += ["--config", str(resolved)]
            k += 2
        elif given[k].startswith("--config="):
            out.append(f"--config={resolved}")
            k += 1
        else:
            out.append(given[k])
            k += 1
    return out


def run(args: argparse.Namespace) -> int:
    """Replace this process with the stage's (never returns unless the exec fails)."""
    options = _given_options(args.stage_args)
    env = stage_environment(os.environ, STAGE_MODULES[args.role])
    if options.help:
        argv = list(args.stage_args)
    else:
        config = load_run_config(options.config)
        argv = stage_argv(args.role, _with_resolved_config(args.stage_args, options.config, config), config)
        if config.mode != "live":
            # Single-threaded numerics in lockstep and pipelined runs, as ``zenslam run`` gives its stages.
            env.update({name: "1" for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")})
    command = stage_command(STAGE_MODULES[args.role], argv)
    logger.debug("exec %s", " ".join(command))
    sys.stdout.flush()
    sys.stderr.flush()
    # A stop signal arriving while the stage still imports waits, pending, until its StopFlag is
    # installed (the mask survives exec), as for a stage the supervisor starts.
    signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    try:
        os.execve(sys.executable, command, env)
    except OSError as exc:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
        raise ProcessError(f"cannot start the {args.role} stage ({' '.join(command)}): {exc}") from exc
    return 1  # not reached
