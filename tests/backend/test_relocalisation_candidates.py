"""The backend's relocalisation reply: candidates from the keyframe database over the whole map, their
neighbours, keyframes and points; and the backend/relocalisation queryable answering the frontend's
client over zenoh on loopback."""

from __future__ import annotations

import threading

import numpy as np

from zenslam.backend.config import BackendConfig
from zenslam.backend.place_recognition import PlaceRecognition
from zenslam.backend.local_mapping import LocalMapper, LocalMappingConfig, new_backend_map
from zenslam.backend.node import BackendNode, serve
from zenslam.backend.relocalisation_candidates import relocalisation_reply
from zenslam.frontend.node import RelocalisationQueries
from zenslam.runtime import bus
from zenslam.schemas import codec, keys
from zenslam.schemas.relocalisation import RelocalisationQuery
from zenslam.vocabulary import BowVector, FeatureVector
from test_node import IdentityAdjuster, World  # noqa: E402  (tests/backend is on the path under pytest)


class TwoByteVocabulary:
    """A stand-in vocabulary: a descriptor's word is its first two bytes."""

    def transform(self, descriptors: np.ndarray) -> tuple[BowVector, FeatureVector]:
        d = np.asarray(descriptors, dtype=np.uint8).reshape(-1, 32)
        words, counts = np.unique(d[:, 0].astype(np.int64) * 256 + d[:, 1], return_counts=True)
        nodes = np.unique(d[:, 0]).astype(np.int64)
        features = tuple(np.flatnonzero(d[:, 0] == n).astype(np.int64) for n in nodes)
        return BowVector(words, counts / max(counts.sum(), 1)), FeatureVector(nodes, features)

    def score(self, a: BowVector, b: BowVector) -> float:
        words = np.union1d(a.word_ids, b.word_ids)
        va, vb = np.zeros(len(words)), np.zeros(len(words))
        va[np.searchsorted(words, a.word_ids)] = a.weights
        vb[np.searchsorted(words, b.word_ids)] = b.weights
        return float(1.0 - 0.5 * np.abs(va - vb).sum())


VOCABULARY = TwoByteVocabulary()


def _mapped(n_keyframes: int = 12) -> tuple[BackendNode, World, dict[int, BowVector]]:
    """A node that mapped ``n_keyframes`` keyframes (identity BA), its database fed with them as it goes."""
    world = World(n_points=600)
    node = BackendNode(
        LocalMapper(new_backend_map(LocalMappingConfig()), LocalMappingConfig(), IdentityAdjuster()), PlaceRecognition(VOCABULARY)
    )
    bows = {}
    for k in range(n_keyframes):
        keyframe = world.keyframe(k)
        node.step(keyframe)
        bows[k] = VOCABULARY.transform(keyframe.descriptors)[0]
    return node, world, bows


def _query(bow: BowVector, max_candidates: int = 3, max_neighbours: int = 4) -> RelocalisationQuery:
    return RelocalisationQuery(42, bow.word_ids, bow.weights, max_candidates, max_neighbours)


def test_the_reply_lists_candidates_best_first_with_their_neighbours_keyframes_and_points() -> None:
    node, _, bows = _mapped()
    bmap = node.map
    target = max(k for k in bows if k in bmap.keyframes and k < 4)  # a place the camera left long ago
    reply = node.relocalisation_candidates(_query(bows[target]))
    assert reply.stamp_ns == 42 and reply.keyframes_processed == 12
    assert 1 <= len(reply.candidates) <= 3
    scores = [c.score for c in reply.candidates]
    assert scores == sorted(scores, reverse=True)
    best = reply.candidates[0]
    assert best.keyframe_id == target or target in best.neighbour_ids.tolist()
    for c in reply.candidates:
        assert c.neighbour_ids.tolist() == bmap.covisibility.best_covisible(c.keyframe_id, 4)
    listed = sorted({c.keyframe_id for c in reply.candidates} | {int(k) for c in reply.candidates for k in c.neighbour_ids})
    assert [kf.id for kf in reply.keyframes] == listed
    for kf in reply.keyframes:
        np.testing.assert_array_equal(kf.map_point_ids, bmap.keyframes[kf.id].map_point_ids)
        np.testing.assert_array_equal(kf.descriptors, bmap.keyframes[kf.id].descriptors)
        np.testing.assert_allclose(kf.T_world_cam, bmap.keyframes[kf.id].T_world_cam)
    observed = np.unique(np.concatenate([kf.map_point_ids for kf in reply.keyframes]))
    assert reply.points.ids.tolist() == [p for p in observed.tolist() if p >= 0]
    for i, point_id in enumerate(reply.points.ids.tolist()):
        point = bmap.points[point_id]
        np.testing.assert_array_equal(reply.points.p_world[i], point.p_world)
        np.testing.assert_array_equal(reply.points.descriptors[i], point.descriptor)
        assert (reply.points.min_distance_m[i], reply.points.max_distance_m[i]) == (point.min_distance_m, point.max_distance_m)


def test_an_unknown_place_gets_no_candidate() -> None:
    node, _, _ = _mapped(4)
    nowhere = BowVector(np.array([70_000, 70_001], np.int64), np.array([0.5, 0.5]))  # words no keyframe has
    reply = relocalisation_reply(node.map, node.places.database, VOCABULARY.score, _query(nowhere))
    assert reply.candidates == () and reply.keyframes == () and len(reply.points.ids) == 0


def test_a_window_query_gets_that_keyframe_and_its_neighbours_whatever_the_words() -> None:
    node, _, _ = _mapped(8)
    empty = np.zeros(0, np.int64)
    query = RelocalisationQuery(7, empty, empty.astype(float), 1, 3, window_keyframe_id=5)
    reply = relocalisation_reply(node.map, node.places.database, VOCABULARY.score, query)
    assert [c.keyframe_id for c in reply.candidates] == [5]
    neighbours = node.map.covisibility.best_covisible(5, 3)
    assert reply.candidates[0].neighbour_ids.tolist() == neighbours and len(neighbours) == 3
    assert [kf.id for kf in reply.keyframes] == sorted({5, *neighbours})
    unknown = RelocalisationQuery(7, empty, empty.astype(float), 1, 3, window_keyframe_id=99)
    assert relocalisation_reply(node.map, node.places.database, VOCABULARY.score, unknown).candidates == ()


def test_the_queryable_answers_the_frontends_client_over_the_bus() -> None:
    node, _, bows = _mapped(6)
    session_name, hub_endpoint = "backend-relocalisation-test", bus.free_tcp_endpoint()
    config = BackendConfig(linger_s=30.0)
    with bus.open_session(bus.BusConfig(listen=(hub_endpoint,))) as hub, bus.open_session(bus.BusConfig(connect=(hub_endpoint,))) as peer:
        publisher = bus.declare_publisher(hub, keys.frontend_keyframe(session_name), codec.KEYFRAME, "lossless")
        stop, result = threading.Event(), {}
        worker = threading.Thread(target=lambda: result.setdefault("ended", serve(peer, session_name, node, config, stop.is_set)))
        worker.start()
        try:
            assert bus.wait_for_alive(hub, session_name, ["backend"], timeout_s=10.0) == set()
            ask = RelocalisationQueries(hub, session_name, timeout_s=10.0)
            reply = ask(_query(bows[1]))
            direct = node.relocalisation_candidates(_query(bows[1]))
            # A query that does not decode gets an error reply and leaves the backend serving.
            errors = [r.err is not None for r in hub.get(keys.backend_relocalisation_query(session_name), payload=b"\xff\x01", timeout=10.0)]
            again = ask(_query(bows[2]))
            publisher.put(codec.encode_end_of_stream(codec.KEYFRAME, node.processed))
        finally:
            stop.set()
            worker.join(timeout=10.0)
        assert reply is not None and again is not None and ask.unanswered == 0 and ask.asked == 2
        assert errors == [True]
        assert [c.keyframe_id for c in reply.candidates] == [c.keyframe_id for c in direct.candidates]
        assert [kf.id for kf in reply.keyframes] == [kf.id for kf in direct.keyframes]
        np.testing.assert_array_equal(reply.points.ids, direct.points.ids)
        np.testing.assert_array_equal(reply.points.p_world, direct.points.p_world)


def test_without_a_backend_the_client_gives_up_after_its_timeout() -> None:
    with bus.open_session(bus.BusConfig(listen=(bus.free_tcp_endpoint(),))) as session:
        ask = RelocalisationQueries(session, "nobody-here", timeout_s=0.2)
        assert ask(_query(BowVector(np.array([1], np.int64), np.array([1.0])))) is None
        assert ask.unanswered == 1
