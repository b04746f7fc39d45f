"""The backend alone on a recording's keyframes, in a process started like a stage, compared with what it recorded.

``replay_backend`` starts ``python -m zenslam.service.backend_replay`` through the ``Supervisor``,
so the replay runs with the stage processes' environment (pinned math kernels, single-threaded
numerics: ``zenslam.runtime.cpu_kernels``) rather than with whatever kernels the calling process
loaded. The child feeds the recorded frontend/keyframe messages, in order, to a fresh
``BackendNode`` and writes its map updates, and the end of stream after them, to an MCAP file;
the caller compares them with the recorded backend/map_update messages.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import sys
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from zenslam.backend.config import BackendConfig
from zenslam.runtime.stage import add_process_arguments, load_section, setup_process_logging
from zenslam.runtime.stop import EXIT_INTERRUPTED, StopFlag
from zenslam.runtime.supervisor import ProcessSpec, Supervisor
from zenslam.schemas import codec
from zenslam.service import mcap_io
from zenslam.service.replay import KEYFRAME_TOPIC, MAP_UPDATE_TOPIC, Comparison, compare_streams, read_topics
from zenslam.service.run_config import RunConfig, run_config_to_yaml, with_map_rules
from zenslam.service.run_output import CONFIG_FILENAME

if TYPE_CHECKING:
    from zenslam.backend.node import StepOutput

logger = logging.getLogger(__name__)

PROCESS_NAME = "backend-replay"
_UPDATES_FILENAME = "map_updates.mcap"


class Backend(Protocol):
    """What the replay needs of a backend: ``BackendNode``'s step and count of processed keyframes."""

    processed: int

    def step(self, keyframe: codec.KeyframeMessage) -> StepOutput: ...


def map_updates(
    keyframes: Iterable[mcap_io.RecordedMessage], backend: Backend, keep_going: Callable[[], bool] = lambda: True
) -> list[mcap_io.RecordedMessage]:
    """``backend``'s map updates (the answer, then any corrections) for each recorded keyframe message,
    in order, and its end of stream when
    the keyframes end with one; logged at the update's stamp (the last one seen, for the end). Stops
    early, without an end of stream, once ``keep_going()`` is false."""
    replayed: list[mcap_io.RecordedMessage] = []
    last_stamp_ns = 0
    for message in keyframes:
        if not keep_going():
            break
        keyframe = codec.decode_keyframe(message.data)
        if isinstance(keyframe, codec.EndOfStream):
            data = codec.encode_end_of_stream(codec.MAP_UPDATE, backend.processed)
            replayed.append(mcap_io.RecordedMessage(MAP_UPDATE_TOPIC, codec.MAP_UPDATE, last_stamp_ns, last_stamp_ns, 0, data))
            break
        for update in backend.step(keyframe).updates:
            last_stamp_ns = max(last_stamp_ns, update.stamp_ns)
            data = codec.encode_map_update(update)
            replayed.append(mcap_io.RecordedMessage(MAP_UPDATE_TOPIC, codec.MAP_UPDATE, update.stamp_ns, update.stamp_ns, 0, data))
        logger.debug("keyframe %d replayed through the backend", keyframe.id)
    return replayed


def replay_backend(recording: str | Path, config: BackendConfig, tolerance: float | None = None) -> Comparison:
    """Run a fresh backend built from ``config`` on ``recording``'s keyframes in a child process started
    like a stage, and compare its map updates with the recorded ones (exactly, or within ``tolerance``:
    see ``field_comparison``)."""
    recording = Path(recording).resolve()
    with tempfile.TemporaryDirectory(prefix="zenslam-backend-replay-") as tmp:
        work = Path(tmp)
        config_path = work / CONFIG_FILENAME
        run_config = with_map_rules(RunConfig(), config.local_mapping.map_rules)  # the map section the backend's copy came from
        config_path.write_text(run_config_to_yaml(dataclasses.replace(run_config, backend=config)))
        output = work / _UPDATES_FILENAME
        with Supervisor(work, PROCESS_NAME, config_path, None) as supervisor:
            supervisor.start(ProcessSpec(PROCESS_NAME, __name__, ("--recording", str(recording), "--output", str(output))))
            supervisor.wait_exit(math.inf)
            supervisor.check()
        replayed = read_topics(output, (MAP_UPDATE_TOPIC,))[MAP_UPDATE_TOPIC]
    recorded = read_topics(recording, (MAP_UPDATE_TOPIC,))[MAP_UPDATE_TOPIC]
    return compare_streams(MAP_UPDATE_TOPIC, recorded, replayed, tolerance)


def main(argv: list[str] | None = None) -> int:
    """The child: the backend section of --config on the keyframes of --recording, map updates to --output."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_process_arguments(parser)
    parser.add_argument("--recording", type=Path, required=True, help="the recording whose frontend/keyframe messages are replayed")
    parser.add_argument("--output", type=Path, required=True, help="MCAP file to write the map updates to")
    args = parser.parse_args(argv)
    setup_process_logging(args.verbose, PROCESS_NAME)
    stop = StopFlag(args.parent_pid).install()  # the supervisor starts it with SIGINT/SIGTERM held back
    # Imported here: the CLI imports this module to build its parser, and only this child needs gtsam.
    from zenslam.backend.node import BackendNode

    backend = BackendNode.from_config(load_section(args.config, "backend", BackendConfig))
    keyframes = read_topics(args.recording, (KEYFRAME_TOPIC,))[KEYFRAME_TOPIC]
    with mcap_io.RecordingWriter(args.output) as writer:
        for message in map_updates(keyframes, backend, stop.keep_going):
            writer.write(message.topic, message.schema, message.data, message.log_time_ns)
    logger.info("%d keyframes replayed through the backend into %s", backend.processed, args.output)
    return EXIT_INTERRUPTED if stop() else 0


if __name__ == "__main__":
    sys.exit(main())
