"""Stereo matching of ORB keypoints on a rectified pair, as ORB-SLAM2's Frame::ComputeStereoMatches."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.errors import CalibrationError, ConfigError
from zenslam.descriptors import hamming_distance_pairs
from zenslam.frontend.orb_extractor import Features, base_to_level_px, level_to_base_px

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class StereoMatchConfig:
    """Stereo matching parameters; the defaults are ORB-SLAM2's."""

    max_descriptor_distance: int = 75  # bits: accept the best ORB match below this (ORB-SLAM2: (TH_HIGH+TH_LOW)/2)
    row_tolerance_px: float = 2.0  # level pixels: right keypoints within +-this*scale(level) rows of the left row
    level_tolerance: int = 1  # levels: right keypoint level within +-this of the left keypoint's
    min_depth_m: float = 0.0  # m: nearest depth searched (max disparity = bf / min_depth); 0 = the baseline
    sad_half_window_px: int = 5  # level pixels: SAD window is (2w+1) x (2w+1) on the left keypoint's level
    sad_search_px: int = 5  # level pixels: the SAD window slides +-this around the ORB match
    max_subpixel_correction_px: float = 1.0  # level pixels: reject a parabola fit moving the minimum further
    outlier_sad_factor: float = 2.1  # reject matches whose SAD exceeds this times the median SAD (1.5 * 1.4)

    def __post_init__(self) -> None:
        problems = []
        if not 0 < self.max_descriptor_distance <= 256:
            problems.append(f"max_descriptor_distance={self.max_descriptor_distance} must be in (0, 256] bits")
        if not self.row_tolerance_px >= 0:
            problems.append(f"row_tolerance_px={self.row_tolerance_px} must be >= 0")
        if self.level_tolerance < 0:
            problems.append(f"level_tolerance={self.level_tolerance} must be >= 0")
        if not (math.isfinite(self.min_depth_m) and self.min_depth_m >= 0):
            problems.append(f"min_depth_m={self.min_depth_m} must be a finite distance >= 0 m")
        if self.sad_half_window_px < 1 or self.sad_search_px < 1:
            problems.append(
                f"sad_half_window_px={self.sad_half_window_px} and sad_search_px={self.sad_search_px} must be >= 1"
            )
        if not self.max_subpixel_correction_px > 0:
            problems.append(f"max_subpixel_correction_px={self.max_subpixel_correction_px} must be > 0")
        if not self.outlier_sad_factor > 0:
            problems.append(f"outlier_sad_factor={self.outlier_sad_factor} must be > 0")
        if problems:
            raise ConfigError("invalid StereoMatchConfig: " + "; ".join(problems))


@dataclass(frozen=True, eq=False)  # arrays: compare fields explicitly
class StereoMatches:
    """Per left keypoint: the right image coordinate and depth of its match, -1 where none.

    ``right_u`` is in level-0 pixels of the right image (same row as the left keypoint, rectified);
    ``depth_m`` = bf / (u_left - right_u) in metres; ``right_index`` the matched right keypoint
    (its ORB match before sub-pixel refinement); ``sad`` the refined SAD cost (grey levels).
    """

    right_u: np.ndarray  # (N,) float32
    depth_m: np.ndarray  # (N,) float32
    right_index: np.ndarray  # (N,) int32
    sad: np.ndarray  # (N,) float32, -1 where none

    @property
    def n_matches(self) -> int:
        return int((self.depth_m > 0).sum())


def match_stereo(
    left: Features,
    right: Features,
    left_pyramid: list[np.ndarray],
    right_pyramid: list[np.ndarray],
    calibration: PinholeCalibration,
    config: StereoMatchConfig | None = None,
) -> StereoMatches:
    """Match left keypoints to right keypoints along rectified rows, refine by SAD, give depth.

    Follows ORB-SLAM2: for each left keypoint the best ORB match (Hamming < 75 bits) among right
    keypoints on the same rows (+-2 * scale) at adjacent levels inside the disparity range
    [0, bf / min_depth], then an 11x11 SAD window slid +-5 px on the left keypoint's level with a parabola through
    the three best costs, then rejection of matches whose SAD exceeds 2.1 x the median (ORB-SLAM2
    applies that test to the SAD cost, not the descriptor distance). Coordinates are level-0
    pixels of the rectified images; depth is in metres along the left camera's z axis. As in
    ORB-SLAM2, a zero disparity is kept as 0.01 px (depth 100 * bf): callers decide what is far.
    """
    config = config or StereoMatchConfig()
    if calibration.baseline_m is None:
        raise CalibrationError("stereo matching needs calibration.baseline_m; this calibration is mono")
    n_left = len(left)
    right_u = np.full(n_left, -1.0, np.float32)
    depth = np.full(n_left, -1.0, np.float32)
    right_index = np.full(n_left, -1, np.int32)
    sad_out = np.full(n_left, -1.0, np.float32)
    if n_left == 0 or len(right) == 0:
        return StereoMatches(right_u, depth, right_index, sad_out)
    bf = calibration.bf
    min_depth = config.min_depth_m if config.min_depth_m > 0 else calibration.baseline_m
    max_disparity = bf / min_depth
    i_left, i_right = _best_descriptor_matches(left, right, left_pyramid[0].shape[0], max_disparity, config)
    u_right, sad = _refine_by_sad(left, right, i_left, i_right, left_pyramid, right_pyramid, config)
    disparity = left.px[i_left, 0].astype(np.float64) - u_right
    valid = np.isfinite(u_right) & (disparity >= 0) & (disparity < max_disparity)
    i_left, i_right, u_right, sad, disparity = (a[valid] for a in (i_left, i_right, u_right, sad, disparity))
    tiny = disparity <= 0  # ORB-SLAM2 keeps zero disparity as a point at 100 * bf
    disparity[tiny] = 0.01
    u_right[tiny] = left.px[i_left[tiny], 0] - 0.01
    if len(sad):
        threshold = config.outlier_sad_factor * np.sort(sad)[len(sad) // 2]
        inlier = sad <= threshold
        i_left, i_right, u_right, sad, disparity = (a[inlier] for a in (i_left, i_right, u_right, sad, disparity))
    right_u[i_left] = u_right
    depth[i_left] = bf / disparity
    right_index[i_left] = i_right
    sad_out[i_left] = sad
    logger.debug("stereo: %d of %d left keypoints matched", len(i_left), n_left)
    return StereoMatches(right_u, depth, right_index, sad_out)


def _best_descriptor_matches(
    left: Features, right: Features, n_rows: int, max_disparity: float, config: StereoMatchConfig
) -> tuple[np.ndarray, np.ndarray]:
    """(left index, right index) of each left keypoint's best ORB match under the threshold."""
    # rows each right keypoint may match: +-row_tolerance * scale of its level, as a row table (CSR)
    v_right = right.px[:, 1].astype(np.float64)
    band = config.row_tolerance_px * right.scale_factors[right.level]
    first_row = np.clip(np.floor(v_right - band).astype(np.int64), 0, n_rows - 1)
    last_row = np.clip(np.ceil(v_right + band).astype(np.int64), 0, n_rows - 1)
    span = last_row - first_row + 1
    entry_right = np.repeat(np.arange(len(right)), span)
    entry_row = np.repeat(first_row, span) + _ranges(span)
    by_row = np.argsort(entry_row, kind="stable")  # right indices ascending within a row
    entry_right = entry_right[by_row]
    row_start = np.searchsorted(entry_row[by_row], np.arange(n_rows + 1))
    # every (left, candidate right) pair on the left keypoint's row
    row_left = np.clip(left.px[:, 1].astype(np.int64), 0, n_rows - 1)
    n_candidates = row_start[row_left + 1] - row_start[row_left]
    pair_left = np.repeat(np.arange(len(left)), n_candidates)
    pair_right = entry_right[np.repeat(row_start[row_left], n_candidates) + _ranges(n_candidates)]
    u_left = left.px[pair_left, 0]
    u_right = right.px[pair_right, 0]
    keep = (
        (np.abs(right.level[pair_right].astype(np.int64) - left.level[pair_left]) <= config.level_tolerance)
        & (u_right >= u_left - max_disparity)
        & (u_right <= u_left)
    )
    pair_left, pair_right = pair_left[keep], pair_right[keep]
    distance = hamming_distance_pairs(left.descriptors[pair_left], right.descriptors[pair_right])
    if len(pair_left) == 0:
        return pair_left, pair_right
    # per left keypoint (pairs are grouped by left index): lowest distance, then lowest right index
    n_right = len(right)
    key = distance.astype(np.int64) * n_right + pair_right
    starts = np.flatnonzero(np.r_[True, pair_left[1:] != pair_left[:-1]])
    best = np.minimum.reduceat(key, starts)
    best_distance, best_right = np.divmod(best, n_right)
    accept = best_distance < config.max_descriptor_distance
    return pair_left[starts][accept], best_right[accept]


def _refine_by_sad(
    left: Features,
    right: Features,
    i_left: np.ndarray,
    i_right: np.ndarray,
    left_pyramid: list[np.ndarray],
    right_pyramid: list[np.ndarray],
    config: StereoMatchConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel right u (level-0 px, NaN if rejected) and best SAD per match, level by level."""
    u_right = np.full(len(i_left), np.nan)
    sad = np.full(len(i_left), np.inf)
    levels = left.level[i_left]
    for level in np.unique(levels).tolist():
        members = np.flatnonzero(levels == level)
        u_right[members], sad[members] = _sad_on_level(
            left.px[i_left[members]],
            right.px[i_right[members], 0],
            (left_pyramid[level], right_pyramid[level]),
            left_pyramid[0].shape,
            config,
        )
    return u_right, sad


def _sad_on_level(
    px_left: np.ndarray,
    u_right0: np.ndarray,
    images: tuple[np.ndarray, np.ndarray],
    base_shape: tuple[int, ...],
    config: StereoMatchConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """SAD slide and parabola fit for matches on one level (``images`` = left, right level images of
    the level-0 images of shape ``base_shape``); returns right u (level-0 px) and SAD."""
    image_left, image_right = images
    w, search = config.sad_half_window_px, config.sad_search_px
    rows, cols = image_left.shape
    left_level = base_to_level_px(px_left, image_left.shape, base_shape)
    u_l = np.rint(left_level[:, 0]).astype(np.int64)
    v_l = np.rint(left_level[:, 1]).astype(np.int64)
    right_level = base_to_level_px(np.column_stack([u_right0, np.zeros(len(u_right0))]), image_right.shape, base_shape)
    u_r0 = np.rint(right_level[:, 0]).astype(np.int64)
    inside = (
        (u_r0 - search - w >= 0)
        & (u_r0 + search + w < cols)
        & (u_l - w >= 0)
        & (u_l + w < cols)
        & (v_l - w >= 0)
        & (v_l + w < rows)
    )
    u_out = np.full(len(u_l), np.nan)
    sad_out = np.full(len(u_l), np.inf)
    if not inside.any():
        return u_out, sad_out
    u_l, v_l, u_r0 = u_l[inside], v_l[inside], u_r0[inside]
    side = 2 * w + 1
    strip_width = side + 2 * search
    patch_left = np.lib.stride_tricks.sliding_window_view(image_left, (side, side))[v_l - w, u_l - w]
    strip = np.lib.stride_tricks.sliding_window_view(image_right, (side, strip_width))[v_l - w, u_r0 - search - w]
    # subtract each window's centre pixel, as ORB-SLAM2 does, to be robust to a brightness offset
    patch_left = patch_left.astype(np.int16) - patch_left[:, w : w + 1, w : w + 1].astype(np.int16)
    strip = strip.astype(np.int16)
    n_offsets = 2 * search + 1
    windows = np.lib.stride_tricks.sliding_window_view(strip, side, axis=2).transpose(0, 2, 1, 3)  # (n, off, r, c)
    centres = strip[:, w, w : w + n_offsets]  # (n, offsets)
    diff = windows - (patch_left[:, None, :, :] + centres[:, :, None, None])
    diff = diff.reshape(len(u_l), n_offsets, side * side)
    np.abs(diff, out=diff)
    costs = diff.sum(axis=2, dtype=np.int32).astype(np.float64)  # (n, offsets)
    best = np.argmin(costs, axis=1)
    interior = (best > 0) & (best < 2 * search)
    b = np.clip(best, 1, 2 * search - 1)
    rows_idx = np.arange(len(best))
    c1, c2, c3 = costs[rows_idx, b - 1], costs[rows_idx, b], costs[rows_idx, b + 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = (c1 - c3) / (2.0 * (c1 + c3 - 2.0 * c2))
    ok = interior & np.isfinite(delta) & (np.abs(delta) <= config.max_subpixel_correction_px)
    u_level = u_r0 + (best - search) + delta
    u_base = level_to_base_px(np.column_stack([u_level, np.zeros(len(u_level))]), image_right.shape, base_shape)[:, 0]
    refined = np.where(ok, u_base, np.nan)
    u_out[inside] = refined
    sad_out[inside] = np.where(ok, costs[rows_idx, best], np.inf)
    return u_out, sad_out


def _ranges(counts: np.ndarray) -> np.ndarray:
    """Concatenated aranges: [0..counts[0]), [0..counts[1]), ... as one int64 array."""
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    ends = np.cumsum(counts)
    offsets = np.repeat(ends - counts, counts)
    return np.arange(total, dtype=np.int64) - offsets
