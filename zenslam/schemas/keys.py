"""Zenoh key expressions of one zenslam session: every key is built here, none is spelled elsewhere.

All keys sit under ``zenslam/<session>/``. Liveliness tokens use ``zenslam/<session>/alive/<process>``.
"""

from __future__ import annotations

import re

from zenslam.errors import ConfigError

ROOT = "zenslam"
STAGES = ("source", "frontend", "backend", "recorder", "run")

# A session or process name is one key chunk: no separators, wildcards or zenoh's reserved characters.
_NAME = re.compile(r"^[A-Za-z0-9_.-]+$")


def _check_name(kind: str, name: str) -> str:
    if not _NAME.match(name or ""):
        raise ConfigError(
            f"{kind} name {name!r} cannot be a zenoh key chunk: use letters, digits, '_', '-' or '.' "
            "(no '/', '*', '$', '?', '#', '@' or spaces)"
        )
    return name


def session_prefix(session: str) -> str:
    """``zenslam/<session>``: the prefix of every key of the session."""
    return f"{ROOT}/{_check_name('session', session)}"


def everything(session: str) -> str:
    """All of the session's data keys (what the recorder subscribes to)."""
    return f"{session_prefix(session)}/**"


def sensor_frame(session: str) -> str:
    """Camera frames from the source (zenslam.SensorFrame)."""
    return f"{session_prefix(session)}/sensor/frame"


def source_ground_truth(session: str) -> str:
    """The source's ground-truth camera poses, sent once before the first frame (zenslam.KeyframeTrajectory)."""
    return f"{session_prefix(session)}/source/ground_truth"


def frontend_pose(session: str) -> str:
    """The tracked camera pose of every frame tracked (foxglove.PoseInFrame)."""
    return f"{session_prefix(session)}/frontend/pose"


def frontend_state(session: str) -> str:
    """The tracking outcome of every frame (zenslam.TrackingState)."""
    return f"{session_prefix(session)}/frontend/state"


def frontend_keyframe(session: str) -> str:
    """New keyframes with their features and new map points (zenslam.Keyframe)."""
    return f"{session_prefix(session)}/frontend/keyframe"


def backend_map_update(session: str) -> str:
    """Corrections of keyframe poses and map points from the backend, one per keyframe processed (zenslam.MapUpdate)."""
    return f"{session_prefix(session)}/backend/map_update"


def backend_loop(session: str) -> str:
    """Detected and accepted loop closures."""
    return f"{session_prefix(session)}/backend/loop"


def status(session: str, stage: str) -> str:
    """How a stage is doing (zenslam.StageStatus)."""
    return f"{session_prefix(session)}/{_check_name('stage', stage)}/status"


def all_status(session: str) -> str:
    """Every stage's status key."""
    return f"{session_prefix(session)}/*/status"


def backend_map_query(session: str) -> str:
    """Queryable: a snapshot of the backend's map (replies zenslam.MapSnapshot)."""
    return f"{session_prefix(session)}/backend/map"


def backend_trajectory_query(session: str) -> str:
    """Queryable: the backend's current keyframe poses (replies zenslam.KeyframeTrajectory)."""
    return f"{session_prefix(session)}/backend/trajectory"


def backend_relocalisation_query(session: str) -> str:
    """Queryable: relocalisation candidates for a lost frame's bag of words (zenslam.RelocalisationQuery in,
    zenslam.RelocalisationCandidates out)."""
    return f"{session_prefix(session)}/backend/relocalisation"


def alive(session: str, process: str) -> str:
    """Liveliness token of one process of the session."""
    return f"{session_prefix(session)}/alive/{_check_name('process', process)}"


def all_alive(session: str) -> str:
    """Every liveliness token of the session."""
    return f"{session_prefix(session)}/alive/*"
