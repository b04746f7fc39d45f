"""The compiled stereo matcher gives exactly what the numpy formulation it replaces gave."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from zenslam.camera import PinholeCalibration
from zenslam.frontend.orb_extractor import Features, OrbExtractor
from zenslam.frontend.stereo_matcher import StereoMatchConfig, StereoMatches, match_stereo

from stereo_numpy_reference import kept_matches, match_stereo as reference_match_stereo  # noqa: E402  (tests/frontend is on the path under pytest)
from test_stereo_matcher import CALIBRATION, stereo_pair, textured_image  # noqa: E402

_FIELDS = ("right_u", "depth_m", "right_index", "sad")

# Configurations that move every rule's boundary: the disparity range, the row band, the level
# range, the descriptor threshold, the SAD window and slide, the parabola bound, the outlier factor.
CONFIGS = [
    StereoMatchConfig(),
    StereoMatchConfig(min_depth_m=2.5, disparity_offset_px=0.25),
    StereoMatchConfig(row_tolerance_px=0.5, level_tolerance=0, max_descriptor_distance=40),
    StereoMatchConfig(row_tolerance_px=3.7, level_tolerance=2, max_descriptor_distance=256),
    StereoMatchConfig(sad_half_window_px=3, sad_search_px=8, max_subpixel_correction_px=0.3, outlier_sad_factor=1.1),
    StereoMatchConfig(sad_half_window_px=9, sad_search_px=2, disparity_offset_px=-3.0, outlier_sad_factor=50.0),
]


def assert_same_matches(
    left: Features,
    right: Features,
    left_pyramid: list[np.ndarray],
    right_pyramid: list[np.ndarray],
    calibration: PinholeCalibration,
    config: StereoMatchConfig,
) -> StereoMatches:
    expected = reference_match_stereo(left, right, left_pyramid, right_pyramid, calibration, config)
    got = match_stereo(left, right, left_pyramid, right_pyramid, calibration, config)
    for name in _FIELDS:
        a, b = getattr(got, name), getattr(expected, name)
        assert a.dtype == b.dtype, name
        np.testing.assert_array_equal(a.view(np.uint8), b.view(np.uint8), err_msg=f"{name} with {config}")
    return got


@pytest.fixture(scope="module")
def synthetic_pairs() -> list[tuple]:
    extractor = OrbExtractor()
    pairs = []
    for seed in (0, 1):
        left, right, _ = stereo_pair(seed)
        pairs.append((*extractor.extract(left), *extractor.extract(right)))
    # grey levels posterised to 6: flat regions, where SAD costs tie and the first lowest must win
    left, right, _ = stereo_pair(2)
    pairs.append((*extractor.extract(left // 48 * 48), *extractor.extract(right // 48 * 48)))
    # right = left: every true disparity is zero
    features, pyramid = extractor.extract(textured_image(3))
    pairs.append((features, pyramid, features, pyramid))
    return pairs


@pytest.mark.parametrize("config", CONFIGS, ids=range(len(CONFIGS)))
def test_synthetic_pairs_match_as_the_numpy_formulation(synthetic_pairs, config: StereoMatchConfig) -> None:
    for f_left, p_left, f_right, p_right in synthetic_pairs:
        assert_same_matches(f_left, f_right, p_left, p_right, CALIBRATION, config)


def test_the_disparity_and_outlier_rules_keep_what_the_numpy_formulation_keeps() -> None:
    """Refined matches at zero disparity (kept as 0.01 px), at the range's ends, rejected (NaN),
    with tied SAD costs, for even and odd counts: the same outputs to the bit."""
    from zenslam.frontend.stereo_kernel import keep_matches

    rng = np.random.default_rng(11)
    n_zero = 0
    for trial in range(200):
        n_left = int(rng.integers(1, 400))
        left_px = np.stack([rng.uniform(0, 640, n_left), rng.uniform(0, 480, n_left)], 1).astype(np.float32)
        left_px[rng.random(n_left) < 0.3] //= 1  # whole pixels, as level-0 keypoints are
        i_left = np.flatnonzero(rng.random(n_left) < 0.7)
        i_right = rng.integers(0, 1000, len(i_left))
        max_disparity = float(rng.choice([20.0, 500.0, rng.uniform(1, 100)]))
        config = StereoMatchConfig(
            disparity_offset_px=float(rng.choice([0.0, 0.25, -1.5])),
            outlier_sad_factor=float(rng.choice([2.1, 1.0, 0.5])),
        )
        # right u of zero disparity once the offset is subtracted (exact: the offsets are binary fractions)
        u_zero = left_px[i_left, 0].astype(np.float64) + config.disparity_offset_px
        kind = rng.integers(0, 6, len(i_left))
        u_right = np.select(
            [kind == 0, kind == 1, kind == 2, kind == 3, kind == 4],
            [u_zero, u_zero + 0.5, u_zero - max_disparity, np.nan, u_zero - max_disparity + 1e-9],
            u_zero - rng.uniform(0, max_disparity, len(i_left)),
        )
        sad = np.where(np.isnan(u_right), np.inf, rng.integers(0, 40, len(i_left)) * 25.0)
        bf = np.float64(50.0) if trial % 2 else 50.0
        expected = kept_matches(left_px, i_left, i_right, u_right, sad, bf, max_disparity, config)
        got = (np.full(n_left, -1.0, np.float32), np.full(n_left, -1.0, np.float32), np.full(n_left, -1, np.int32))
        got += (np.full(n_left, -1.0, np.float32),)
        keep_matches(
            left_px, i_left, i_right, u_right, sad, config.disparity_offset_px, max_disparity,
            config.outlier_sad_factor, float(bf), *got,
        )  # fmt: skip
        for name, a, b in zip(_FIELDS, got, expected):
            np.testing.assert_array_equal(a.view(np.uint8), b.view(np.uint8), err_msg=f"{name}, trial {trial}")
        n_zero += int(np.sum(got[1] == np.float32(bf / 0.01)))
    assert n_zero > 1000  # the zero-disparity rule was exercised


def test_a_numpy_baseline_promotes_as_a_python_one(synthetic_pairs) -> None:
    """A calibration read with numpy holds numpy floats: u_left - max_disparity is then float64,
    with a Python float float32; both give the numpy formulation's candidates."""
    f_left, p_left, f_right, p_right = synthetic_pairs[0]
    calibration = PinholeCalibration(
        np.float64(500.0), np.float64(500.0), 320.0, 240.0, 640, 480, baseline_m=np.float64(0.1) / np.float64(3.0)
    )
    for config in CONFIGS[:2]:
        assert_same_matches(f_left, f_right, p_left, p_right, calibration, config)


def test_features_on_the_image_border_and_without_candidates(synthetic_pairs) -> None:
    """Keypoints whose SAD window leaves the image, rows outside it, and a right image with one keypoint."""
    f_left, p_left, f_right, p_right = synthetic_pairs[0]
    rng = np.random.default_rng(3)
    moved = Features(
        px=np.concatenate([f_left.px, rng.uniform([0, 0], [640, 480], (200, 2)).astype(np.float32)]),
        level=np.concatenate([f_left.level, rng.integers(0, 8, 200).astype(f_left.level.dtype)]),
        angle_deg=np.concatenate([f_left.angle_deg, np.zeros(200, np.float32)]),
        response=np.concatenate([f_left.response, np.zeros(200, np.float32)]),
        descriptors=np.concatenate([f_left.descriptors, f_left.descriptors[rng.integers(0, len(f_left), 200)]]),
        scale_factors=f_left.scale_factors,
        inv_level_sigma2=f_left.inv_level_sigma2,
    )
    for config in CONFIGS:
        assert_same_matches(moved, f_right, p_left, p_right, CALIBRATION, config)
        assert_same_matches(moved, f_right.subset(np.array([7])), p_left, p_right, CALIBRATION, config)


def test_read_only_inputs_take_the_compiled_signature_of_writable_ones(synthetic_pairs) -> None:
    """Images decoded from the bus are read-only, an in-process source's are not: both must run the
    kernels the warm-up compiled, not compile their own at a first frame."""
    from zenslam.frontend import stereo_kernel

    kernels = (stereo_kernel.best_descriptor_matches, stereo_kernel.refine_level_by_sad, stereo_kernel.keep_matches)
    f_left, p_left, f_right, p_right = synthetic_pairs[0]
    match_stereo(f_left, f_right, p_left, p_right, CALIBRATION)
    signatures = [len(k.signatures) for k in kernels]

    def frozen(array: np.ndarray) -> np.ndarray:
        copy = array.copy()
        copy.flags.writeable = False
        return copy

    def frozen_features(features: Features) -> Features:
        names = ("px", "level", "angle_deg", "response", "descriptors", "scale_factors", "inv_level_sigma2")
        return Features(**{name: frozen(getattr(features, name)) for name in names})

    match_stereo(
        frozen_features(f_left), frozen_features(f_right), [frozen(a) for a in p_left], [frozen(a) for a in p_right], CALIBRATION
    )
    assert [len(k.signatures) for k in kernels] == signatures


def _frames(spec: str, every: int) -> tuple[PinholeCalibration, list]:
    from zenslam.service.sources import open_source

    source = open_source(spec)
    return source.calibration, list(itertools.islice(source, 0, None, every))


def _assert_clip_matches_as_the_numpy_formulation(calibration: PinholeCalibration, frames: list) -> None:
    extractor = OrbExtractor()
    for frame in frames:
        (f_left, p_left), (f_right, p_right) = extractor.extract_pair(frame.left, frame.right)
        for config in CONFIGS[:2]:
            matches = assert_same_matches(f_left, f_right, p_left, p_right, calibration, config)
            assert matches.n_matches > 50


@pytest.mark.dataset
def test_kitti_frames_match_as_the_numpy_formulation(kitti_root: Path) -> None:
    _assert_clip_matches_as_the_numpy_formulation(*_frames(f"kitti:{kitti_root / 'sequences' / '06'}", 10))


@pytest.mark.dataset
def test_euroc_frames_match_as_the_numpy_formulation(euroc_micro: Path) -> None:
    _assert_clip_matches_as_the_numpy_formulation(*_frames(f"euroc:{euroc_micro}", 19))
