"""``zenslam replay RUN.mcap``: replay a lockstep recording and compare what comes out with what it recorded.

``--stage all`` (the default) runs source, frontend and backend again on the recording's sensor
frames (``zenslam run mcap:RUN.mcap --lockstep --no-faults`` with the config.yaml beside the
recording: the recorded frames already carry its injected faults) into a new run folder
OUTPUT/RUN_ID, and compares its run.mcap with the recording on frontend/pose,
frontend/state, frontend/keyframe and backend/map_update. ``--stage backend`` feeds the recorded
keyframes to a fresh backend (in a process started like a stage) and compares its map updates with
the recorded ones. Prints the verdict, then the message counts per topic.
"""

from __future__ import annotations

import argparse
import logging
import math
import textwrap
from pathlib import Path

from zenslam.errors import ProcessError, RecordingError
from zenslam.runtime.stop import EXIT_INTERRUPTED
from zenslam.service import backend_replay, mcap_io, replay
from zenslam.service.commands import run as run_command
from zenslam.service.recorder_config import RECORDING_NAME
from zenslam.service.run_output import CONFIG_FILENAME, new_run_id

logger = logging.getLogger(__name__)

EXIT_IDENTICAL = 0  # identical, or equivalent within --tolerance
EXIT_DIFFERENT = 1

_EPILOG = """\
verdict (first line of the output):
  identical                      every compared value has the same bits
  equivalent within X: ...       (with --tolerance X) no value differs by more than X; the largest
                                 deviation |r - p| / max(1, |r|) and where it is
  first difference[ beyond X]: TOPIC message I (stamp_ns S): PATH: recorded R, replayed P
                                 the earliest value that differs (beyond X), e.g. p_world[1372][0]

exit status: 0 identical or equivalent, 1 a difference, 2 an error (unreadable recording, a replay
run or backend replay process that failed), 130 interrupted.
"""


def _tolerance(text: str) -> float:
    value = float(text)
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"tolerance must be a finite number >= 0, got {text!r}")
    return value


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "replay",
        help="replay a lockstep recording (whole pipeline or backend alone) and compare with what it recorded",
        description=textwrap.fill(" ".join(__doc__.split("\n\n", 1)[1].replace("``", "").split()), 100),
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "recording", type=Path, help="a lockstep run's run.mcap; the config.yaml beside it is used (the defaults, with a warning, when absent)"
    )
    parser.add_argument(
        "--stage", choices=("all", "backend"), default="all",
        help="all: source, frontend and backend again on the recorded frames (default); "
        "backend: the recorded keyframes through a fresh backend",
    )  # fmt: skip
    parser.add_argument(
        "--tolerance", type=_tolerance, default=None, metavar="X",
        help="accept floating-point differences up to X, for replays on another architecture where bits cannot match: "
        "recorded r and replayed p agree when |r - p| <= X * max(1, |r|) (X absolute up to magnitude 1, relative above); "
        "integers, ids, counts, strings and descriptors must still be equal. Default: bit-identical",
    )  # fmt: skip
    parser.add_argument(
        "--output", type=Path, default=Path("recordings"), help="--stage all: folder of the new run folder (default recordings)"
    )
    parser.add_argument("--run-id", default=None, help="--stage all: name of the new run folder (default replay-<date-time-pid>)")
    parser.add_argument("--no-progress", action="store_true", help="--stage all: no progress bar")
    parser.set_defaults(handler=run)


def run_arguments(recording: Path, output: Path, run_id: str, progress: bool) -> list[str]:
    """The ``zenslam run`` arguments that replay ``recording``'s sensor frames in lockstep with its config."""
    argv = ["run", f"mcap:{recording.resolve()}", "--lockstep", "--no-faults", "--output", str(output), "--run-id", run_id]
    config = recording.parent / CONFIG_FILENAME
    if config.is_file():
        argv += ["--config", str(config)]
        saved_map = replay.recorded_run_config(recording).backend.save_map
        if saved_map:  # the replay's map goes to its own run folder, not over the recorded run's
            argv += ["--save-map", str(output / run_id / Path(saved_map).name)]
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
        config = replay.recorded_run_config(recording).backend
        comparison = backend_replay.replay_backend(recording, config, args.tolerance)
    else:
        run_id = args.run_id or f"replay-{new_run_id()}"
        code, replayed = replay_pipeline(recording, args.output, run_id, progress=not args.no_progress)
        if code == EXIT_INTERRUPTED:
            return code
        if code != 0:
            raise ProcessError(f"the replay run ended with exit code {code}; see {replayed.parent}")
        if not replayed.is_file():
            raise RecordingError(f"the replay run wrote no {replayed}; is recorder.enabled false in its config.yaml?")
        comparison = replay.compare_recordings(recording, replayed, tolerance=args.tolerance)
    for line in comparison.lines():
        print(line)
    return EXIT_IDENTICAL if comparison.equivalent else EXIT_DIFFERENT
