"""The source's ground truth on the bus and in run.mcap, so a recording is scored when it is replayed.

``zenslam run`` publishes the source's ground truth once on source/ground_truth, after the recorder
listens and before any frame, so run.mcap holds it on ``/source/ground_truth``; ``McapSource`` reads
it back as its ground truth. The message is a zenslam.KeyframeTrajectory whose ids are the poses'
indices (the schema carries stamped poses; no new schema is needed for them). Recordings made
before this channel existed have no ground truth.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from zenslam.runtime import bus
from zenslam.schemas import codec, keys
from zenslam.service import mcap_io
from zenslam.trajectory import Trajectory

logger = logging.getLogger(__name__)

_ANY_SESSION = "replay"
SCHEMA = codec.KEYFRAME_TRAJECTORY


def ground_truth_topic() -> str:
    """The MCAP topic of the source/ground_truth key (``/source/ground_truth``)."""
    return mcap_io.topic_for_key(keys.source_ground_truth(_ANY_SESSION), _ANY_SESSION)


def encode_ground_truth(ground_truth: Trajectory) -> bytes:
    """The bus message of a ground-truth trajectory (T_world_cam at stamps_ns)."""
    poses = np.asarray(ground_truth.T_world_cam, dtype=float)
    message = codec.KeyframeTrajectoryMessage(
        keyframe_ids=np.arange(len(poses), dtype=np.int64),
        stamps_ns=np.asarray(ground_truth.stamps_ns, dtype=np.int64),
        T_world_cam=poses,
        finished=True,
    )
    return codec.encode_keyframe_trajectory(message)


def decode_ground_truth(data: bytes) -> Trajectory:
    """The ground-truth trajectory of a source/ground_truth message."""
    message = codec.decode_keyframe_trajectory(data)
    return Trajectory(message.stamps_ns, message.T_world_cam)


def publish_ground_truth(session: bus.Session, session_name: str, ground_truth: Trajectory) -> None:
    """Send ``ground_truth`` once on source/ground_truth, lossless (the recorder must already listen)."""
    publisher = bus.declare_publisher(session, keys.source_ground_truth(session_name), SCHEMA, "lossless")
    try:
        publisher.put(encode_ground_truth(ground_truth))
    finally:
        publisher.undeclare()
    logger.debug("sent %d ground-truth poses", len(ground_truth))


def read_ground_truth(path: str | Path) -> Trajectory | None:
    """The ground truth recorded in the MCAP file ``path``, or None when it holds none (older recordings)."""
    for message in mcap_io.iter_messages(path, [ground_truth_topic()], log_time_order=False):
        return decode_ground_truth(message.data)
    logger.info("%s holds no %s channel: no ground truth to score a replay with", path, ground_truth_topic())
    return None


def write_ground_truth(writer: mcap_io.RecordingWriter, ground_truth: Trajectory) -> None:
    """Record ``ground_truth`` as the recorder would (for recordings written without the bus)."""
    writer.write(ground_truth_topic(), SCHEMA, encode_ground_truth(ground_truth), 0)
