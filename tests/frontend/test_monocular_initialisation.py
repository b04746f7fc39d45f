"""Monocular map start on rendered frames: two keyframes at the first pair with parallax, never on a still camera."""

import numpy as np
import pytest

from zenslam.backend.config import BackendConfig
from zenslam.backend.local_mapping import LocalMapper, bundle_adjuster, new_backend_map
from zenslam.frontend.config import FrontendConfig
from zenslam.frontend.node import keyframe_message
from zenslam.frontend.pipeline import FrontendPipeline
from zenslam.geometry import invert_T
from zenslam.schemas import codec
from zenslam.service.sources import open_source


def _run(spec: str, frames: int):
    source = open_source(spec)
    pipeline = FrontendPipeline(FrontendConfig(), source.calibration, source.sensor)
    outs = [pipeline.step(f.index, f.stamp_ns, f.left) for f in (source.frame(i) for i in range(frames))]
    return source, pipeline, outs


def test_loop_scene_starts_a_map_of_two_keyframes_at_unit_median_depth():
    source, pipeline, outs = _run("synthetic:loop/mono", 12)
    started = next(i for i, out in enumerate(outs) if out.state == "ok")
    assert started <= 10
    assert all(out.state == "initializing" and out.keyframe is None for out in outs[:started])
    assert outs[0].lost_reason == "waiting_for_second_frame"
    assert all(out.state == "ok" for out in outs[started:])
    first_out = outs[started]
    (first,), second = first_out.earlier_keyframes, first_out.keyframe
    assert (first.id, second.id) == (0, 1) and first.frame_index < second.frame_index == started
    assert np.allclose(first.T_world_cam, np.eye(4))
    # Every point of the first keyframe is observed by the second; the points' median depth is the map's unit.
    assert len(first.new_point_ids) >= 50 and len(second.new_point_ids) == 0
    assert set(first.new_point_ids) <= set(second.map_point_ids[second.map_point_ids >= 0])
    assert np.median(first.new_points_world[:, 2]) == pytest.approx(1.0)
    # Local mapping's BA of the two keyframes: the motion's direction and rotation match the truth, at the
    # scale the frontend chose (the distance between the keyframes is kept: their poses are published).
    config = BackendConfig()
    mapper = LocalMapper(new_backend_map(config.local_mapping), config.local_mapping, bundle_adjuster(config.local_ba))
    for kf in (first, second):
        update = mapper.process(codec.decode_keyframe(codec.encode_keyframe(keyframe_message(kf, source.calibration, "mono"))))
    pipeline.apply_map_update(update)
    truth = source.ground_truth()
    G = [truth.T_world_cam[truth.stamps_ns == kf.stamp_ns][0] for kf in (first, second)]
    T_true = invert_T(G[1]) @ G[0]
    T_est = mapper.map.keyframes[1].T_cam_world @ mapper.map.keyframes[0].T_world_cam
    cos_t = T_true[:3, 3] @ T_est[:3, 3] / np.linalg.norm(T_true[:3, 3]) / np.linalg.norm(T_est[:3, 3])
    assert np.degrees(np.arccos(min(cos_t, 1.0))) < 4.0
    R_err = T_true[:3, :3].T @ T_est[:3, :3]
    assert np.degrees(np.arccos(np.clip((np.trace(R_err) - 1) / 2, -1, 1))) < 0.5
    frontend_baseline = np.linalg.norm(second.T_world_cam[:3, 3] - first.T_world_cam[:3, 3])
    assert np.linalg.norm(T_est[:3, 3]) == pytest.approx(frontend_baseline)
    assert not np.allclose(mapper.map.keyframes[1].T_world_cam, second.T_world_cam, atol=1e-4)  # the BA moved it


def test_a_still_camera_never_starts_a_map():
    _, pipeline, outs = _run("synthetic:still/mono", 8)
    assert all(out.state == "initializing" and out.T_world_cam is None and out.keyframe is None for out in outs)
    assert {out.lost_reason for out in outs[1:]} == {"waiting_for_parallax"}
    assert pipeline.tracker.map.n_keyframes == 0
