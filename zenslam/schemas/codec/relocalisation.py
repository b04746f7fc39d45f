"""Relocalisation over the bus (backend/relocalisation): the frontend's query and the backend's candidates."""

from __future__ import annotations

from zenslam.errors import MessageError
from zenslam.schemas import zenslam_pb2 as pb
from zenslam.schemas.codec.packing import pack, parse, transform_from_pb, transform_to_pb, unpack
from zenslam.schemas.relocalisation import (
    MapKeyframe,
    MapPoints,
    RelocalisationCandidate,
    RelocalisationCandidates,
    RelocalisationQuery,
)


def encode_relocalisation_query(query: RelocalisationQuery) -> bytes:
    """Encode a backend/relocalisation query."""
    msg = pb.RelocalisationQuery(
        stamp_ns=query.stamp_ns, num_words=len(query.word_ids),
        max_candidates=query.max_candidates, max_neighbours=query.max_neighbours,
    )
    msg.word_ids = pack(query.word_ids, "<i8", (), "relocalisation query word_ids")
    msg.weights = pack(query.weights, "<f8", (), "relocalisation query weights")
    if query.window_keyframe_id >= 0:
        msg.window_keyframe_id = query.window_keyframe_id
    return msg.SerializeToString()


def decode_relocalisation_query(data: bytes) -> RelocalisationQuery:
    """Decode a backend/relocalisation query."""
    msg = parse(pb.RelocalisationQuery, data)
    w = msg.num_words
    return RelocalisationQuery(
        stamp_ns=msg.stamp_ns,
        word_ids=unpack(msg.word_ids, "<i8", (w,), "relocalisation query word_ids"),
        weights=unpack(msg.weights, "<f8", (w,), "relocalisation query weights"),
        max_candidates=msg.max_candidates,
        max_neighbours=msg.max_neighbours,
        window_keyframe_id=msg.window_keyframe_id if msg.HasField("window_keyframe_id") else -1,
    )


_MAP_KEYFRAME_ARRAYS: dict[str, tuple[str, tuple[int, ...]]] = {
    "levels": ("<i2", ()), "angles_deg": ("<f4", ()), "right_u": ("<f4", ()), "depth_m": ("<f4", ()),
    "descriptors": ("u1", (32,)), "map_point_ids": ("<i8", ()),
}  # fmt: skip
_MAP_POINT_ARRAYS: dict[str, tuple[str, str, tuple[int, ...]]] = {  # message field: (MapPoints field, dtype, row)
    "point_ids": ("ids", "<i8", ()), "p_world": ("p_world", "<f8", (3,)), "descriptors": ("descriptors", "u1", (32,)),
    "normals": ("normals", "<f8", (3,)), "min_distance_m": ("min_distance_m", "<f8", ()),
    "max_distance_m": ("max_distance_m", "<f8", ()),
}  # fmt: skip


def encode_relocalisation_candidates(reply: RelocalisationCandidates) -> bytes:
    """Encode a backend/relocalisation reply; every keyframe's arrays must agree with its keypoint count."""
    msg = pb.RelocalisationCandidates(
        stamp_ns=reply.stamp_ns, keyframes_processed=reply.keyframes_processed, num_points=len(reply.points.ids)
    )
    for candidate in reply.candidates:
        out = msg.candidates.add(keyframe_id=candidate.keyframe_id, score=candidate.score)
        out.neighbour_ids = pack(candidate.neighbour_ids, "<i8", (), f"relocalisation candidate {candidate.keyframe_id} neighbour_ids")
    for kf in reply.keyframes:
        n, where = len(kf.keypoints_px), f"relocalisation keyframe {kf.id}"
        out = msg.keyframes.add(id=kf.id, stamp_ns=kf.stamp_ns, num_keypoints=n)
        transform_to_pb(kf.T_world_cam, out.T_world_cam)
        out.keypoints_px = pack(kf.keypoints_px, "<f4", (2,), f"{where} keypoints_px")
        for name, (dtype, tail) in _MAP_KEYFRAME_ARRAYS.items():
            array = getattr(kf, name)
            if len(array) != n:
                raise MessageError(f"{where}: {name} has {len(array)} entries for {n} keypoints")
            setattr(out, name, pack(array, dtype, tail, f"{where} {name}"))
        out.scale_factors = pack(kf.scale_factors, "<f8", (), f"{where} scale_factors")
    for name, (attr, dtype, tail) in _MAP_POINT_ARRAYS.items():
        setattr(msg, name, pack(getattr(reply.points, attr), dtype, tail, f"relocalisation reply {name}"))
    return msg.SerializeToString()


def decode_relocalisation_candidates(data: bytes) -> RelocalisationCandidates:
    """Decode a backend/relocalisation reply."""
    msg = parse(pb.RelocalisationCandidates, data)
    candidates = tuple(
        RelocalisationCandidate(
            keyframe_id=c.keyframe_id,
            score=c.score,
            neighbour_ids=unpack(c.neighbour_ids, "<i8", (len(c.neighbour_ids) // 8,), f"relocalisation candidate {c.keyframe_id} neighbour_ids"),
        )
        for c in msg.candidates
    )
    keyframes = []
    for kf in msg.keyframes:
        n, where = kf.num_keypoints, f"relocalisation keyframe {kf.id}"
        arrays = {name: unpack(getattr(kf, name), dtype, (n, *tail), f"{where} {name}") for name, (dtype, tail) in _MAP_KEYFRAME_ARRAYS.items()}
        keyframes.append(
            MapKeyframe(
                id=kf.id,
                stamp_ns=kf.stamp_ns,
                T_world_cam=transform_from_pb(kf.T_world_cam),
                keypoints_px=unpack(kf.keypoints_px, "<f4", (n, 2), f"{where} keypoints_px"),
                scale_factors=unpack(kf.scale_factors, "<f8", (len(kf.scale_factors) // 8,), f"{where} scale_factors"),
                **arrays,
            )
        )
    p = msg.num_points
    points = MapPoints(**{
        attr: unpack(getattr(msg, name), dtype, (p, *tail), f"relocalisation reply {name}")
        for name, (attr, dtype, tail) in _MAP_POINT_ARRAYS.items()
    })  # fmt: skip
    return RelocalisationCandidates(msg.stamp_ns, candidates, tuple(keyframes), points, msg.keyframes_processed)
