"""A run folder's outputs from its recording, for stages started on their own (``zenslam stage recorder --run-dir``).

When the stages run on different machines no ``zenslam run`` follows them; the recorder has
heard every message they sent, so the run's outputs come from ``run.mcap``: the tracking
states, poses, map updates, statuses and loops fill the same ``RunLog`` that ``zenslam run`` fills
from the bus (each topic in the order it was recorded, as it arrived), the ground truth is the
one the source sent (``/source/ground_truth``), and ``write_outputs`` writes trajectory.tum,
trajectory_final.tum, keyframes.tum, metrics.json and the plot as ``zenslam run`` does. The
backend's final keyframe poses are not on a topic: the recorder asks the backend for them when
its stream ends, as ``zenslam run`` does, and passes them in.
"""

from __future__ import annotations

import logging
from pathlib import Path

from zenslam.schemas import codec, keys
from zenslam.service import mcap_io
from zenslam.service.recorded_ground_truth import read_ground_truth
from zenslam.service.run_config import RunConfig
from zenslam.service.run_output import RunLog, RunResult, evaluation_config_for, write_outputs

logger = logging.getLogger(__name__)

_SESSION = "recorded"  # any session name: topics are keys without their session prefix


def _topic(key: str) -> str:
    return mcap_io.topic_for_key(key, _SESSION)


STATE_TOPIC = _topic(keys.frontend_state(_SESSION))
POSE_TOPIC = _topic(keys.frontend_pose(_SESSION))
MAP_UPDATE_TOPIC = _topic(keys.backend_map_update(_SESSION))
LOOP_TOPIC = _topic(keys.backend_loop(_SESSION))
KEYFRAME_TOPIC = _topic(keys.frontend_keyframe(_SESSION))
STATUS_TOPICS = tuple(_topic(keys.status(_SESSION, stage)) for stage in ("source", "frontend", "backend"))


def run_log_from_recording(recording: Path) -> RunLog:
    """The ``RunLog`` of what ``recording`` holds, as ``zenslam run`` would have filled it from the bus."""
    log = RunLog()
    topics = [STATE_TOPIC, POSE_TOPIC, MAP_UPDATE_TOPIC, LOOP_TOPIC, *STATUS_TOPICS]
    for message in mcap_io.iter_messages(recording, topics, log_time_order=False):
        decoded = mcap_io.decode(message)
        if message.topic == STATE_TOPIC:
            if isinstance(decoded, codec.EndOfStream):
                log.ended = True
            else:
                log.add_state(decoded)
        elif message.topic == POSE_TOPIC:
            log.add_pose(decoded)
        elif message.topic == MAP_UPDATE_TOPIC:
            log.add_map_update(decoded)
        elif message.topic == LOOP_TOPIC:
            log.loops.append(decoded)
        else:
            log.add_status(decoded)
    return log


def recorded_sensor(recording: Path) -> str | None:
    """The sensor kind ("mono", "stereo", "rgbd") of the first recorded keyframe; None when there is none."""
    for message in mcap_io.iter_messages(recording, [KEYFRAME_TOPIC], log_time_order=False):
        decoded = mcap_io.decode(message)
        if isinstance(decoded, codec.KeyframeMessage):
            return decoded.sensor
    return None


def write_recorded_outputs(
    run_dir: Path,
    recording: Path,
    config: RunConfig,
    session: str,
    backend_keyframes: codec.KeyframeTrajectoryMessage | None,
    stopped: bool,
) -> RunResult:
    """Write the run folder's outputs (see ``write_outputs``) from ``recording``; ``backend_keyframes``:
    the backend's answer to the trajectory query at the end of its stream (None: it did not answer,
    and keyframes.tum has the frontend's keyframes with the backend's updates applied). ``stopped``:
    the recorder was stopped before the stages had finished; metrics.json says ``run.completed``."""
    log = run_log_from_recording(recording)
    log.backend_keyframes = backend_keyframes
    log.first_keyframe_id = config.frontend.tracking.local_map.keyframe_id_start  # past a saved map's ids
    completed = log.ended and log.backend_ended and not log.stopped_stages and not stopped
    extra = {"run": {"run_id": session, "source": config.source.spec, "mode": config.mode, "completed": completed}}
    sensor = recorded_sensor(recording) or config.source.sensor or "stereo"
    evaluation_config = evaluation_config_for(config.evaluation, sensor)
    return write_outputs(run_dir, log, read_ground_truth(recording), evaluation_config, extra)
