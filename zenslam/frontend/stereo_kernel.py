"""Stereo matching of ORB keypoints, compiled: row-band descriptor search, SAD refinement, disparity rules.

``stereo_matcher.match_stereo`` states the rules; these kernels apply them one left keypoint at a
time, as ORB-SLAM2's Frame::ComputeStereoMatches does, instead of numpy's sorted pair arrays.
Every choice is an integer comparison or an IEEE operation on the caller's numbers in the order
the rules give (no fastmath), so the result is the same on any x86-64 CPU.
"""

from __future__ import annotations

import numpy as np

from zenslam.compiled import kernel
from zenslam.descriptor_words import popcount


@kernel
def best_descriptor_matches(
    left_px, left_level, left_words, u_low, right_px, right_level, right_words, scale_factors,
    n_rows, row_tolerance, level_tolerance, max_distance,
):  # fmt: skip
    """(left index, right index) of each left keypoint's best ORB match below ``max_distance`` bits.

    Candidates of left keypoint i: the right keypoints whose row band (their row +-row_tolerance *
    scale of their level, floored and ceiled, clipped to the image) holds i's row (its v truncated),
    at a level within level_tolerance of i's, with u in [u_low[i], u_i]. The best is the lowest
    distance, then the lowest right index. ``*_words`` are the descriptors as (N, 4) uint64.
    """
    n_left, n_right = len(left_px), len(right_px)
    # right keypoints by row of their band (CSR), ascending index within a row
    first_row = np.empty(n_right, np.int64)
    last_row = np.empty(n_right, np.int64)
    row_count = np.zeros(n_rows + 1, np.int64)
    for j in range(n_right):
        v = np.float64(right_px[j, 1])
        band = row_tolerance * scale_factors[right_level[j]]
        first_row[j] = min(max(np.int64(np.floor(v - band)), 0), n_rows - 1)
        last_row[j] = min(max(np.int64(np.ceil(v + band)), 0), n_rows - 1)
        for row in range(first_row[j], last_row[j] + 1):
            row_count[row + 1] += 1
    row_start = np.cumsum(row_count)
    fill = row_start[:-1].copy()
    by_row = np.empty(row_start[-1], np.int64)
    for j in range(n_right):
        for row in range(first_row[j], last_row[j] + 1):
            by_row[fill[row]] = j
            fill[row] += 1

    i_left = np.empty(n_left, np.int64)
    i_right = np.empty(n_left, np.int64)
    n_found = 0
    for i in range(n_left):
        row = min(max(np.int64(left_px[i, 1]), 0), n_rows - 1)
        u_high = left_px[i, 0]
        best_distance = np.int64(max_distance)  # only a distance below it is kept
        best = -1
        for slot in range(row_start[row], row_start[row + 1]):
            j = by_row[slot]
            if abs(np.int64(right_level[j]) - np.int64(left_level[i])) > level_tolerance:
                continue
            if not (right_px[j, 0] >= u_low[i] and right_px[j, 0] <= u_high):
                continue
            distance = np.int64(0)
            for w in range(4):
                distance += popcount(left_words[i, w] ^ right_words[j, w])
            if distance < best_distance:  # ascending j: a tie keeps the lower index
                best_distance = distance
                best = j
        if best >= 0:
            i_left[n_found] = i
            i_right[n_found] = best
            n_found += 1
    return i_left[:n_found], i_right[:n_found]


@kernel
def refine_level_by_sad(
    image_left, image_right, level, left_px, left_level, right_px, i_left, i_right,
    left_to_level_u, left_to_level_v, right_to_level_u, right_to_base_u,
    half_window, search, max_correction, u_right, sad,
):  # fmt: skip
    """Sub-pixel right u (level-0 px) and SAD cost of the matches whose left keypoint is at ``level``.

    Writes ``u_right[k]`` and ``sad[k]`` of each match k = (i_left[k], i_right[k]) at that level
    whose SAD slide fits in both images and whose parabola fit is interior and within
    ``max_correction`` level pixels; leaves the others as the caller set them. The window around
    the left keypoint (level pixels, rounded) slides +-search around the right keypoint's u, each
    window less its centre pixel; the parabola goes through the lowest cost and its neighbours.
    ``*_to_level_*`` and ``right_to_base_u`` are the level/level-0 size ratios of the images.
    """
    rows = min(image_left.shape[0], image_right.shape[0])
    cols_left, cols_right = image_left.shape[1], image_right.shape[1]
    w = half_window
    n_offsets = 2 * search + 1
    side = 2 * w + 1
    strip_width = side + 2 * search
    patch = np.empty((side, side), np.int32)
    strip = np.empty((side, strip_width), np.int32)
    centres = np.empty(n_offsets, np.int32)
    costs = np.empty(n_offsets, np.int32)  # at most 121 * 510 for the default window
    for k in range(len(i_left)):
        if left_level[i_left[k]] != level:
            continue
        u_l = np.int64(np.rint((np.float64(left_px[i_left[k], 0]) + 0.5) * left_to_level_u - 0.5))
        v_l = np.int64(np.rint((np.float64(left_px[i_left[k], 1]) + 0.5) * left_to_level_v - 0.5))
        u_r0 = np.int64(np.rint((np.float64(right_px[i_right[k], 0]) + 0.5) * right_to_level_u - 0.5))
        # the rule's bounds use the left image's width; the right strip must lie in the right image too
        cols = min(cols_left, cols_right)
        if not (u_r0 - search - w >= 0 and u_r0 + search + w < cols and u_l - w >= 0 and u_l + w < cols_left):
            continue
        if not (v_l - w >= 0 and v_l + w < rows):
            continue
        # the left window less its centre, and the right strip, as int32 copies: the slide's
        # loops then run over small contiguous arrays with indices known to be in range
        centre_left = np.int32(image_left[v_l, u_l])
        for y in range(side):
            row_left = image_left[v_l - w + y]
            row_right = image_right[v_l - w + y]
            for x in range(side):
                patch[y, x] = np.int32(row_left[u_l - w + x]) - centre_left
            for x in range(strip_width):
                strip[y, x] = np.int32(row_right[u_r0 - search - w + x])
        # SAD of the window at every offset at once, offsets innermost: integer sums, so the
        # order of the additions does not change them
        for offset in range(n_offsets):
            centres[offset] = strip[w, w + offset]
            costs[offset] = 0
        for y in range(side):
            for x in range(side):
                value = patch[y, x]
                for offset in range(n_offsets):
                    costs[offset] += abs(strip[y, offset + x] - centres[offset] - value)
        best = 0
        for offset in range(1, n_offsets):
            if costs[offset] < costs[best]:  # the first lowest cost, as argmin
                best = offset
        if not (0 < best < 2 * search):
            continue
        c1, c2, c3 = np.float64(costs[best - 1]), np.float64(costs[best]), np.float64(costs[best + 1])
        denominator = 2.0 * (c1 + c3 - 2.0 * c2)
        if denominator == 0.0:  # the parabola's correction would be infinite or undefined
            continue
        delta = (c1 - c3) / denominator
        if not abs(delta) <= max_correction:
            continue
        u_level = np.float64(u_r0 + (best - search)) + delta
        u_right[k] = (u_level + 0.5) * right_to_base_u - 0.5
        sad[k] = c2


@kernel
def keep_matches(
    left_px, i_left, i_right, u_right, sad, disparity_offset, max_disparity, outlier_factor, bf,
    right_u_out, depth_out, right_index_out, sad_out,
):  # fmt: skip
    """Write the matches that pass the disparity range and the SAD outlier rule into the (N,) outputs.

    A match keeps u_right - disparity_offset if its disparity (left u minus that) is in
    [0, max_disparity); a zero disparity becomes 0.01 px (float32 u_left - 0.01, as numpy computes
    it on the float32 keypoints). Of those, a match whose SAD exceeds outlier_factor times the
    middle SAD (the upper median of an even count) is dropped. Depth is bf / disparity.
    """
    n = len(i_left)
    u_kept = np.empty(n, np.float64)
    disparity_kept = np.empty(n, np.float64)
    keep = np.empty(n, np.int64)
    n_kept = 0
    for k in range(n):
        u = u_right[k] - disparity_offset
        disparity = np.float64(left_px[i_left[k], 0]) - u
        if not (np.isfinite(u) and disparity >= 0 and disparity < max_disparity):
            continue
        if disparity <= 0:
            disparity = 0.01
            u = np.float64(left_px[i_left[k], 0] - np.float32(0.01))
        u_kept[n_kept] = u
        disparity_kept[n_kept] = disparity
        keep[n_kept] = k
        n_kept += 1
    if n_kept == 0:
        return 0
    sad_kept = np.empty(n_kept, np.float64)
    for m in range(n_kept):
        sad_kept[m] = sad[keep[m]]
    threshold = outlier_factor * np.sort(sad_kept)[n_kept // 2]
    n_inliers = 0
    for m in range(n_kept):
        if not sad_kept[m] <= threshold:
            continue
        i = i_left[keep[m]]
        right_u_out[i] = u_kept[m]
        depth_out[i] = bf / disparity_kept[m]
        right_index_out[i] = i_right[keep[m]]
        sad_out[i] = sad_kept[m]
        n_inliers += 1
    return n_inliers
