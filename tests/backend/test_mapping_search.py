"""Local mapping's compiled searches (triangulation's pairs under one node, fusion's search by
projection) give exactly what their numpy formulations gave, on random scenes with every kind of
keypoint (stereo and not, every level) and on keypoints at whole pixels."""

from __future__ import annotations

import numpy as np
import pytest

from zenslam.backend.fusion_search import best_in_windows
from zenslam.backend.keyframe import BackendKeyframe
from zenslam.backend.map_point import PointGeometry
from zenslam.backend.point_fusion import FusionConfig, match_projected
from zenslam.backend.triangulation import TriangulationConfig, candidate_pairs, fundamental_matrix
from zenslam.camera import PinholeCalibration
from zenslam.geometry import invert_T, make_T, so3_exp, transform_points
from zenslam.map_point_rules import mean_viewing_directions, representative_descriptors

from mapping_search_numpy_reference import match_projected as numpy_match_projected  # noqa: E402  (tests/backend is on the path)
from mapping_search_numpy_reference import node_candidates as numpy_node_candidates  # noqa: E402

STEREO = PinholeCalibration(500.0, 500.0, 320.0, 240.0, 640, 480, 0.1)
MONO = PinholeCalibration(500.0, 500.0, 320.0, 240.0, 640, 480)


def _keyframe(rng, kf_id, T_world_cam, p_world, calibration, stereo_share, whole_pixels=False, n_extra=200):
    """A keyframe seeing ``p_world`` (noisy keypoints, flipped descriptor bits) and ``n_extra``
    keypoints of nothing; stereo for ``stereo_share`` of them when the calibration has a baseline."""
    p_cam = transform_points(invert_T(T_world_cam), p_world)
    px = calibration.fx * p_cam[:, :2] / p_cam[:, 2:] + [calibration.cx, calibration.cy] + rng.normal(0, 0.7, (len(p_cam), 2))
    px = np.vstack([px, rng.uniform([0, 0], [calibration.width, calibration.height], (n_extra, 2))])
    if whole_pixels:
        px = np.round(px)
    n = len(px)
    depth = np.concatenate([p_cam[:, 2], rng.uniform(2, 20, n_extra)])
    stereo = (rng.random(n) < stereo_share) & (calibration.baseline_m is not None)
    bf = calibration.bf if calibration.baseline_m is not None else 0.0
    descriptors = rng.integers(0, 256, (n, 32), dtype=np.uint8)
    return BackendKeyframe(
        id=kf_id, stamp_ns=kf_id, T_world_cam=T_world_cam, calibration=calibration,
        sensor="stereo" if calibration.baseline_m is not None else "mono", keypoints_px=px,
        levels=rng.integers(0, 8, n).astype(np.int64), angles_deg=np.zeros(n),
        right_u=np.where(stereo, px[:, 0] - bf / depth + rng.normal(0, 0.5, n), -1.0),
        depth_m=np.where(stereo, depth, -1.0), descriptors=descriptors, scale_factors=1.2 ** np.arange(8),
        map_point_ids=np.full(n, -1, np.int64),
    )  # fmt: skip


def _scene(seed, calibration, stereo_share, forward, whole_pixels=False, n_points=600):
    rng = np.random.default_rng(seed)
    p_world = np.column_stack([rng.uniform(-4, 4, n_points), rng.uniform(-3, 3, n_points), rng.uniform(4, 15, n_points)])
    T1 = np.eye(4)
    step = [0.0, 0.05, -0.6] if forward else [0.5, 0.05, 0.1]  # forward: the first keyframe in front of the second
    T2 = make_T(so3_exp(rng.normal(0, 0.02, 3)), np.array(step))
    kf1 = _keyframe(rng, 1, T1, p_world, calibration, stereo_share, whole_pixels)
    kf2 = _keyframe(rng, 2, T2, p_world, calibration, stereo_share, whole_pixels)
    kf2.descriptors[: n_points] = kf1.descriptors[: n_points]  # the same points look alike
    flips = rng.random((n_points, 32)) < 0.1
    kf2.descriptors[: n_points][flips] ^= rng.integers(1, 256, int(flips.sum()), dtype=np.uint8)
    return rng, p_world, kf1, kf2


SCENES = {
    "stereo sideways": dict(calibration=STEREO, stereo_share=0.6, forward=False),
    "stereo forward, whole pixels": dict(calibration=STEREO, stereo_share=0.5, forward=True, whole_pixels=True),
    "mono forward (epipole in the image)": dict(calibration=MONO, stereo_share=0.0, forward=True),
    "mono sideways, whole pixels": dict(calibration=MONO, stereo_share=0.0, forward=False, whole_pixels=True),
}


def pair_searches(kind: str, seed: int, epipole_min_distance_px: float = 80.0):
    """Triangulation's pairs under one node on a scene of ``kind``: the kernel's and numpy's."""
    rng, _, kf1, kf2 = _scene(seed, **SCENES[kind])
    # a wide band (many pairs at its edge) and, forward, a wide disc around the epipole
    config = TriangulationConfig(epipolar_chi2=40.0, epipole_min_distance_px=epipole_min_distance_px)
    nodes1, nodes2 = rng.integers(-1, 6, kf1.n_keypoints), rng.integers(-1, 6, kf2.n_keypoints)
    shared = rng.random(600) < 0.8  # most of the points' two keypoints under one node, as a vocabulary puts them
    nodes2[:600][shared] = nodes1[:600][shared]
    idx1 = np.sort(rng.choice(kf1.n_keypoints, kf1.n_keypoints * 3 // 4, replace=False))
    idx2 = np.sort(rng.choice(kf2.n_keypoints, kf2.n_keypoints * 3 // 4, replace=False))
    F12 = fundamental_matrix(kf1, kf2)
    got = candidate_pairs(kf1, kf2, idx1, idx2, F12, config, (nodes1, nodes2))
    return got, numpy_node_candidates(kf1, kf2, idx1, idx2, F12, config, nodes1, nodes2)


def fusion_searches(kind: str, seed: int):
    """Fusion's matches on a scene of ``kind`` (keypoints with close rivals): the kernel's and numpy's."""
    rng, p_world, kf1, kf2 = _scene(seed, **SCENES[kind])
    n = len(p_world)
    rays = p_world - kf2.centre_world
    distance = np.linalg.norm(rays, axis=1)
    normals = rays / distance[:, None] + rng.normal(0, 0.2, (n, 3))
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    geometry = PointGeometry(p_world, normals, distance / rng.uniform(1.0, 3.0, n), distance * rng.uniform(1.0, 8.0, n))
    descriptors = kf2.descriptors[:n].copy()
    _add_rivals(rng, kf1, n)
    config = FusionConfig(chi2_mono=20.0, chi2_stereo=25.0, max_descriptor_distance=80)  # wider gates: more ties at the edges
    return match_projected(kf1, geometry, descriptors, config), numpy_match_projected(kf1, geometry, descriptors, config)


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("kind", SCENES)
def test_pairs_under_one_node_are_the_numpy_formulations(kind, seed) -> None:
    got, expected = pair_searches(kind, seed)
    assert len(expected[0]) > 100
    for a, b in zip(got, expected):
        np.testing.assert_array_equal(a, b)
    if kind.startswith("mono forward"):  # the epipole rule removed some pairs
        assert len(pair_searches(kind, seed, epipole_min_distance_px=0.0)[0][0]) > len(got[0])


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("kind", SCENES)
def test_fusion_matches_are_the_numpy_formulations(kind, seed) -> None:
    got, expected = fusion_searches(kind, seed)
    assert len(expected[0]) > 50
    for a, b in zip(got, expected):
        np.testing.assert_array_equal(a, b)


def _add_rivals(rng, kf: BackendKeyframe, n: int) -> None:
    """Give each of the first ``n`` keypoints of ``kf`` a rival 0-3 px away at any level whose
    descriptor is a few bits off: each window then holds candidates that only the rules tell apart."""
    px = kf.keypoints_px[:n] + rng.uniform(-3, 3, (n, 2))
    descriptors = kf.descriptors[:n].copy()
    flips = rng.random((n, 32)) < 0.05
    descriptors[flips] ^= rng.integers(1, 256, int(flips.sum()), dtype=np.uint8)
    kf.keypoints_px = np.vstack([kf.keypoints_px, px])
    kf.levels = np.concatenate([kf.levels, rng.integers(0, 8, n)])
    kf.right_u = np.concatenate([kf.right_u, np.where(kf.right_u[:n] >= 0, kf.right_u[:n] + rng.normal(0, 2, n), -1.0)])
    kf.depth_m = np.concatenate([kf.depth_m, kf.depth_m[:n]])
    kf.descriptors = np.vstack([kf.descriptors, descriptors])
    kf.angles_deg = np.zeros(len(kf.levels))
    kf.map_point_ids = np.full(len(kf.levels), -1, np.int64)
    kf.map_point_rows = np.full(len(kf.levels), -1, np.int64)


def _best_of_three(kp_right_u: list[float], proj_right_u: float = np.nan) -> int:
    """The keypoint matched to a projection at (11, 10) among keypoints at (10, 10), (11, 10) and
    (12, 10) with the same descriptor as the point's (level 0, 3 px window)."""
    best = best_in_windows(
        np.array([0]), np.array([11.0]), np.array([10.0]), np.array([3.0]), np.array([0]), np.array([proj_right_u]),
        np.array([0]), np.array([3]), np.arange(3), np.array([[10.0, 10.0], [11.0, 10.0], [12.0, 10.0]]),
        np.zeros(3, np.int64), np.array(kp_right_u), np.ones(8), 5.991, 7.815, np.zeros((1, 4), np.uint64),
        np.zeros((3, 4), np.uint64), 50,
    )  # fmt: skip
    return int(best[0])


def test_a_fusion_window_reads_a_missing_right_u_as_zero_and_prefers_the_lower_keypoint_on_a_tie() -> None:
    assert _best_of_three([-1.0, -1.0, -1.0]) == 0  # equal distances: the lowest keypoint
    assert _best_of_three([0.5, -1.0, -1.0]) == 0  # a missing projected right u is read as 0: within the gate
    assert _best_of_three([5.0, -1.0, -1.0]) == 1  # 1 + 25 px^2 is outside it: the next keypoint
    assert _best_of_three([5.0, -1.0, -1.0], proj_right_u=5.0) == 0


def test_the_backend_warm_up_compiles_the_searches_for_the_types_local_mapping_uses() -> None:
    # The backend warms them up at its start; its first keyframe must find nothing left to compile.
    from zenslam.backend import epipolar_search, fusion_search
    from zenslam.backend.config import BackendConfig
    from zenslam.backend.kernel_warm_up import warm_up_kernels
    from zenslam.vocabulary import load_vocabulary
    from zenslam.representative_descriptor import representative_offsets
    from zenslam.viewing_direction import mean_rays
    from zenslam.vocabulary.descent import descend

    warm_up_kernels(BackendConfig())
    kernels = (epipolar_search.node_pair_candidates, fusion_search.best_in_windows, descend, representative_offsets, mean_rays)
    compiled = [len(k.signatures) for k in kernels]
    assert all(compiled)
    test_pairs_under_one_node_are_the_numpy_formulations("stereo sideways", 0)
    test_pairs_under_one_node_are_the_numpy_formulations("mono forward (epipole in the image)", 0)
    test_fusion_matches_are_the_numpy_formulations("stereo sideways", 0)
    test_fusion_matches_are_the_numpy_formulations("mono sideways, whole pixels", 0)
    descriptors = np.random.default_rng(0).integers(0, 256, (50, 32), dtype=np.uint8)
    descriptors.setflags(write=False)  # a message's
    load_vocabulary(None).transform(descriptors)
    representative_descriptors(descriptors.reshape(10, 5, 32), np.arange(10) % 5 + 1)
    mean_viewing_directions(np.ones((4, 3)), np.zeros((4, 3, 3)), np.array([1, 2, 3, 1]))
    assert [len(k.signatures) for k in kernels] == compiled
