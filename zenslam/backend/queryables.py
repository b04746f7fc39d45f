"""The backend's queryables: backend/map, backend/trajectory and backend/relocalisation.

Queries wait in the bus wrapper's channels until the backend's worker answers them between two
keyframes, on its own thread, so a reply always shows the map between two keyframes. The query
side, for any process of the session, is ``zenslam.runtime.backend_queries``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Protocol


from zenslam.errors import ZenslamError
from zenslam.runtime import bus
from zenslam.schemas import codec, keys
from zenslam.schemas.relocalisation import RelocalisationCandidates, RelocalisationQuery

logger = logging.getLogger(__name__)


class MapAnswers(Protocol):
    """What the queryables ask of the map's owner (``BackendNode``)."""

    def trajectory(self, waiting: Sequence[codec.KeyframeMessage] = ()) -> codec.KeyframeTrajectoryMessage: ...

    def snapshot(self) -> codec.MapSnapshotMessage: ...

    def relocalisation_candidates(self, query: RelocalisationQuery) -> RelocalisationCandidates: ...


class BackendQueryables:
    """backend/map, backend/trajectory and backend/relocalisation, declared through the bus wrapper."""

    def __init__(self, session: bus.Session, session_name: str) -> None:
        self._map_key = keys.backend_map_query(session_name)
        self._trajectory_key = keys.backend_trajectory_query(session_name)
        self._relocalisation_key = keys.backend_relocalisation_query(session_name)
        self._map = bus.declare_queryable(session, self._map_key)
        self._trajectory = bus.declare_queryable(session, self._trajectory_key)
        self._relocalisation = bus.declare_queryable(session, self._relocalisation_key)

    def answer(self, node: MapAnswers, waiting: Callable[[], Sequence[codec.KeyframeMessage]] = tuple) -> int:
        """Reply to every waiting query with the map as it is now; returns how many were answered.
        ``waiting()``: the keyframes waiting to be mapped, which count for the next ids of the
        trajectory's reply (asked only when a trajectory query waits)."""
        answered = 0

        def trajectory() -> bytes:
            return codec.encode_keyframe_trajectory(node.trajectory(waiting()))

        for queryable, key, schema, make in (
            (self._map, self._map_key, codec.MAP_SNAPSHOT, lambda: codec.encode_map_snapshot(node.snapshot())),
            (self._trajectory, self._trajectory_key, codec.KEYFRAME_TRAJECTORY, trajectory),
        ):
            payload = None
            for query in bus.waiting_queries(queryable):
                payload = make() if payload is None else payload
                bus.reply(query, key, payload, schema)
                answered += 1
        return answered + self._answer_relocalisation(node)

    def _answer_relocalisation(self, node: MapAnswers) -> int:
        """Each relocalisation query carries its own bag of words: one reply per query. A query
        that does not decode gets an error reply (the querier's problem, not the backend's)."""
        answered = 0
        for query in bus.waiting_queries(self._relocalisation):
            try:
                request = codec.decode_relocalisation_query(query.payload.to_bytes() if query.payload is not None else b"")
            except ZenslamError as exc:
                logger.warning("relocalisation query refused: %s", exc)
                bus.reply_error(query, str(exc))
            else:
                reply = codec.encode_relocalisation_candidates(node.relocalisation_candidates(request))
                bus.reply(query, self._relocalisation_key, reply, codec.RELOCALISATION_CANDIDATES)
            answered += 1
        return answered

    def close(self) -> None:
        """Finalise the queries left unanswered and undeclare the queryables."""
        for queryable in (self._map, self._trajectory, self._relocalisation):
            bus.close_queryable(queryable)
