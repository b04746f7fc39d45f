"""Asking the backend over the bus (from any process of the session): its keyframe trajectory and a map snapshot.

The query side of the backend's queryables, below both stages: a client, the recorder or the frontend
asks without loading gtsam or local mapping.
"""

from __future__ import annotations

from collections.abc import Callable


from zenslam.runtime import bus
from zenslam.schemas import codec, keys


def _query(session: bus.Session, key: str, decode: Callable[[bytes], object], timeout_s: float):
    for reply in bus.query(session, key, timeout_s):
        if reply.ok is not None:
            return decode(reply.ok.payload.to_bytes())
    return None


def query_trajectory(session: bus.Session, session_name: str, timeout_s: float = 10.0) -> codec.KeyframeTrajectoryMessage | None:
    """Ask the backend for its keyframe poses; None when no backend answers within ``timeout_s`` seconds."""
    return _query(session, keys.backend_trajectory_query(session_name), codec.decode_keyframe_trajectory, timeout_s)


def query_map(session: bus.Session, session_name: str, timeout_s: float = 10.0) -> codec.MapSnapshotMessage | None:
    """Ask the backend for a snapshot of its map; None when no backend answers within ``timeout_s`` seconds."""
    return _query(session, keys.backend_map_query(session_name), codec.decode_map_snapshot, timeout_s)
