"""A keyframe whose local BA waits for queued keyframes is placed on the backend's map as it is inserted."""

from __future__ import annotations

import dataclasses

import numpy as np

from test_local_mapping import StubAdjuster, SyntheticFrontend, run  # noqa: E402  (tests/backend is on the path under pytest)
from zenslam.backend.keyframe import BackendKeyframe
from zenslam.backend.keyframe_placement import PlacementConfig, placement
from zenslam.backend.local_mapping import LocalMapper, LocalMappingConfig, new_backend_map
from zenslam.geometry import make_T, so3_exp, transform_points

# Where a frontend behind the backend's map put a keyframe: 6 cm and 0.6 degrees off its place.
STALE = make_T(so3_exp(np.array([0.0, 0.01, 0.0])), [0.04, -0.02, 0.04])


def _mapper_and_stale_keyframe(config: LocalMappingConfig, seed: int = 11):
    """A map of three exact keyframes, and the fourth as a frontend on an older map would send it:
    its pose and the points it creates moved together by ``STALE``."""
    frontend = SyntheticFrontend(seed=seed, clutter=0, duplicate_rate=0.0)
    mapper = LocalMapper(new_backend_map(config), config, StubAdjuster())
    run(frontend, mapper, 3)
    message = frontend.next_message()
    stale = dataclasses.replace(
        message, T_world_cam=STALE @ message.T_world_cam, new_points_world=transform_points(STALE, message.new_points_world)
    )
    return frontend, mapper, message, stale


def test_a_deferred_keyframe_is_placed_on_the_map_with_the_points_it_creates() -> None:
    frontend, mapper, truth, stale = _mapper_and_stale_keyframe(LocalMappingConfig())
    mapper.process(stale, queued=1)
    assert mapper.last_stats.deferred == 1 and mapper.last_stats.placed == 1
    placed = mapper.map.keyframe(truth.id)
    np.testing.assert_allclose(placed.T_world_cam, truth.T_world_cam, atol=1e-6)
    created = [p for p in truth.new_point_ids.tolist() if p in mapper.map.points]
    assert len(created) >= 3
    rows = [truth.new_point_ids.tolist().index(p) for p in created]
    np.testing.assert_allclose(mapper.map.positions(created), truth.new_points_world[rows], atol=1e-6)
    assert mapper.map.check_consistency() == []


def test_a_keyframe_mapped_at_once_or_with_placement_off_is_inserted_as_sent() -> None:
    """Lockstep (nothing queued) keeps the frontend's pose, which its local BA refines; so does a
    deferred keyframe with ``placement.enabled`` false."""
    _, mapper, _, stale = _mapper_and_stale_keyframe(LocalMappingConfig())
    mapper.process(stale, queued=0)
    assert mapper.last_stats.placed == 0
    np.testing.assert_array_equal(mapper.map.keyframe(stale.id).T_world_cam, stale.T_world_cam)  # the stub BA moves nothing
    off = dataclasses.replace(LocalMappingConfig(), placement=PlacementConfig(enabled=False))
    _, mapper, _, stale = _mapper_and_stale_keyframe(off)
    mapper.process(stale, queued=1)
    assert mapper.last_stats.deferred == 1 and mapper.last_stats.placed == 0
    np.testing.assert_array_equal(mapper.map.keyframe(stale.id).T_world_cam, stale.T_world_cam)


def test_a_keyframe_with_too_few_observations_of_the_map_is_not_placed() -> None:
    _, mapper, _, stale = _mapper_and_stale_keyframe(LocalMappingConfig())
    keyframe = BackendKeyframe.from_message(stale)
    known = [p for p in stale.map_point_ids.tolist() if p in mapper.map.points]
    keyframe.map_point_ids[:] = -1
    keyframe.map_point_ids[np.flatnonzero(np.isin(stale.map_point_ids, known))[:29]] = known[:29]
    assert placement(mapper.map, keyframe, PlacementConfig(min_inliers=30)) is None
    keyframe.map_point_ids[np.flatnonzero(np.isin(stale.map_point_ids, known))] = known
    correction = placement(mapper.map, keyframe, PlacementConfig(min_inliers=30))
    np.testing.assert_allclose(correction @ STALE, np.eye(4), atol=1e-6)  # undoes the stale offset
