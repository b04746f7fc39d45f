"""FAST-9/16 corners with OpenCV's test, score and non-maximum suppression, compiled, over windows of an image."""

from __future__ import annotations

import numpy as np

from zenslam.compiled import kernel

_RADIUS = 3  # pixels: the circle's radius; no corner closer than this to its window's edge

# OpenCV's circle of 16 pixels (fast_score.cpp, offsets16) as (dx, dy), in its order.
_CIRCLE = np.array(
    [(0, 3), (1, 3), (2, 2), (3, 1), (3, 0), (3, -1), (2, -2), (1, -3),
     (0, -3), (-1, -3), (-2, -2), (-3, -1), (-3, 0), (-3, 1), (-2, 2), (-1, 3)],
    np.int64,
)  # fmt: skip


def fast_in_windows(image: np.ndarray, windows: np.ndarray, threshold: int) -> tuple[np.ndarray, np.ndarray]:
    """FAST-9/16 corners with non-maximum suppression in each window, as one OpenCV call per window gives.

    ``image`` is a grey uint8 (H, W) array; ``windows`` (M, 4) int rows ``(x0, y0, x1, y1)`` are
    half-open pixel rectangles inside it. For each window this is
    ``cv2.FastFeatureDetector_create(threshold, True, TYPE_9_16).detect(image[y0:y1, x0:x1])``:
    a pixel at least 3 px inside the window is a corner when 9 contiguous pixels of its circle
    are all brighter than it by more than ``threshold`` or all darker by more than it; its score
    is OpenCV's (the largest threshold it stays a corner at), and it is kept when its score is
    strictly greater than its 8 neighbours' (pixels that are not corners, or not candidates of
    this window, score 0). Integer arithmetic only. Returns (K, 2) int32 corners (x, y) in image
    pixels, window after window, each in raster order, and their (K,) int32 scores.
    """
    windows = _checked_windows(windows, image.shape)
    if len(windows) == 0:
        return np.zeros((0, 2), np.int32), np.zeros(0, np.int32)
    x0, y0 = int(windows[:, 0].min()), int(windows[:, 1].min())
    x1, y1 = int(windows[:, 2].max()), int(windows[:, 3].max())
    strength = strength_map(image, (x0, y0, x1, y1))
    xy, score = corners_in_windows(strength, windows - [x0, y0, x0, y0], threshold)
    return xy + np.array([x0, y0], np.int32), score


def strength_map(image: np.ndarray, box: tuple[int, int, int, int]) -> np.ndarray:
    """(y1 - y0, x1 - x0) uint8 FAST strengths of the pixels of ``image[y0:y1, x0:x1]``, ``box`` = (x0, y0, x1, y1).

    A pixel's strength s is the FAST score it has as a corner plus one: it is a corner at
    threshold t exactly when s > t, with OpenCV's score s - 1, whatever t. Pixels closer than
    3 px to the box's edge are 0 (no corner), as in an OpenCV call on that crop; a pixel farther
    in depends only on the pixels within 3 px of it, so every window of the box that holds it
    3 px inside sees the same strength.
    """
    image = np.ascontiguousarray(image, np.uint8)
    (x0, y0, x1, y1) = (int(v) for v in _checked_windows(np.array([box]), image.shape)[0])
    offsets = _CIRCLE[:, 0] + _CIRCLE[:, 1] * image.shape[1]
    return _strengths(image.ravel(), image.shape[1], x0, y0, x1, y1, offsets)


def corners_in_windows(strength: np.ndarray, windows: np.ndarray, threshold: int) -> tuple[np.ndarray, np.ndarray]:
    """FAST corners at ``threshold`` in each window of a ``strength_map``, as ``fast_in_windows`` returns them.

    ``windows`` (M, 4) rows ``(x0, y0, x1, y1)`` are in the map's pixels. A corner of a window is
    a pixel at least 3 px inside it with strength s > threshold; it is kept when every neighbour
    that is a corner of the same window scores less, i.e. has a smaller strength (a neighbour that
    is no corner scores 0, and a kept corner must score above 0: s >= 2).
    """
    windows = _checked_windows(windows, strength.shape)
    threshold = min(max(int(threshold), 0), 255)  # OpenCV clamps it likewise
    return _suppressed(np.ascontiguousarray(strength, np.uint8), windows, threshold)


def fast_in_cells(
    image: np.ndarray,
    box: tuple[int, int, int, int],
    grid: tuple[int, int, int, int],
    thresholds: tuple[int, int],
    tiles_per_row: int,
) -> tuple[np.ndarray, np.ndarray]:
    """ORB-SLAM's per-cell FAST on the region ``box`` = (x0, y0, x1, y1) of ``image``, as the ORB extractor's rule has it.

    FAST(ini) with non-maximum suppression over the whole region (one OpenCV call on the crop);
    then for the cells of ``grid`` = (n_cols, n_rows, w_cell, h_cell) (cell (i, j) detects in
    [3 + j * w_cell, 3 + (j + 1) * w_cell) and likewise in y; the last row and column take the
    corners past them) that hold none of its corners, FAST(min) on their windows (the cell and a 3 px margin,
    replicating the region's last row and column past its edge) tiled into a mosaic
    ``tiles_per_row`` windows wide: one OpenCV call on the mosaic, keeping the corners at least
    3 px inside their own window and inside the region. A margin pixel's score there sees the
    neighbouring tile, so the suppression at a window's margin is the mosaic's, not a per-window
    call's: that is the rule the extractor's keypoints follow. ``thresholds`` = (ini, min).
    Returns (K, 2) int32 corners (x, y) in region pixels, the region's in raster order then the
    mosaic's in its raster order, and their (K,) int32 scores.
    """
    (x0, y0, x1, y1) = (int(v) for v in _checked_windows(np.array([box]), image.shape)[0])
    ini, low = (min(max(int(t), 0), 255) for t in thresholds)  # OpenCV clamps them likewise
    flat = np.ascontiguousarray(image, np.uint8).ravel()
    n_cols, n_rows, w_cell, h_cell = (int(v) for v in grid)
    return _fast_in_cells(flat, image.shape[1], x0, y0, x1 - x0, y1 - y0, n_cols, n_rows, w_cell, h_cell, ini, low, int(tiles_per_row), _CIRCLE)


@kernel
def _fast_in_cells(flat, cols, x0, y0, width, height, n_cols, n_rows, w_cell, h_cell, ini, low, tiles_per_row, circle):
    whole = np.empty((1, 4), np.int64)
    whole[0, 0], whole[0, 1], whole[0, 2], whole[0, 3] = 0, 0, width, height
    strength = _strengths(flat, cols, x0, y0, x0 + width, y0 + height, circle[:, 0] + circle[:, 1] * cols)
    xy, score = _suppressed(strength, whole, ini)
    counts = np.zeros(n_rows * n_cols, np.int64)
    for k in range(len(xy)):
        col = min((xy[k, 0] - _RADIUS) // w_cell, n_cols - 1)
        row = min((xy[k, 1] - _RADIUS) // h_cell, n_rows - 1)
        counts[row * n_cols + col] += 1
    empty = np.flatnonzero(counts == 0)
    n_tiles = len(empty)
    if n_tiles == 0:
        return xy, score
    win_w, win_h = w_cell + 2 * _RADIUS, h_cell + 2 * _RADIUS
    per_row = min(n_tiles, tiles_per_row)
    mosaic_w, mosaic_h = per_row * win_w, (-(-n_tiles // per_row)) * win_h
    mosaic = np.zeros(mosaic_w * mosaic_h, np.uint8)  # tile t at mosaic row t // per_row, column t % per_row
    for t in range(n_tiles):
        cell_y, cell_x = (empty[t] // n_cols) * h_cell, (empty[t] % n_cols) * w_cell
        tile_y, tile_x = (t // per_row) * win_h, (t % per_row) * win_w
        for dy in range(win_h):
            source = (y0 + min(cell_y + dy, height - 1)) * cols + x0  # past the region: its last row and column
            target = (tile_y + dy) * mosaic_w + tile_x
            for dx in range(win_w):
                mosaic[target + dx] = flat[source + min(cell_x + dx, width - 1)]
    mosaic_whole = np.empty((1, 4), np.int64)
    mosaic_whole[0, 0], mosaic_whole[0, 1], mosaic_whole[0, 2], mosaic_whole[0, 3] = 0, 0, mosaic_w, mosaic_h
    mosaic_strength = _strengths(mosaic, mosaic_w, 0, 0, mosaic_w, mosaic_h, circle[:, 0] + circle[:, 1] * mosaic_w)
    tile_xy, tile_score = _suppressed(mosaic_strength, mosaic_whole, low)
    out_xy = np.empty((len(xy) + len(tile_xy), 2), np.int32)
    out_score = np.empty(len(xy) + len(tile_xy), np.int32)
    out_xy[: len(xy)] = xy
    out_score[: len(xy)] = score
    n = len(xy)
    for k in range(len(tile_xy)):
        local_x, local_y = tile_xy[k, 0] % win_w, tile_xy[k, 1] % win_h
        t = (tile_xy[k, 1] // win_h) * per_row + tile_xy[k, 0] // win_w
        if t >= n_tiles or not (_RADIUS <= local_x < win_w - _RADIUS and _RADIUS <= local_y < win_h - _RADIUS):
            continue  # a blank tile past the last cell, or a window's margin
        x = local_x + (empty[t] % n_cols) * w_cell
        y = local_y + (empty[t] // n_cols) * h_cell
        if x >= width - _RADIUS or y >= height - _RADIUS:
            continue  # the replicated pixels past the region
        out_xy[n, 0], out_xy[n, 1] = x, y
        out_score[n] = tile_score[k]
        n += 1
    return out_xy[:n].copy(), out_score[:n].copy()


def _checked_windows(windows: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    windows = np.ascontiguousarray(windows, np.int64).reshape(-1, 4)
    if len(windows) and (
        windows[:, 0].min() < 0
        or windows[:, 1].min() < 0
        or windows[:, 2].max() > shape[1]
        or windows[:, 3].max() > shape[0]
    ):
        raise ValueError(f"FAST windows must lie inside the image of shape {shape}; got boxes {windows.tolist()[:4]}...")
    return windows


@kernel
def _strengths(flat, cols, x0, y0, x1, y1, offsets):
    strength = np.zeros((max(y1 - y0, 0), max(x1 - x0, 0)), np.uint8)
    for y in range(_RADIUS, y1 - y0 - _RADIUS):
        _row_strengths(flat, (y0 + y) * cols + x0, _RADIUS, x1 - x0 - _RADIUS, offsets, strength[y])
    return strength


@kernel
def _suppressed(strength, windows, threshold):
    capacity = 0  # at most one corner per candidate pixel (np.empty only reserves the pages)
    for w in range(len(windows)):
        capacity += max(windows[w, 2] - windows[w, 0] - 2 * _RADIUS, 0) * max(windows[w, 3] - windows[w, 1] - 2 * _RADIUS, 0)
    xy = np.empty((capacity, 2), np.int32)
    score = np.empty(capacity, np.int32)
    n = 0
    for w in range(len(windows)):
        # the window's candidates: [cx0, cx1) x [cy0, cy1); their neighbours outside it score 0
        cx0, cy0 = windows[w, 0] + _RADIUS, windows[w, 1] + _RADIUS
        cx1, cy1 = windows[w, 2] - _RADIUS, windows[w, 3] - _RADIUS
        floor = max(threshold, 1)  # kept corners have s > threshold and a score s - 1 > 0
        for y in range(cy0, cy1):
            row, up, down = strength[y], strength[y - 1], strength[y + 1]
            # unsigned column indices: no wraparound test in the scan over every pixel
            for ux in range(np.uint64(max(cx0, 0)), np.uint64(max(cx1, 0))):
                s = row[ux]
                if s <= floor:
                    continue
                x = np.int64(ux)
                # neighbours clamped into the window: a repeated pixel does not change a maximum,
                # but the pixel itself (s) must stay out of its own row's
                x_lo, x_hi = max(x - 1, cx0), min(x + 1, cx1 - 1)
                left = row[x - 1] if x > cx0 else np.uint8(0)
                right = row[x + 1] if x < cx1 - 1 else np.uint8(0)
                above = max(up[x_lo], up[x], up[x_hi]) if y > cy0 else np.uint8(0)
                below = max(down[x_lo], down[x], down[x_hi]) if y < cy1 - 1 else np.uint8(0)
                neighbours = max(left, right, above, below)  # the largest strength of the window's 8 neighbours
                if neighbours >= s:
                    continue
                xy[n, 0] = x
                xy[n, 1] = y
                score[n] = s - 1
                n += 1
    return xy[:n].copy(), score[:n].copy()


@kernel
def _row_strengths(flat, base, x_start, x_stop, offsets, out):
    """out[x] = the FAST strength of the pixel flat[base + x] for x in [x_start, x_stop): see ``strength_map``.

    A pixel is a corner at threshold t when some arc of 9 contiguous circle pixels is all darker
    than it by more than t (the arc's brightest pixel is) or all brighter (its darkest is). So it
    is a corner exactly when max(A, B) > t, where A = centre - (the smallest over the 16 arcs of
    the arc's largest pixel) and B = (the largest arc minimum) - centre; and cornerScore<16>'s
    a0/b0 loops compute max(t, A, B) - 1, max(A, B) - 1 for a corner. Arc extremes come from
    pairs, then fours, eights and nines of neighbours. Unsigned bytes throughout (numba widens
    integer arithmetic to 64 bits; min, max and comparisons of bytes stay bytes) and unsigned
    indices (numba's negative-index wraparound would keep LLVM from vectorising): LLVM runs it
    32 pixels at a time.
    """
    c = np.uint64(base)
    s0, s1, s2, s3 = np.uint64(base + offsets[0]), np.uint64(base + offsets[1]), np.uint64(base + offsets[2]), np.uint64(base + offsets[3])
    s4, s5, s6, s7 = np.uint64(base + offsets[4]), np.uint64(base + offsets[5]), np.uint64(base + offsets[6]), np.uint64(base + offsets[7])
    s8, s9, s10, s11 = np.uint64(base + offsets[8]), np.uint64(base + offsets[9]), np.uint64(base + offsets[10]), np.uint64(base + offsets[11])
    s12, s13, s14, s15 = np.uint64(base + offsets[12]), np.uint64(base + offsets[13]), np.uint64(base + offsets[14]), np.uint64(base + offsets[15])
    for x in range(np.uint64(x_start), np.uint64(x_stop)):
        v = flat[c + x]
        p0, p1, p2, p3 = flat[s0 + x], flat[s1 + x], flat[s2 + x], flat[s3 + x]
        p4, p5, p6, p7 = flat[s4 + x], flat[s5 + x], flat[s6 + x], flat[s7 + x]
        p8, p9, p10, p11 = flat[s8 + x], flat[s9 + x], flat[s10 + x], flat[s11 + x]
        p12, p13, p14, p15 = flat[s12 + x], flat[s13 + x], flat[s14 + x], flat[s15 + x]
        # a_k, b_k: the largest of the 2 and 4 circle pixels from k on; an arc k..k+8 is b_k, b_{k+4}, p_{k+8}
        a0, a1, a2, a3 = max(p0, p1), max(p1, p2), max(p2, p3), max(p3, p4)
        a4, a5, a6, a7 = max(p4, p5), max(p5, p6), max(p6, p7), max(p7, p8)
        a8, a9, a10, a11 = max(p8, p9), max(p9, p10), max(p10, p11), max(p11, p12)
        a12, a13, a14, a15 = max(p12, p13), max(p13, p14), max(p14, p15), max(p15, p0)
        b0, b1, b2, b3 = max(a0, a2), max(a1, a3), max(a2, a4), max(a3, a5)
        b4, b5, b6, b7 = max(a4, a6), max(a5, a7), max(a6, a8), max(a7, a9)
        b8, b9, b10, b11 = max(a8, a10), max(a9, a11), max(a10, a12), max(a11, a13)
        b12, b13, b14, b15 = max(a12, a14), max(a13, a15), max(a14, a0), max(a15, a1)
        darkest_arc = min(
            min(max(b0, b4, p8), max(b1, b5, p9), max(b2, b6, p10), max(b3, b7, p11)),
            min(max(b4, b8, p12), max(b5, b9, p13), max(b6, b10, p14), max(b7, b11, p15)),
            min(max(b8, b12, p0), max(b9, b13, p1), max(b10, b14, p2), max(b11, b15, p3)),
            min(max(b12, b0, p4), max(b13, b1, p5), max(b14, b2, p6), max(b15, b3, p7)),
        )
        a0, a1, a2, a3 = min(p0, p1), min(p1, p2), min(p2, p3), min(p3, p4)
        a4, a5, a6, a7 = min(p4, p5), min(p5, p6), min(p6, p7), min(p7, p8)
        a8, a9, a10, a11 = min(p8, p9), min(p9, p10), min(p10, p11), min(p11, p12)
        a12, a13, a14, a15 = min(p12, p13), min(p13, p14), min(p14, p15), min(p15, p0)
        b0, b1, b2, b3 = min(a0, a2), min(a1, a3), min(a2, a4), min(a3, a5)
        b4, b5, b6, b7 = min(a4, a6), min(a5, a7), min(a6, a8), min(a7, a9)
        b8, b9, b10, b11 = min(a8, a10), min(a9, a11), min(a10, a12), min(a11, a13)
        b12, b13, b14, b15 = min(a12, a14), min(a13, a15), min(a14, a0), min(a15, a1)
        brightest_arc = max(
            max(min(b0, b4, p8), min(b1, b5, p9), min(b2, b6, p10), min(b3, b7, p11)),
            max(min(b4, b8, p12), min(b5, b9, p13), min(b6, b10, p14), min(b7, b11, p15)),
            max(min(b8, b12, p0), min(b9, b13, p1), min(b10, b14, p2), min(b11, b15, p3)),
            max(min(b12, b0, p4), min(b13, b1, p5), min(b14, b2, p6), min(b15, b3, p7)),
        )
        dark = v - min(v, darkest_arc)  # A, or 0 when negative: no corner at any threshold then
        bright = brightest_arc - min(brightest_arc, v)
        out[x] = max(dark, bright)

