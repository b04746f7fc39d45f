"""Saved maps: a map written and read back is the same map; other versions, cameras and vocabularies are refused."""

from __future__ import annotations

import dataclasses
import json
import zipfile

import numpy as np
import pytest

from zenslam.backend.local_ba import BAProblem, BAResult
from zenslam.backend.local_mapping import LocalMapper, LocalMappingConfig, new_backend_map
from zenslam.backend.map import BackendMap
from zenslam.backend.map_file import MapFileError, check_compatible, load_map, read_header, save_map
from zenslam.backend.node import BackendNode
from zenslam.backend.place_recognition import PlaceRecognition
from zenslam.camera import PinholeCalibration
from zenslam.geometry import invert_T, make_T, transform_points
from zenslam.schemas.codec import KeyframeMessage
from zenslam.schemas.map_update import BACKEND_POINT_ID_BASE
from zenslam.vocabulary import load_vocabulary

CAL = PinholeCalibration(500.0, 500.0, 320.0, 240.0, 640, 480, 0.1)


class _Identity:
    def optimize(self, problem: BAProblem) -> BAResult:
        inliers = np.ones(len(problem.obs_keyframe), dtype=bool)
        return BAResult(problem.T_world_cam.copy(), problem.p_world.copy(), inliers, np.zeros(0, np.int64), {})


def _keyframes(n: int, seed: int = 0) -> list[KeyframeMessage]:
    """Stereo keyframes moving along +x past 400 random points, each keypoint at its exact projection."""
    rng = np.random.default_rng(seed)
    p = np.column_stack([rng.uniform(-3, 6, 400), rng.uniform(-1.5, 1.5, 400), rng.uniform(3, 9, 400)])
    desc = rng.integers(0, 256, (400, 32), dtype=np.uint8)
    known: set[int] = set()
    out = []
    for k in range(n):
        T = make_T(np.eye(3), [0.2 * k, 0.0, 0.0])
        p_cam = transform_points(invert_T(T), p)
        z = p_cam[:, 2]
        px = CAL.fx * p_cam[:, :2] / z[:, None] + [CAL.cx, CAL.cy]
        vis = np.flatnonzero((z > 0.5) & (px[:, 0] >= 0) & (px[:, 0] < 640) & (px[:, 1] >= 0) & (px[:, 1] < 480))
        new = np.array([i for i in vis.tolist() if i not in known], dtype=np.int64)
        known.update(vis.tolist())
        m = len(vis)
        out.append(KeyframeMessage(
            id=10 + k, stamp_ns=k * 100_000_000, frame_index=3 * k, T_world_cam=T, calibration=CAL, sensor="stereo",
            keypoints_px=px[vis].astype(np.float32), levels=rng.integers(0, 3, m).astype(np.int16),
            angles_deg=rng.uniform(0, 360, m).astype(np.float32), right_u=(px[vis, 0] - CAL.bf / z[vis]).astype(np.float32),
            depth_m=z[vis].astype(np.float32), descriptors=desc[vis], map_point_ids=vis.astype(np.int64),
            scale_factors=1.2 ** np.arange(8), new_point_ids=new, new_points_world=p[new].reshape(-1, 3),
        ))  # fmt: skip
    return out


@pytest.fixture(scope="module")
def vocabulary():
    return load_vocabulary(None)


@pytest.fixture(scope="module")
def mapped(vocabulary) -> BackendNode:
    """A backend that mapped 8 keyframes, then had a loop edge, a culled keyframe and a fused point."""
    config = LocalMappingConfig()
    node = BackendNode(LocalMapper(new_backend_map(config), config, _Identity()), PlaceRecognition(vocabulary))
    for keyframe in _keyframes(8):
        node.step(keyframe)
    bmap = node.map
    bmap.essential_graph.add_loop_edge(10, 17)
    bmap.remove_keyframe(13)
    node.places.remove([13])
    a, b = sorted(p for p in bmap.points if len(bmap.points[p].observations) >= 2 and 13 not in bmap.points[p].observations)[:2]
    bmap.replace_point(a, b)
    bmap.new_point(np.array([1.0, 2.0, 3.0]), 10)  # one point of the backend's id space, unobserved
    bmap.take_changes()
    return node


def _load(path, vocabulary) -> tuple[BackendMap, PlaceRecognition]:
    bmap, places = BackendMap(), PlaceRecognition(vocabulary)
    load_map(path, bmap, places, CAL, "stereo")
    return bmap, places


def test_a_saved_map_loads_back_equal(mapped, vocabulary, tmp_path):
    path = tmp_path / "m.zmap"
    header = save_map(path, mapped.map, mapped.places)
    bmap, places = _load(path, vocabulary)
    saved = mapped.map
    assert bmap.check_consistency() == []
    assert list(bmap.keyframes) == list(saved.keyframes)
    for kf_id, kf in saved.keyframes.items():
        got = bmap.keyframes[kf_id]
        for name in ("T_world_cam", "keypoints_px", "levels", "angles_deg", "right_u", "depth_m", "descriptors", "scale_factors", "map_point_ids"):
            np.testing.assert_array_equal(getattr(got, name), getattr(kf, name), err_msg=name)
        assert (got.stamp_ns, got.serial, got.calibration, got.sensor) == (kf.stamp_ns, kf.serial, kf.calibration, kf.sensor)
        assert places.bow(kf_id).word_ids.tolist() == mapped.places.bow(kf_id).word_ids.tolist()
        np.testing.assert_array_equal(places.bow(kf_id).weights, mapped.places.bow(kf_id).weights)
        fv, want = places.feature_vectors[kf_id], mapped.places.feature_vectors[kf_id]
        assert fv.node_ids.tolist() == want.node_ids.tolist()
        assert [g.tolist() for g in fv.features] == [g.tolist() for g in want.features]
    assert list(bmap.points) == list(saved.points)
    for point_id, pt in saved.points.items():
        got = bmap.points[point_id]
        assert list(got.observations.items()) == list(pt.observations.items())  # the order observations were made in
        for name in ("p_world", "descriptor", "normal"):
            np.testing.assert_array_equal(getattr(got, name), getattr(pt, name))
        fields = ("first_keyframe_id", "created_serial", "min_distance_m", "max_distance_m", "n_visible", "n_found", "weighted_observations")
        assert [getattr(got, f) for f in fields] == [getattr(pt, f) for f in fields]
    assert {k: saved.covisibility.weights(k) for k in saved.keyframes} == {k: bmap.covisibility.weights(k) for k in bmap.keyframes}
    assert bmap.spanning_tree.edges() == saved.spanning_tree.edges()
    assert bmap.essential_graph.edges() == saved.essential_graph.edges()
    assert bmap.essential_graph.loop_edges() == [(10, 17)]
    culled = [(k, e.parent_id, e.stamp_ns, e.T_parent_cam.tolist()) for k, e in saved.culled.entries()]
    assert [(k, e.parent_id, e.stamp_ns, e.T_parent_cam.tolist()) for k, e in bmap.culled.entries()] == culled
    assert 13 in [c[0] for c in culled]
    assert bmap.fused_ids() == saved.fused_ids() and len(bmap.fused_ids()) == 1
    assert (bmap.first_keyframe_id, bmap.next_serial) == (10, saved.next_serial)
    assert bmap.point_id_allocator.upcoming == saved.point_id_allocator.upcoming
    # A run continuing the map takes ids past every saved one (fused and culled ones too).
    frontend_ids = [p for p in [*saved.points, *saved.fused_ids()] if p < BACKEND_POINT_ID_BASE]
    assert header.next_keyframe_id == 18 and header.next_frontend_point_id == max(frontend_ids) + 1
    assert header.next_backend_point_id == saved.point_id_allocator.upcoming > BACKEND_POINT_ID_BASE


def test_the_file_is_a_zip_of_npy_arrays_and_a_json_header(mapped, tmp_path):
    path = tmp_path / "m.zmap"
    save_map(path, mapped.map, mapped.places)
    with zipfile.ZipFile(path) as archive:
        names = archive.namelist()
        header = json.loads(archive.read("header.json"))
        with archive.open("point_p_world.npy") as member:
            p_world = np.load(member, allow_pickle=False)  # any numpy reads it, no code involved
    assert names[0] == "header.json" and all(n.endswith(".npy") for n in names[1:])
    assert (header["format"], header["version"], header["camera"]["sensor"]) == ("zenslam-map", 1, "stereo")
    assert header["counts"]["keyframes"] == len(mapped.map.keyframes) and header["vocabulary"]["id"].startswith("sha256:")
    np.testing.assert_array_equal(p_world, np.array([p.p_world for p in mapped.map.points.values()]))


def test_the_same_map_gives_the_same_bytes_whenever_it_is_written(mapped, tmp_path, monkeypatch):
    monkeypatch.setattr(zipfile.time, "time", lambda: 1_000_000_000.0)
    save_map(tmp_path / "a.zmap", mapped.map, mapped.places)
    monkeypatch.setattr(zipfile.time, "time", lambda: 1_700_000_000.0)  # years later
    save_map(tmp_path / "b.zmap", mapped.map, mapped.places)
    assert (tmp_path / "a.zmap").read_bytes() == (tmp_path / "b.zmap").read_bytes()


def _rewrite_header(path, **changes) -> None:
    with zipfile.ZipFile(path) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    header = json.loads(members["header.json"])
    header.update(changes)
    members["header.json"] = json.dumps(header).encode()
    with zipfile.ZipFile(path, "w") as archive:
        for name, data in members.items():
            archive.writestr(name, data)


def test_another_format_version_is_refused_naming_both(mapped, vocabulary, tmp_path):
    path = tmp_path / "m.zmap"
    save_map(path, mapped.map, mapped.places)
    _rewrite_header(path, version=2)
    with pytest.raises(MapFileError, match=r"version 2 but this zenslam reads version 1"):
        _load(path, vocabulary)


def test_another_vocabulary_is_refused_naming_both_ids(mapped, vocabulary, tmp_path):
    path = tmp_path / "m.zmap"
    save_map(path, mapped.map, mapped.places)
    other = vocabulary.with_weights(vocabulary.word_weights * 2.0)
    bmap, places = BackendMap(), PlaceRecognition(other)
    with pytest.raises(MapFileError) as raised:
        load_map(path, bmap, places, CAL, "stereo")
    message = str(raised.value)
    assert vocabulary.content_id in message and other.content_id in message and "backend.vocabulary" in message
    assert not bmap.keyframes


def test_another_camera_is_refused_naming_both(mapped, tmp_path):
    path = tmp_path / "m.zmap"
    header = save_map(path, mapped.map, mapped.places)
    other = dataclasses.replace(CAL, fx=510.0)
    with pytest.raises(MapFileError, match=r"fx=500\.000.*but this run's is a stereo camera fx=510\.000"):
        check_compatible(read_header(path), other, "stereo", header.vocabulary_id)
    with pytest.raises(MapFileError, match=r"made with a stereo camera .* but this run's is a mono camera"):
        check_compatible(header, dataclasses.replace(CAL, baseline_m=None), "mono", header.vocabulary_id)
    check_compatible(header, CAL, "stereo", header.vocabulary_id)  # the same camera passes


def test_files_that_are_no_map_are_refused(tmp_path):
    not_zip = tmp_path / "a.zmap"
    not_zip.write_bytes(b"hello")
    with pytest.raises(MapFileError, match="not a zenslam map"):
        read_header(not_zip)
    with pytest.raises(MapFileError, match="does not exist"):
        read_header(tmp_path / "missing.zmap")
    other_zip = tmp_path / "b.zmap"
    with zipfile.ZipFile(other_zip, "w") as archive:
        archive.writestr("header.json", json.dumps({"format": "something-else"}))
    with pytest.raises(MapFileError, match="'something-else'"):
        read_header(other_zip)


def test_a_truncated_array_is_refused(mapped, vocabulary, tmp_path):
    path = tmp_path / "m.zmap"
    save_map(path, mapped.map, mapped.places)
    with zipfile.ZipFile(path) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    members["point_p_world.npy"] = members["point_p_world.npy"][:-24]
    with zipfile.ZipFile(path, "w") as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    with pytest.raises(MapFileError, match="point_p_world"):
        _load(path, vocabulary)
