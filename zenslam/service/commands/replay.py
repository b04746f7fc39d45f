"""``zenslam replay RUN.mcap [--stage all|backend] [--output DIR]``: replay a lockstep recording and compare.

``--stage all`` runs the whole pipeline again (``zenslam run mcap:RUN.mcap --lockstep`` with the
``config.yaml`` beside the recording, without its ``source.faults``: the recorded frames already
carry them) into a new run folder under DIR and compares its run.mcap
with the original; ``--stage backend`` feeds the recorded keyframes to a fresh backend and compares
its map updates with the recorded ones. Prints "identical" or the first difference; exit 0 when
identical, 1 when not.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from zenslam.errors import RecordingError
from zenslam.service import mcap_io, replay
from zenslam.service.commands import run as run_command
from zenslam.service.recorder import RECORDING_NAME
from zenslam.service.run_output import CONFIG_FILENAME, new_run_id

logger = logging.getLogger(__name__)

EXIT_IDENTICAL = 0
EXIT_DIFFERENT = 1


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "replay",
        help="replay a lockstep recording (whole pipeline or backend alone) and compare with what was recorded",
        description=__doc__.split("\n\n", 1)[1].replace("\n", " ").strip(),
    )
    parser.add_argument("recording", type=Path, help="a lockstep run's run.mcap (its config.yaml beside it is used)")
    parser.add_argument(
        "--stage", choices=("all", "backend"), default="all",
        help="all: source, frontend and backend again (default); backend: the recorded keyframes through a fresh backend",
    )
    parser.add_argument(
        "--output", type=Path, default=Path("recordings"), help="--stage all: folder of the new run folder (default recordings)"
    )
    parser.add_argument("--run-id", default=None, help="--stage all: name of the new run folder (default replay-<date-time-pid>)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(handler=run)


def run_arguments(recording: Path, output: Path, run_id: str, progress: bool) -> list[str]:
    """The ``zenslam run`` arguments that replay ``recording``'s sensor frames in lockstep with its config."""
    argv = ["run", f"mcap:{recording.resolve()}", "--lockstep", "--no-faults", "--output", str(output), "--run-id", run_id]
    config = recording.parent / CONFIG_FILENAME
    if config.is_file():
        argv += ["--config", str(config)]
    else:
        logger.warning("no %s beside %s: replaying with the default configuration", CONFIG_FILENAME, recording)
    return argv + ([] if progress else ["--no-progress"])


def replay_pipeline(recording: Path, output: Path, run_id: str, progress: bool = False) -> tuple[int, Path]:
    """Run the whole pipeline on ``recording``'s frames into ``output/run_id``; (run's exit code, new run.mcap)."""
    parser = argparse.ArgumentParser(prog="zenslam")
    run_command.register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(run_arguments(recording, output, run_id, progress))
    code = int(args.handler(args) or 0)
    return code, output / run_id / RECORDING_NAME


def run(args: argparse.Namespace) -> int:
    recording: Path = args.recording
    mcap_io.check_magic(recording)
    if args.stage == "backend":
        comparison = replay.replay_backend(recording, replay.recorded_run_config(recording).backend)
    else:
        run_id = args.run_id or f"replay-{new_run_id()}"
        code, replayed = replay_pipeline(recording, args.output, run_id, progress=not args.no_progress)
        if code != 0:
            logger.error("the replay run ended with exit code %d; see %s", code, replayed.parent)
            return code
        if not replayed.is_file():
            raise RecordingError(f"the replay run wrote no {replayed}; is recorder.enabled false in its config.yaml?")
        comparison = replay.compare_recordings(recording, replayed)
    for line in comparison.lines():
        print(line)
    return EXIT_IDENTICAL if comparison.identical else EXIT_DIFFERENT
