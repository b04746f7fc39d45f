"""rBRIEF, the ORB descriptor: 256 intensity tests on the blurred level image, steered by the keypoint's angle, compiled."""

from __future__ import annotations

import math

import cv2
import numpy as np

from zenslam.compiled import kernel
from zenslam.errors import ZenslamError

DESCRIPTOR_BYTES = 32  # 256 tests, test i is bit i % 8 of byte i // 8
BORDER_PX = 19  # level pixels: a keypoint's rounded centre stays this far inside, so every steered test fits
_N_POINTS = 16 * DESCRIPTOR_BYTES  # two pattern points per test
_DEG_TO_RAD = np.float32(math.pi / 180.0)  # OpenCV's (float)(CV_PI/180.f): the product is taken in float32
_PATCH_SIZE = 31  # level pixels: the patch OpenCV's fixed pattern is made for

# Reading the pattern back: step images (dark left of _STEP_X, bright from it, and the reverse) with
# keypoints on one row at every column within _SWEEP_PX of the step, at the angles below. A test
# whose two points land at different columns u0 < u1 fires exactly while the step separates them,
# which gives both columns; at 0 degrees the column is the point's x, at 90 degrees -y, and the other
# angles separate the points that share an x or a y.
_STEP_X = 48  # level pixels: column of the probe images' step
_SWEEP_PX = 24  # level pixels: |column offset| of the probe keypoints; steered points reach 19
_PROBE_SIZE = (40, 2 * _STEP_X)  # rows, columns
_PROBE_ANGLES_DEG = (0, 90, 15, 30, 45, 60, 75, 105, 120, 135, 150, 165, 200, 250, 290, 340)
_GRID_PX = 15  # level pixels: pattern coordinates are searched in [-15, 15] (the 31 px patch)


def describe(image: np.ndarray, xy: np.ndarray, angle_deg: np.ndarray, pattern: np.ndarray) -> np.ndarray:
    """(K, 32) uint8 rBRIEF descriptors of (K, 2) level pixels ``xy`` with orientations ``angle_deg`` (degrees).

    ``image`` is the grey uint8 level image, ``pattern`` the ``rbrief_pattern``: ``describe_blurred``
    on the image smoothed by ``blur``. Every rounded centre must lie BORDER_PX inside the image
    (IndexError).
    """
    if len(xy) == 0:
        return np.zeros((0, DESCRIPTOR_BYTES), np.uint8)
    return describe_blurred(blur(image), xy, angle_deg, pattern)


def blur(image: np.ndarray) -> np.ndarray:
    """The image smoothed for the tests: ORB's 7x7, sigma 2 Gaussian (BORDER_REFLECT_101) as ORB.compute
    applies it, compiled, with the bits of OpenCV's SSE baseline path on every CPU.

    ORB.compute (and ORB-SLAM) blur a view into a border-extended copy of the image, where
    GaussianBlur takes the separable filter with OpenCV's float32 Gaussian taps. Its AVX2 path fuses
    multiplies and adds, so it rounds some pixels to another grey level than its baseline path
    (CPUs without AVX2) and the descriptors, and lockstep runs, depended on the CPU: the stages
    pinned OpenCV to its baseline, which slowed the whole extraction (benchmarks/frontend.md). ``_separable_blur`` is
    that baseline filter in float32 operations none of which fuse (fastmath is off), so it gives
    its bits on any target (tests/frontend/test_orb_descriptor.py compares them).
    """
    return _separable_blur(np.ascontiguousarray(image, np.uint8), _GAUSSIAN_TAPS)


# OpenCV's getGaussianKernel(7, 2.0, CV_32F): 7 float32 taps summing to 1.
_GAUSSIAN_TAPS = cv2.getGaussianKernel(7, 2.0, cv2.CV_32F).ravel().astype(np.float32)


@kernel
def _separable_blur(image, taps):
    """(H, W) uint8: the rows filtered with the 7 taps in order (float32 sums from the first tap), then
    the columns as a symmetric filter (the centre tap, then each pair of rows summed before its tap),
    rounded half to even and saturated: OpenCV's RowFilter and SymmColumnFilter on its baseline path.
    Each pass runs over a padded row at a time (the reflected border columns written apart), so its
    loops over columns have no branch and vectorise (across pixels; each pixel's sum keeps its order)."""
    rows, cols = image.shape
    filtered = np.empty((rows + 6, cols), np.float32)  # rows -3 .. rows + 2, reflected
    padded = np.empty(cols + 6, np.float32)  # columns -3 .. cols + 2, BORDER_REFLECT_101
    t0, t1, t2, t3, t4, t5, t6 = taps[0], taps[1], taps[2], taps[3], taps[4], taps[5], taps[6]
    for y in range(rows):
        source = image[y]
        for k in range(3):
            padded[k] = np.float32(source[3 - k])
            padded[cols + 3 + k] = np.float32(source[cols - 2 - k])
        for x in range(cols):
            padded[x + 3] = np.float32(source[x])
        row = filtered[y + 3]
        for x in range(cols):
            s = t0 * padded[x]
            s = s + t1 * padded[x + 1]
            s = s + t2 * padded[x + 2]
            s = s + t3 * padded[x + 3]
            s = s + t4 * padded[x + 4]
            s = s + t5 * padded[x + 5]
            s = s + t6 * padded[x + 6]
            row[x] = s
    for k in range(1, 4):
        filtered[3 - k] = filtered[3 + k]
        filtered[rows + 2 + k] = filtered[rows + 2 - k]
    out = np.empty((rows, cols), np.uint8)
    black, white = np.float32(0.0), np.float32(255.0)
    for y in range(rows):
        c, u1, d1, u2, d2, u3, d3 = filtered[y + 3], filtered[y + 2], filtered[y + 4], filtered[y + 1], filtered[y + 5], filtered[y], filtered[y + 6]
        target = out[y]
        for x in range(cols):
            s = t3 * c[x]
            s = s + t4 * (u1[x] + d1[x])
            s = s + t5 * (u2[x] + d2[x])
            s = s + t6 * (u3[x] + d3[x])
            target[x] = np.uint8(min(max(np.rint(s), black), white))
    return out


def describe_blurred(blurred: np.ndarray, xy: np.ndarray, angle_deg: np.ndarray, pattern: np.ndarray) -> np.ndarray:
    """(K, 32) uint8 rBRIEF descriptors on an already smoothed level image: the bytes of OpenCV's
    computeOrbDescriptors (WTA_K = 2), the pattern rotated in float32 and rounded half to even, a
    test's bit set when its first point is darker than its second."""
    if len(xy) == 0:
        return np.zeros((0, DESCRIPTOR_BYTES), np.uint8)
    xy32 = np.ascontiguousarray(xy, np.float32)  # a cv2.KeyPoint holds float32: the centre is rounded from that
    angle32 = np.ascontiguousarray(angle_deg, np.float32)
    blurred = np.ascontiguousarray(blurred)
    return _descriptors(blurred, xy32, angle32, np.ascontiguousarray(pattern[:, 0]), np.ascontiguousarray(pattern[:, 1]))


@kernel
def _descriptors(blurred, xy, angle_deg, pattern_x, pattern_y):
    """(K, 32) uint8: OpenCV's computeOrbDescriptors (WTA_K = 2) on the blurred image.

    Each keypoint's 512 steered points are rounded to pixel offsets in one pass (which vectorises),
    then its 256 tests read them.
    """
    rows, cols = blurred.shape
    pixels = blurred.ravel()  # C-contiguous: a view
    out = np.empty((len(xy), DESCRIPTOR_BYTES), np.uint8)
    offsets = np.empty(len(pattern_x), np.int32)  # int32 arithmetic vectorises on any x86-64 target
    for k in range(len(xy)):
        cx = np.int64(np.rint(xy[k, 0]))
        cy = np.int64(np.rint(xy[k, 1]))
        if not (BORDER_PX <= cx < cols - BORDER_PX and BORDER_PX <= cy < rows - BORDER_PX):
            raise IndexError("keypoint closer than 19 px to the image border")
        angle = angle_deg[k] * _DEG_TO_RAD
        # OpenCV's (float)cos(angle) of the float angle: the double cosine rounded once to float32.
        a = np.float32(math.cos(np.float64(angle)))
        b = np.float32(math.sin(np.float64(angle)))
        centre = np.int32(cy * cols + cx)
        step = np.int32(cols)
        for i in range(len(pattern_x)):
            # float32 products and differences, none fused (fastmath is off): the roundings of OpenCV's C++
            x = pattern_x[i] * a - pattern_y[i] * b
            y = pattern_x[i] * b + pattern_y[i] * a
            offsets[i] = centre + np.int32(np.rint(y)) * step + np.int32(np.rint(x))
        for byte in range(DESCRIPTOR_BYTES):
            value = 0
            for bit in range(8):
                i = 16 * byte + 2 * bit
                value |= np.int64(pixels[offsets[i]] < pixels[offsets[i + 1]]) << bit
            out[k, byte] = value
    return out


def rbrief_pattern() -> np.ndarray:
    """(512, 2) float32 pattern points (x, y) in level pixels: OpenCV's ORB pattern for 31 px patches.

    Test i compares points 2i and 2i + 1. The points are read back from the installed OpenCV through
    ORB.compute on probe images (a few milliseconds), so the tests are exactly the ones OpenCV makes;
    the result is then checked against ORB.compute on a textured image at many angles.
    """
    angles = np.asarray(_PROBE_ANGLES_DEG, np.float32)
    columns = _STEP_X + np.arange(-_SWEEP_PX, _SWEEP_PX + 1)
    rising = np.zeros(_PROBE_SIZE, np.uint8)
    rising[:, _STEP_X:] = 255
    grid = np.stack(np.meshgrid(np.arange(-_GRID_PX, _GRID_PX + 1), np.arange(-_GRID_PX, _GRID_PX + 1)), -1).reshape(-1, 2)
    grid_columns = _steered_columns(grid.astype(np.float32), angles)  # (angles, grid points)
    columns_seen = [_step_columns(image, angles, columns) for image in (rising, 255 - rising)]
    u0 = np.where(columns_seen[0][2], columns_seen[0][0], columns_seen[1][0])  # (angles, tests)
    u1 = np.where(columns_seen[0][2], columns_seen[0][1], columns_seen[1][1])
    apart = columns_seen[0][2] | columns_seen[1][2]
    if np.any(columns_seen[0][2] & columns_seen[1][2]):
        raise ZenslamError("ORB pattern probe: a test fired on both step directions; OpenCV's ORB is not the one expected")
    first = _matching_points(grid_columns, u0, apart)
    second = _matching_points(grid_columns, u1, apart)
    pattern = np.empty((_N_POINTS, 2), np.float32)
    for test in range(_N_POINTS // 2):
        pairs = [
            (g0, g1)
            for g0 in np.flatnonzero(first[test])
            for g1 in np.flatnonzero(second[test])
            if np.array_equal(grid_columns[~apart[:, test], g0], grid_columns[~apart[:, test], g1])
        ]
        if len(pairs) != 1:
            raise ZenslamError(f"ORB pattern probe: test {test} matches {len(pairs)} point pairs, not one")
        pattern[2 * test], pattern[2 * test + 1] = grid[pairs[0][0]], grid[pairs[0][1]]
    _check_pattern(pattern)
    return pattern


def _steered_columns(points: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """(angles, points) int64 column offsets of the points steered by each angle, as ``_descriptors`` rounds them."""
    radians = angles * _DEG_TO_RAD
    a = np.array([math.cos(float(r)) for r in radians], np.float32)[:, None]
    b = np.array([math.sin(float(r)) for r in radians], np.float32)[:, None]
    return np.rint(points[:, 0] * a - points[:, 1] * b).astype(np.int64)


def _step_columns(image: np.ndarray, angles: np.ndarray, columns: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each test's two steered columns (angles, tests), and where the step told them (the test fired somewhere).

    The blurred step is constant up to column ``flat_end``, strictly monotone to ``flat_start``, constant
    after. A test fires where its brighter-side point is past ``flat_end`` and its other point before
    ``flat_start``: on a rising step for the keypoint columns [flat_end + 1 - u1, flat_start - 1 - u0],
    on a falling one [flat_end + 1 - u0, flat_start - 1 - u1].
    """
    profile = _orb_compute_blur(image)[_PROBE_SIZE[0] // 2].astype(np.int64)
    change = np.flatnonzero(np.diff(profile))
    flat_end, flat_start = int(change[0]), int(change[-1]) + 1
    if not np.all(np.diff(np.sign(np.diff(profile[flat_end : flat_start + 1]))) == 0):
        raise ZenslamError("ORB pattern probe: the blurred step is not monotone")
    fired = _orb_tests(image, np.repeat(columns[None, :], len(angles), 0), np.repeat(angles[:, None], len(columns), 1))
    fired = fired.reshape(len(angles), len(columns), -1)  # (angles, keypoint columns, tests)
    told = fired.any(axis=1)
    low = columns[np.argmax(fired, axis=1)]
    high = columns[len(columns) - 1 - np.argmax(fired[:, ::-1], axis=1)]
    if not np.array_equal(fired.sum(axis=1), np.where(told, high - low + 1, 0)):
        raise ZenslamError("ORB pattern probe: a test fired on columns that are not one interval")
    from_first, from_last = flat_end + 1 - low, flat_start - 1 - high
    return (from_last, from_first, told) if profile[-1] > profile[0] else (from_first, from_last, told)


def _orb_compute_blur(image: np.ndarray) -> np.ndarray:
    """The blur ORB.compute applies inside: GaussianBlur on a view into a border-extended copy, which
    takes the separable filter with float32 taps (not ``blur``'s fixed-point one)."""
    return cv2.sepFilter2D(image, -1, _GAUSSIAN_TAPS, _GAUSSIAN_TAPS, borderType=cv2.BORDER_REFLECT_101)


def _orb_tests(image: np.ndarray, columns: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """(K, 256) bool: OpenCV's ORB.compute tests at keypoints on the middle row of ``image``."""
    row = _PROBE_SIZE[0] // 2
    keypoints = [cv2.KeyPoint(float(x), float(row), _PATCH_SIZE, float(angle)) for x, angle in zip(columns.ravel(), angles.ravel())]
    return _unpack(_orb_compute(image, keypoints))


def _orb_compute(image: np.ndarray, keypoints: list[cv2.KeyPoint]) -> np.ndarray:
    orb = cv2.ORB_create(nfeatures=len(keypoints), nlevels=1, edgeThreshold=BORDER_PX, patchSize=_PATCH_SIZE, WTA_K=2)
    kept, descriptors = orb.compute(image, keypoints)
    if descriptors is None or len(kept) != len(keypoints):
        raise ZenslamError("ORB pattern probe: ORB.compute dropped probe keypoints")
    return descriptors


def _unpack(descriptors: np.ndarray) -> np.ndarray:
    return np.unpackbits(descriptors, axis=1, bitorder="little").astype(bool)


def _matching_points(grid_columns: np.ndarray, columns: np.ndarray, told: np.ndarray) -> np.ndarray:
    """(tests, grid points) bool: the grid points steered to the told column at every angle where one was told."""
    agree = np.ones((columns.shape[1], grid_columns.shape[1]), bool)
    for angle in range(len(grid_columns)):  # one angle at a time: small int8 comparisons
        seen = np.flatnonzero(told[angle])
        agree[seen] &= grid_columns[angle].astype(np.int8) == columns[angle, seen, None].astype(np.int8)
    return agree


def _check_pattern(pattern: np.ndarray) -> None:
    """``describe_blurred`` with ``pattern`` must give ORB.compute's bytes on a textured image at many
    angles, given the image as ORB.compute blurs it."""
    rng = np.random.default_rng(0)
    image = cv2.resize(rng.integers(0, 256, (12, 12), dtype=np.uint8), (96, 96), interpolation=cv2.INTER_CUBIC)
    n = 256
    xy = rng.integers(BORDER_PX, 96 - BORDER_PX, (n, 2)).astype(np.float32)
    angle = rng.uniform(0.0, 360.0, n).astype(np.float32)
    keypoints = [cv2.KeyPoint(float(x), float(y), _PATCH_SIZE, float(t)) for (x, y), t in zip(xy, angle)]
    if not np.array_equal(describe_blurred(_orb_compute_blur(image), xy, angle, pattern), _orb_compute(image, keypoints)):
        raise ZenslamError("ORB pattern probe: the pattern read back does not reproduce ORB.compute")
