"""The backend map and its place recognition as flat arrays, and back: the content of a saved map.

Every per-object field becomes a column; variable-length parts (a keyframe's keypoints, a point's
observations, a bag of words) are concatenated with an ``*_offsets`` array of length count + 1,
so that item ``i`` is ``values[offsets[i]:offsets[i + 1]]``. ``map_file`` documents each array;
this module only converts, in the map's own orders (keyframes in insertion order, points in
creation order, observations in the order they were made), so a loaded map is the saved one.
"""

from __future__ import annotations

from itertools import islice

import numpy as np

from zenslam.backend.culled_keyframes import CulledKeyframe
from zenslam.backend.map import BackendKeyframe, BackendMap, MapPoint
from zenslam.backend.place_recognition import PlaceRecognition
from zenslam.backend.point_store import PointStore
from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.vocabulary import BowVector, FeatureVector

# Keyframe keypoint columns: array name -> (BackendKeyframe field, dtype, row shape).
KEYPOINT_COLUMNS: dict[str, tuple[str, str, tuple[int, ...]]] = {
    "keypoints_px": ("keypoints_px", "<f8", (2,)), "keypoint_levels": ("levels", "<i8", ()),
    "keypoint_angles_deg": ("angles_deg", "<f8", ()), "keypoint_right_u": ("right_u", "<f8", ()),
    "keypoint_depth_m": ("depth_m", "<f8", ()), "keypoint_descriptors": ("descriptors", "u1", (32,)),
    "keypoint_map_point_ids": ("map_point_ids", "<i8", ()),
}  # fmt: skip


def _offsets(lengths: list[int]) -> np.ndarray:
    out = np.zeros(len(lengths) + 1, dtype=np.int64)
    np.cumsum(np.asarray(lengths, dtype=np.int64), out=out[1:])
    return out


def _concat(parts: list[np.ndarray], dtype: str, row: tuple[int, ...]) -> np.ndarray:
    if not parts:
        return np.zeros((0, *row), dtype=dtype)
    return np.concatenate([np.asarray(p, dtype=dtype).reshape(-1, *row) for p in parts])


def map_to_arrays(bmap: BackendMap, places: PlaceRecognition | None) -> dict[str, np.ndarray]:
    """Every array of a saved map (``map_file`` names and documents them)."""
    kfs = list(bmap.keyframes.values())
    out: dict[str, np.ndarray] = {
        "keyframe_ids": np.array([kf.id for kf in kfs], dtype="<i8"),
        "keyframe_stamps_ns": np.array([kf.stamp_ns for kf in kfs], dtype="<i8"),
        "keyframe_serials": np.array([kf.serial for kf in kfs], dtype="<i8"),
        "keyframe_T_world_cam": np.array([kf.T_world_cam for kf in kfs], dtype="<f8").reshape(-1, 4, 4),
        "keyframe_keypoint_offsets": _offsets([kf.n_keypoints for kf in kfs]),
        "keyframe_scale_offsets": _offsets([kf.n_levels for kf in kfs]),
        "keyframe_scale_factors": _concat([kf.scale_factors for kf in kfs], "<f8", ()),
    }
    for name, (attr, dtype, row) in KEYPOINT_COLUMNS.items():
        out[name] = _concat([getattr(kf, attr) for kf in kfs], dtype, row)
    out.update(_points_to_arrays(bmap))
    out.update(_graphs_to_arrays(bmap))
    out.update(_places_to_arrays(kfs, places))
    return out


def _points_to_arrays(bmap: BackendMap) -> dict[str, np.ndarray]:
    pts = list(bmap.points.values())
    rows = bmap.point_rows(list(bmap.points))
    store = bmap.point_store
    return {
        "point_ids": np.array([p.id for p in pts], dtype="<i8"),
        "point_p_world": store.p_world[rows].astype("<f8").reshape(-1, 3),
        "point_first_keyframe_ids": np.array([p.first_keyframe_id for p in pts], dtype="<i8"),
        "point_created_serials": np.array([p.created_serial for p in pts], dtype="<i8"),
        "point_descriptors": store.descriptor[rows].astype("u1").reshape(-1, 32),
        "point_normals": store.normal[rows].astype("<f8").reshape(-1, 3),
        "point_min_distance_m": store.min_distance_m[rows].astype("<f8"),
        "point_max_distance_m": store.max_distance_m[rows].astype("<f8"),
        "point_n_visible": np.array([p.n_visible for p in pts], dtype="<i8"),
        "point_n_found": np.array([p.n_found for p in pts], dtype="<i8"),
        "point_observation_offsets": _offsets([len(p.observations) for p in pts]),
        "observation_keyframe_ids": np.array([k for p in pts for k in p.observations], dtype="<i8"),
        "observation_keypoints": np.array([i for p in pts for i in p.observations.values()], dtype="<i8"),
    }


def _graphs_to_arrays(bmap: BackendMap) -> dict[str, np.ndarray]:
    cov = bmap.covisibility
    weights = [(a, b, w) for a in cov.keyframes() for b, w in sorted(cov.weights(a).items()) if a < b]
    culled = bmap.culled.entries()
    fused = sorted(bmap.fused_ids().items())
    return {
        "covisibility_weights": np.array(weights, dtype="<i8").reshape(-1, 3),
        "spanning_tree_parents": np.array(
            [bmap.spanning_tree.parent(k) if bmap.spanning_tree.parent(k) is not None else -1 for k in bmap.keyframes], dtype="<i8"
        ),
        "loop_edges": np.array(bmap.essential_graph.loop_edges(), dtype="<i8").reshape(-1, 2),
        "culled_keyframe_ids": np.array([k for k, _ in culled], dtype="<i8"),
        "culled_stamps_ns": np.array([e.stamp_ns for _, e in culled], dtype="<i8"),
        "culled_parent_ids": np.array([e.parent_id for _, e in culled], dtype="<i8"),
        "culled_T_parent_cam": np.array([e.T_parent_cam for _, e in culled], dtype="<f8").reshape(-1, 4, 4),
        "fused_point_ids": np.array(fused, dtype="<i8").reshape(-1, 2),
    }


def _places_to_arrays(kfs: list[BackendKeyframe], places: PlaceRecognition | None) -> dict[str, np.ndarray]:
    bows = [places.bow(kf.id) if places is not None and kf.id in places.database else BowVector.empty() for kf in kfs]
    fvecs = [places.feature_vectors.get(kf.id, FeatureVector.empty()) if places is not None else FeatureVector.empty() for kf in kfs]
    groups = [g for fv in fvecs for g in fv.features]
    return {
        "bow_offsets": _offsets([len(b) for b in bows]),
        "bow_word_ids": _concat([b.word_ids for b in bows], "<i8", ()),
        "bow_weights": _concat([b.weights for b in bows], "<f8", ()),
        "feature_vector_offsets": _offsets([len(fv) for fv in fvecs]),
        "feature_vector_node_ids": _concat([fv.node_ids for fv in fvecs], "<i8", ()),
        "feature_vector_group_offsets": _offsets([len(g) for g in groups]),
        "feature_vector_keypoints": _concat(groups, "<i8", ()),
    }


def _split(values: np.ndarray, offsets: np.ndarray) -> list[np.ndarray]:
    """``values`` cut at ``offsets`` (count + 1,) into views."""
    bounds = offsets.tolist()
    return [values[a:b] for a, b in zip(bounds[:-1], bounds[1:])]


def map_from_arrays(
    arrays: dict[str, np.ndarray],
    bmap: BackendMap,
    places: PlaceRecognition | None,
    calibration: PinholeCalibration,
    sensor: SensorKind,
    next_serial: int,
    next_backend_point_id: int,
) -> None:
    """Fill the empty ``bmap`` (and ``places``) with the saved map in ``arrays`` (shapes checked by
    ``map_file``); every keyframe gets ``calibration`` and ``sensor``. The keyframes' keypoint
    arrays and bags of words are slices of ``arrays`` (no copy): hand over arrays nothing else writes."""
    a = arrays
    kp_off, sc_off = a["keyframe_keypoint_offsets"], a["keyframe_scale_offsets"]
    # Slices of the arrays just read (fresh, writable, one per column): each keyframe's are disjoint.
    columns = {attr: _split(a[name], kp_off) for name, (attr, _, _) in KEYPOINT_COLUMNS.items()}
    scales = _split(a["keyframe_scale_factors"], sc_off)
    ids = a["keyframe_ids"].tolist()
    for k, kf_id in enumerate(ids):
        kf = BackendKeyframe(
            id=kf_id, stamp_ns=int(a["keyframe_stamps_ns"][k]), T_world_cam=a["keyframe_T_world_cam"][k].copy(),
            calibration=calibration, sensor=sensor, scale_factors=scales[k].copy(),
            **{attr: column[k] for attr, column in columns.items()},
        )  # fmt: skip
        kf.serial = int(a["keyframe_serials"][k])
        bmap.keyframes[kf_id] = kf
        bmap.covisibility.add_keyframe(kf_id)
    _points_from_arrays(a, bmap)
    sorter = np.argsort(a["point_ids"], kind="stable")
    for kf in bmap.keyframes.values():
        associated = kf.map_point_ids >= 0
        kf.map_point_rows = np.full(kf.n_keypoints, -1, dtype=np.int64)
        kf.map_point_rows[associated] = sorter[np.searchsorted(a["point_ids"], kf.map_point_ids[associated], sorter=sorter)]
    _graphs_from_arrays(a, bmap, ids)
    bmap.first_keyframe_id = next((k for k, p in zip(ids, a["spanning_tree_parents"].tolist()) if p < 0), None)
    fused = dict(zip(a["fused_point_ids"][:, 0].tolist(), a["fused_point_ids"][:, 1].tolist()))
    bmap.restore_bookkeeping(next_serial, fused, next_backend_point_id)
    if places is not None:
        _places_from_arrays(a, places, ids)


def _weighted_observations(a: dict[str, np.ndarray]) -> np.ndarray:
    """(P,) ORB-SLAM's Observations() of each point: a stereo/RGB-D observation counts 2."""
    ids = a["keyframe_ids"]
    order = np.argsort(ids, kind="stable")
    rows = order[np.searchsorted(ids[order], a["observation_keyframe_ids"])]
    if np.any(ids[rows] != a["observation_keyframe_ids"]):
        raise ValueError("an observation names a keyframe that is not in the map")
    keypoint = a["keyframe_keypoint_offsets"][rows] + a["observation_keypoints"]
    weights = np.where(a["keypoint_right_u"][keypoint] >= 0, 2, 1)
    counts = np.diff(a["point_observation_offsets"])
    sums = np.zeros(len(counts), dtype=np.int64)
    sums[counts > 0] = np.add.reduceat(weights, a["point_observation_offsets"][:-1][counts > 0]) if len(weights) else 0
    return sums


def _points_from_arrays(a: dict[str, np.ndarray], bmap: BackendMap) -> None:
    counts = np.diff(a["point_observation_offsets"]).tolist()
    pairs = zip(a["observation_keyframe_ids"].tolist(), a["observation_keypoints"].tolist())
    n = len(a["point_ids"])
    store = PointStore(max(2 * n, 1024))
    store.n_rows = n
    store.p_world[:n] = a["point_p_world"]
    store.descriptor[:n] = a["point_descriptors"]
    store.normal[:n] = a["point_normals"]
    store.min_distance_m[:n] = a["point_min_distance_m"]
    store.max_distance_m[:n] = a["point_max_distance_m"]
    bmap.point_store = store
    rows = zip(
        a["point_ids"].tolist(), a["point_first_keyframe_ids"].tolist(), a["point_created_serials"].tolist(),
        a["point_n_visible"].tolist(), a["point_n_found"].tolist(), _weighted_observations(a).tolist(), counts,
    )  # fmt: skip
    points = bmap.points
    for row, (pid, first, serial, visible, found, weighted, count) in enumerate(rows):
        pt = MapPoint(pid, store, row, first, serial)
        pt.observations = dict(islice(pairs, count))
        pt.n_visible, pt.n_found, pt.weighted_observations = visible, found, weighted
        points[pid] = pt


def _graphs_from_arrays(a: dict[str, np.ndarray], bmap: BackendMap, ids: list[int]) -> None:
    for x, y, w in a["covisibility_weights"].tolist():
        bmap.covisibility.change_weight(x, y, w)
    parents = dict(zip(ids, a["spanning_tree_parents"].tolist()))
    children: dict[int, list[int]] = {}
    for kf_id, parent in parents.items():
        children.setdefault(parent, []).append(kf_id)
    queue = list(children.get(-1, []))  # parents before children: the tree is added from the root down
    for kf_id in queue:
        bmap.spanning_tree.add(kf_id, None if parents[kf_id] < 0 else parents[kf_id])
        queue.extend(children.get(kf_id, []))
    for x, y in a["loop_edges"].tolist():
        bmap.essential_graph.add_loop_edge(x, y)
    culled = zip(a["culled_keyframe_ids"].tolist(), a["culled_stamps_ns"].tolist(), a["culled_parent_ids"].tolist())
    for k, (kf_id, stamp, parent) in enumerate(culled):
        bmap.culled.restore(kf_id, CulledKeyframe(stamp, parent, a["culled_T_parent_cam"][k].copy()))


def _places_from_arrays(a: dict[str, np.ndarray], places: PlaceRecognition, ids: list[int]) -> None:
    words, weights = _split(a["bow_word_ids"], a["bow_offsets"]), _split(a["bow_weights"], a["bow_offsets"])
    nodes = _split(a["feature_vector_node_ids"], a["feature_vector_offsets"])
    groups = _split(a["feature_vector_keypoints"], a["feature_vector_group_offsets"])
    fv_off = a["feature_vector_offsets"].tolist()
    features = [FeatureVector(nodes[k], tuple(groups[fv_off[k] : fv_off[k + 1]])) for k in range(len(ids))]
    places.restore_all(ids, [BowVector(w, x) for w, x in zip(words, weights)], features)
