"""FAST-9/16 corners with OpenCV's test, score and non-maximum suppression, compiled, over windows of an image."""

from __future__ import annotations

import numpy as np

from zenslam.compiled import kernel

_RADIUS = 3  # pixels: the circle's radius; no corner closer than this to its window's edge

# OpenCV's circle of 16 pixels (fast_score.cpp, offsets16) as (dx, dy), in its order: the score
# reads arcs of this sequence, so the order is part of the result.
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
    image = np.ascontiguousarray(image, np.uint8)
    windows = np.ascontiguousarray(windows, np.int64).reshape(-1, 4)
    if len(windows) and (
        windows[:, 0].min() < 0
        or windows[:, 1].min() < 0
        or windows[:, 2].max() > image.shape[1]
        or windows[:, 3].max() > image.shape[0]
    ):
        raise ValueError(f"FAST windows must lie inside the image of shape {image.shape}")
    threshold = min(max(int(threshold), 0), 255)  # OpenCV clamps it likewise
    offsets = _CIRCLE[:, 0] + _CIRCLE[:, 1] * image.shape[1]
    return _fast_windows(image.ravel(), image.shape[1], windows, threshold, offsets)


@kernel
def _fast_windows(flat, cols, windows, threshold, offsets):
    capacity = 1024
    xy = np.empty((capacity, 2), np.int32)
    score = np.empty(capacity, np.int32)
    n = 0
    max_h = 0
    max_w = 0
    for w in range(len(windows)):
        max_w = max(max_w, windows[w, 2] - windows[w, 0])
        max_h = max(max_h, windows[w, 3] - windows[w, 1])
    scores = np.zeros((max_h, max_w), np.uint8)  # the window's scores; 0 off its candidates
    for w in range(len(windows)):
        x0, y0, x1, y1 = windows[w, 0], windows[w, 1], windows[w, 2], windows[w, 3]
        h, wd = y1 - y0, x1 - x0
        if h < 2 * _RADIUS + 1 or wd < 2 * _RADIUS + 1:
            continue
        scores[:h, :wd] = 0
        for y in range(_RADIUS, h - _RADIUS):
            _row_scores(flat, (y0 + y) * cols + x0, _RADIUS, wd - _RADIUS, threshold, offsets, scores[y])
        for y in range(_RADIUS, h - _RADIUS):
            for x in range(_RADIUS, wd - _RADIUS):
                s = scores[y, x]
                if s == 0:
                    continue
                if not (
                    s > scores[y, x - 1] and s > scores[y, x + 1]
                    and s > scores[y - 1, x - 1] and s > scores[y - 1, x] and s > scores[y - 1, x + 1]
                    and s > scores[y + 1, x - 1] and s > scores[y + 1, x] and s > scores[y + 1, x + 1]
                ):  # fmt: skip
                    continue
                if n == capacity:
                    capacity *= 2
                    xy = _grown(xy, capacity)
                    score = _grown(score, capacity)
                xy[n, 0] = x0 + x
                xy[n, 1] = y0 + y
                score[n] = s
                n += 1
    return xy[:n].copy(), score[:n].copy()


@kernel
def _grown(array, capacity):
    out = np.empty((capacity,) + array.shape[1:], array.dtype)
    out[: len(array)] = array
    return out


@kernel
def _row_scores(flat, base, x_start, x_stop, threshold, offsets, out):
    """out[x] = OpenCV's FAST score of the pixel flat[base + x] if it is a corner, else 0, for x in [x_start, x_stop).

    A pixel is a corner when some arc of 9 contiguous circle pixels is all darker than it by more
    than the threshold (the arc's brightest pixel is) or all brighter (its darkest is).
    cornerScore<16>'s a0/b0 loops compute max(threshold, A, B) - 1, where A is the largest over
    the 16 arcs of the arc's smallest centre-minus-pixel difference and B the same for
    pixel-minus-centre: the corner's score is max(A, B) - 1, and A = centre - (the smallest over
    the arcs of the arc's largest pixel), B = (the largest arc minimum) - centre. Arc extremes
    come from pairs, then fours, eights and nines of neighbours. Unsigned bytes throughout (numba
    widens integer arithmetic to 64 bits; min, max and comparisons of bytes stay bytes) and
    unsigned indices (numba's negative-index wraparound would keep LLVM from vectorising):
    LLVM runs it 32 pixels at a time.
    """
    t = np.uint8(threshold)
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
        dark = v - min(v, darkest_arc)
        bright = brightest_arc - min(brightest_arc, v)
        s = max(dark, bright)
        out[x] = (s - np.uint8(1)) if s > t else np.uint8(0)  # a score-0 corner never survives NMS

