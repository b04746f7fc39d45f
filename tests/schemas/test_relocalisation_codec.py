"""The backend/relocalisation query and reply survive encode -> decode; bad ones fail naming the field."""

from __future__ import annotations

import numpy as np
import pytest

from zenslam.geometry import make_T, so3_exp
from zenslam.schemas import codec
from zenslam.schemas import zenslam_pb2 as pb
from zenslam.schemas.map_update import BACKEND_POINT_ID_BASE
from zenslam.schemas.relocalisation import (
    MapKeyframe,
    MapPoints,
    RelocalisationCandidate,
    RelocalisationCandidates,
    RelocalisationQuery,
)


def _map_keyframe(rng: np.random.Generator, kf_id: int, n: int) -> MapKeyframe:
    return MapKeyframe(
        id=kf_id,
        stamp_ns=1_403_636_579_763_555_584 + kf_id,
        T_world_cam=make_T(so3_exp(rng.normal(size=3)), rng.normal(size=3)),
        keypoints_px=rng.uniform(0, 640, (n, 2)).astype(np.float32),
        levels=rng.integers(0, 8, n).astype(np.int16),
        angles_deg=rng.uniform(0, 360, n).astype(np.float32),
        right_u=np.where(rng.random(n) < 0.5, -1.0, rng.uniform(0, 640, n)).astype(np.float32),
        depth_m=rng.uniform(0.5, 20, n).astype(np.float32),
        descriptors=rng.integers(0, 256, (n, 32), dtype=np.uint8),
        map_point_ids=np.where(rng.random(n) < 0.3, -1, rng.integers(0, 2**40, n)).astype(np.int64),
        scale_factors=1.2 ** np.arange(8),
    )


def _reply(rng: np.random.Generator, p: int = 50) -> RelocalisationCandidates:
    points = MapPoints(
        ids=np.arange(p, dtype=np.int64) + BACKEND_POINT_ID_BASE,
        p_world=rng.normal(size=(p, 3)),
        descriptors=rng.integers(0, 256, (p, 32), dtype=np.uint8),
        normals=rng.normal(size=(p, 3)),
        min_distance_m=rng.uniform(0.5, 1, p),
        max_distance_m=rng.uniform(5, 10, p),
    )
    candidates = (
        RelocalisationCandidate(7, 0.42, np.array([3, 9], np.int64)),
        RelocalisationCandidate(12, 0.31, np.zeros(0, np.int64)),
    )
    keyframes = tuple(_map_keyframe(rng, k, 20 + k) for k in (3, 7, 9, 12))
    return RelocalisationCandidates(stamp_ns=99, candidates=candidates, keyframes=keyframes, points=points, keyframes_processed=40)


def test_query_round_trip():
    query = RelocalisationQuery(5, np.array([1, 17, 9_000_000], np.int64), np.array([0.5, 0.25, 0.25]), 4, 8)
    decoded = codec.decode_relocalisation_query(codec.encode_relocalisation_query(query))
    assert (decoded.stamp_ns, decoded.max_candidates, decoded.max_neighbours) == (5, 4, 8)
    np.testing.assert_array_equal(decoded.word_ids, query.word_ids)
    np.testing.assert_array_equal(decoded.weights, query.weights)
    assert decoded.word_ids.dtype == np.int64 and decoded.weights.dtype == np.float64
    assert decoded.window_keyframe_id == -1  # a lost frame's query: ranked by its words


def test_a_window_query_round_trips_keyframe_zero_too():
    for kf_id in (0, 123):
        query = RelocalisationQuery(5, np.zeros(0, np.int64), np.zeros(0), 1, 10, window_keyframe_id=kf_id)
        assert codec.decode_relocalisation_query(codec.encode_relocalisation_query(query)).window_keyframe_id == kf_id


def test_a_query_of_mismatched_words_and_weights_is_refused():
    with pytest.raises(ValueError, match="word ids and weights"):
        RelocalisationQuery(5, np.array([1, 2], np.int64), np.array([1.0]))


def test_reply_round_trip():
    reply = _reply(np.random.default_rng(3))
    decoded = codec.decode_relocalisation_candidates(codec.encode_relocalisation_candidates(reply))
    assert (decoded.stamp_ns, decoded.keyframes_processed) == (99, 40)
    assert [(c.keyframe_id, c.score, c.neighbour_ids.tolist()) for c in decoded.candidates] == [(7, 0.42, [3, 9]), (12, 0.31, [])]
    assert [kf.id for kf in decoded.keyframes] == [3, 7, 9, 12]
    for got, want in zip(decoded.keyframes, reply.keyframes):
        assert got.stamp_ns == want.stamp_ns
        np.testing.assert_allclose(got.T_world_cam, want.T_world_cam, atol=1e-12)
        for name in ("keypoints_px", "levels", "angles_deg", "right_u", "depth_m", "descriptors", "map_point_ids", "scale_factors"):
            g, w = getattr(got, name), getattr(want, name)
            assert g.dtype == w.dtype and g.shape == w.shape, name
            np.testing.assert_array_equal(g, w, err_msg=name)
    for name in ("ids", "p_world", "descriptors", "normals", "min_distance_m", "max_distance_m"):
        np.testing.assert_array_equal(getattr(decoded.points, name), getattr(reply.points, name), err_msg=name)
    assert decoded.keyframe(9) is decoded.keyframes[2] and decoded.keyframe(8) is None


def test_an_empty_reply_round_trips():
    decoded = codec.decode_relocalisation_candidates(codec.encode_relocalisation_candidates(RelocalisationCandidates(1)))
    assert decoded.candidates == () and decoded.keyframes == ()
    assert decoded.points.p_world.shape == (0, 3) and decoded.points.descriptors.shape == (0, 32)


def test_a_keyframe_with_mismatched_arrays_is_refused():
    reply = _reply(np.random.default_rng(4))
    kf = reply.keyframes[0]
    bad = MapKeyframe(**{**kf.__dict__, "angles_deg": kf.angles_deg[:-1]})
    with pytest.raises(codec.MessageError, match="relocalisation keyframe 3: angles_deg has 22 entries for 23 keypoints"):
        codec.encode_relocalisation_candidates(RelocalisationCandidates(1, keyframes=(bad,)))


def test_a_truncated_reply_names_the_field():
    msg = pb.RelocalisationCandidates.FromString(codec.encode_relocalisation_candidates(_reply(np.random.default_rng(5))))
    msg.normals = msg.normals[:-8]
    with pytest.raises(codec.MessageError, match="normals"):
        codec.decode_relocalisation_candidates(msg.SerializeToString())


def test_every_array_of_the_relocalisation_messages_has_a_layout():
    for schema in (codec.RELOCALISATION_QUERY, codec.RELOCALISATION_CANDIDATES):
        descriptors = [codec.MESSAGE_CLASSES[schema].DESCRIPTOR]
        descriptors += [f.message_type for f in descriptors[0].fields if f.message_type is not None]
        for descriptor in descriptors:
            for f in descriptor.fields:
                if f.type == f.TYPE_BYTES:
                    assert f.name in codec.ARRAY_FIELDS[descriptor.full_name], f"{descriptor.full_name}.{f.name}"


def test_tracking_state_carries_the_relocalised_flag_and_costs_nothing_without_it():
    state = codec.TrackingStateMessage(3, 4, "ok", has_pose=True, relocalised=True)
    assert codec.decode_tracking_state(codec.encode_tracking_state(state)).relocalised
    plain = codec.TrackingStateMessage(3, 4, "ok", has_pose=True)
    assert not codec.decode_tracking_state(codec.encode_tracking_state(plain)).relocalised
    assert len(codec.encode_tracking_state(plain)) < len(codec.encode_tracking_state(state))
