"""The numpy formulation of stereo matching, kept as the reference the compiled kernels
(zenslam/frontend/stereo_kernel.py) must equal exactly."""

from __future__ import annotations

import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.descriptors import hamming_distance_pairs
from zenslam.errors import CalibrationError
from zenslam.frontend.orb_extractor import Features, base_to_level_px
from zenslam.frontend.stereo_matcher import StereoMatchConfig, StereoMatches


def match_stereo(
    left: Features,
    right: Features,
    left_pyramid: list[np.ndarray],
    right_pyramid: list[np.ndarray],
    calibration: PinholeCalibration,
    config: StereoMatchConfig | None = None,
) -> StereoMatches:
    """``zenslam.frontend.stereo_matcher.match_stereo`` as numpy pair arrays (its docstring states the rules)."""
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
    return StereoMatches(*kept_matches(left.px, i_left, i_right, u_right, sad, bf, max_disparity, config))


def kept_matches(
    left_px: np.ndarray,
    i_left: np.ndarray,
    i_right: np.ndarray,
    u_right: np.ndarray,
    sad: np.ndarray,
    bf: float,
    max_disparity: float,
    config: StereoMatchConfig,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(right_u, depth_m, right_index, sad) of the refined matches that pass the disparity range and the SAD outlier rule."""
    n_left = len(left_px)
    right_u = np.full(n_left, -1.0, np.float32)
    depth = np.full(n_left, -1.0, np.float32)
    right_index = np.full(n_left, -1, np.int32)
    sad_out = np.full(n_left, -1.0, np.float32)
    u_right = u_right - config.disparity_offset_px  # the right u the offset's disparity implies
    disparity = left_px[i_left, 0].astype(np.float64) - u_right
    valid = np.isfinite(u_right) & (disparity >= 0) & (disparity < max_disparity)
    i_left, i_right, u_right, sad, disparity = (a[valid] for a in (i_left, i_right, u_right, sad, disparity))
    tiny = disparity <= 0  # ORB-SLAM2 keeps zero disparity as a point at 100 * bf
    disparity[tiny] = 0.01
    u_right[tiny] = left_px[i_left[tiny], 0] - 0.01
    if len(sad):
        threshold = config.outlier_sad_factor * np.sort(sad)[len(sad) // 2]
        inlier = sad <= threshold
        i_left, i_right, u_right, sad, disparity = (a[inlier] for a in (i_left, i_right, u_right, sad, disparity))
    right_u[i_left] = u_right
    depth[i_left] = bf / disparity
    right_index[i_left] = i_right
    sad_out[i_left] = sad
    return right_u, depth, right_index, sad_out


def _best_descriptor_matches(
    left: Features, right: Features, n_rows: int, max_disparity: float, config: StereoMatchConfig
) -> tuple[np.ndarray, np.ndarray]:
    """(left index, right index) of each left keypoint's best ORB match under the threshold.

    A left keypoint's candidates are the right keypoints whose row band (+-row_tolerance * scale of
    their level) holds its row, at a level within level_tolerance of its own, with u in
    [u_left - max_disparity, u_left]. The right keypoints enter a table once per row of their band,
    sorted by (row, level, u), so the candidates at one level are one slice found by binary search.
    """
    n_left, n_right = len(left), len(right)
    n_levels = len(right.scale_factors)
    # u ranks (ties by index): u comparisons with a left keypoint become comparisons of ranks
    u_right = right.px[:, 0]
    by_u = np.argsort(u_right, kind="stable")
    u_rank = np.empty(n_right, np.int64)
    u_rank[by_u] = np.arange(n_right)
    v_right = right.px[:, 1].astype(np.float64)
    band = config.row_tolerance_px * right.scale_factors[right.level]
    first_row = np.clip(np.floor(v_right - band).astype(np.int64), 0, n_rows - 1)
    last_row = np.clip(np.ceil(v_right + band).astype(np.int64), 0, n_rows - 1)
    span = last_row - first_row + 1
    entry_right = np.repeat(np.arange(n_right), span)
    entry_row = np.repeat(first_row, span) + _ranges(span)
    entry_key = (entry_row * n_levels + right.level.astype(np.int64)[entry_right]) * n_right + u_rank[entry_right]
    order = np.argsort(entry_key)  # unique keys: one entry per (right keypoint, row)
    entry_key, entry_right = entry_key[order], entry_right[order]
    # one slice per (left keypoint, level within the tolerance)
    u_left = left.px[:, 0]
    u_sorted = u_right[by_u]
    lo_rank = np.searchsorted(u_sorted, u_left - max_disparity, side="left")  # first right u >= u_left - max_disparity
    hi_rank = np.searchsorted(u_sorted, u_left, side="right")  # past the last right u <= u_left
    row_left = np.clip(left.px[:, 1].astype(np.int64), 0, n_rows - 1)
    level = left.level.astype(np.int64)[:, None] + np.arange(-config.level_tolerance, config.level_tolerance + 1)
    bucket = (row_left[:, None] * n_levels + level) * n_right
    start = np.searchsorted(entry_key, bucket + lo_rank[:, None])
    end = np.searchsorted(entry_key, bucket + hi_rank[:, None])
    count = np.where((level >= 0) & (level < n_levels) & (end > start), end - start, 0).reshape(-1)
    pair_left = np.repeat(np.repeat(np.arange(n_left), level.shape[1]), count)  # grouped by left keypoint
    pair_right = entry_right[np.repeat(start.reshape(-1), count) + _ranges(count)]
    if len(pair_left) == 0:
        return pair_left, pair_right
    distance = hamming_distance_pairs(left.descriptors[pair_left], right.descriptors[pair_right])
    # per left keypoint: lowest distance, then lowest right index
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
    """Sub-pixel right u (level-0 px, NaN if rejected) and best SAD per match.

    Each match's SAD slide runs on the left keypoint's level; the windows of all levels are
    gathered first and their costs computed together.
    """
    w, search = config.sad_half_window_px, config.sad_search_px
    side = 2 * w + 1
    base_shape = left_pyramid[0].shape
    levels = left.level[i_left]
    parts = []
    for level in np.unique(levels).tolist():
        members = np.flatnonzero(levels == level)
        image_left, image_right = left_pyramid[level], right_pyramid[level]
        rows, cols = image_left.shape
        left_level = base_to_level_px(left.px[i_left[members]], image_left.shape, base_shape)
        u_l = np.rint(left_level[:, 0]).astype(np.int64)
        v_l = np.rint(left_level[:, 1]).astype(np.int64)
        to_level = image_right.shape[1] / base_shape[1]
        u_r0 = np.rint((right.px[i_right[members], 0].astype(np.float64) + 0.5) * to_level - 0.5).astype(np.int64)
        inside = (
            (u_r0 - search - w >= 0)
            & (u_r0 + search + w < cols)
            & (u_l - w >= 0)
            & (u_l + w < cols)
            & (v_l - w >= 0)
            & (v_l + w < rows)
        )
        if not inside.any():
            continue
        u_l, v_l, u_r0 = u_l[inside], v_l[inside], u_r0[inside]
        patch = _windows(image_left, v_l - w, u_l - w, side, side)
        strip = _windows(image_right, v_l - w, u_r0 - search - w, side, side + 2 * search)
        to_base = np.full(len(u_r0), base_shape[1] / image_right.shape[1])
        parts.append((members[inside], patch, strip, u_r0, to_base))
    u_right = np.full(len(i_left), np.nan)
    sad = np.full(len(i_left), np.inf)
    if not parts:
        return u_right, sad
    members, patch, strip, u_r0, to_base = (np.concatenate(p) for p in zip(*parts))
    costs = _sad_costs(patch, strip, w, search)
    best = np.argmin(costs, axis=1)
    interior = (best > 0) & (best < 2 * search)
    b = np.clip(best, 1, 2 * search - 1)
    rows_idx = np.arange(len(best))
    c1, c2, c3 = costs[rows_idx, b - 1], costs[rows_idx, b], costs[rows_idx, b + 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = (c1 - c3) / (2.0 * (c1 + c3 - 2.0 * c2))
    ok = interior & np.isfinite(delta) & (np.abs(delta) <= config.max_subpixel_correction_px)
    u_level = u_r0 + (best - search) + delta
    u_base = (u_level + 0.5) * to_base - 0.5  # level_to_base_px of the right level image's u
    u_right[members] = np.where(ok, u_base, np.nan)
    sad[members] = np.where(ok, costs[rows_idx, best], np.inf)
    return u_right, sad


def _sad_costs(patch: np.ndarray, strip: np.ndarray, w: int, search: int) -> np.ndarray:
    """(n, 2 * search + 1) float64 SAD of each left patch (n, side, side) slid along its right strip
    (n, side, side + 2 * search), each window less its centre pixel as ORB-SLAM2 does, to be
    robust to a brightness offset."""
    n, side = len(patch), 2 * w + 1
    patch = patch.astype(np.int16)
    patch -= patch[:, w : w + 1, w : w + 1]
    strip = strip.astype(np.int16)
    costs = np.empty((2 * search + 1, n), np.int32)
    diff = np.empty((n, side, side), np.int16)
    for offset in range(2 * search + 1):  # a loop of whole-batch operations: contiguous rows, no 4-D temporaries
        np.subtract(strip[:, :, offset : offset + side], patch, out=diff)
        diff -= strip[:, w, w + offset][:, None, None]
        np.abs(diff, out=diff)
        np.sum(diff.reshape(n, side * side), axis=1, dtype=np.int32, out=costs[offset])
    return costs.T.astype(np.float64)


def _windows(image: np.ndarray, rows: np.ndarray, cols: np.ndarray, height: int, width: int) -> np.ndarray:
    """(n, height, width) copies of ``image``'s windows whose top-left pixels are (rows, cols)."""
    step_y, step_x = image.strides
    shape = (image.shape[0] - height + 1, image.shape[1] - width + 1, height, width)
    return np.lib.stride_tricks.as_strided(image, shape, (step_y, step_x, step_y, step_x), writeable=False)[rows, cols]


def _ranges(counts: np.ndarray) -> np.ndarray:
    """Concatenated aranges: [0..counts[0]), [0..counts[1]), ... as one int64 array."""
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    ends = np.cumsum(counts)
    offsets = np.repeat(ends - counts, counts)
    return np.arange(total, dtype=np.int64) - offsets
