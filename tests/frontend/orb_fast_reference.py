"""The ORB extractor's FAST as it was before its compiled kernel: the reference of zenslam/frontend/orb_fast.py.

``mosaic_detect_cells`` is the former ``orb_extractor._detect_cells``: OpenCV's FastFeatureDetector
over the detection region, then over a mosaic of the empty cells' windows. The extractor must
equal it exactly (tests/frontend/test_orb_fast.py); benchmarks/frontend_fast.py times it against
the kernel.
"""

from __future__ import annotations

import math
import operator

import cv2
import numpy as np

from zenslam.frontend.orb_extractor import OrbConfig

_EDGE_THRESHOLD = 19
_FAST_RADIUS = 3
_MOSAIC_TILES = 24  # windows per mosaic row in the FAST fallback: rows of ~900 px keep FAST's SIMD busy


def opencv_fast(image: np.ndarray, threshold: int) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's FAST-9/16 with non-maximum suppression: (K, 2) float32 corners (x, y), (K,) float32 scores."""
    detector = cv2.FastFeatureDetector_create(threshold, True, cv2.FAST_FEATURE_DETECTOR_TYPE_9_16)
    return _fast(detector, np.ascontiguousarray(image))


def mosaic_detect_cells(image: np.ndarray, config: OrbConfig) -> tuple[np.ndarray, np.ndarray, int, int]:
    """The former ``orb_extractor._detect_cells``, same arguments and results as the current one."""
    fast_ini = cv2.FastFeatureDetector_create(config.ini_fast_threshold, True, cv2.FAST_FEATURE_DETECTOR_TYPE_9_16)
    fast_min = cv2.FastFeatureDetector_create(config.min_fast_threshold, True, cv2.FAST_FEATURE_DETECTOR_TYPE_9_16)
    return _mosaic_detect_cells(image, config, fast_ini, fast_min)


def _mosaic_detect_cells(
    image: np.ndarray,
    config: OrbConfig,
    fast_ini: cv2.FastFeatureDetector,
    fast_min: cv2.FastFeatureDetector,
) -> tuple[np.ndarray, np.ndarray, int, int]:
    """ORB-SLAM's per-cell FAST, relative to the detection region's corner.

    ORB-SLAM runs FAST(ini) on each ~30 px cell and falls back to FAST(min) where the cell has no
    corner. FAST(ini) with non-maximum suppression equals FAST(min) keeping scores >= ini, so one
    FAST(ini) call over the whole region plus FAST(min) on the empty cells gives the same corners
    at a fraction of the calls. Returns keypoints (K, 2) float32, responses (K,) float32, and the
    region's width and height (level pixels).
    """
    rows, cols = image.shape
    border = _EDGE_THRESHOLD - _FAST_RADIUS
    width, height = cols - 2 * border, rows - 2 * border
    if width <= 2 * _FAST_RADIUS + 1 or height <= 2 * _FAST_RADIUS + 1:
        return np.zeros((0, 2), np.float32), np.zeros(0, np.float32), max(width, 1), max(height, 1)
    n_cols = max(1, int(width / config.cell_size_px))
    n_rows = max(1, int(height / config.cell_size_px))
    w_cell = int(math.ceil(width / n_cols))
    h_cell = int(math.ceil(height / n_rows))
    region = image[border : border + height, border : border + width]
    xy, response = _fast(fast_ini, region)
    # Cell (i, j) detects in [3 + j*w_cell, 3 + (j+1)*w_cell): its FAST window is 6 px wider than the cell.
    col = np.minimum((xy[:, 0].astype(np.int64) - _FAST_RADIUS) // w_cell, n_cols - 1)
    row = np.minimum((xy[:, 1].astype(np.int64) - _FAST_RADIUS) // h_cell, n_rows - 1)
    counts = np.bincount(row * n_cols + col, minlength=n_rows * n_cols)
    empty_row, empty_col = np.divmod(np.flatnonzero(counts == 0), n_cols)
    if len(empty_row):
        cell_xy, cell_response = _fast_in_cells(fast_min, region, empty_row, empty_col, w_cell, h_cell)
        xy = np.concatenate([xy, cell_xy])
        response = np.concatenate([response, cell_response])
    return xy, response, width, height


def _fast_in_cells(
    detector: cv2.FastFeatureDetector,
    region: np.ndarray,
    cell_row: np.ndarray,
    cell_col: np.ndarray,
    w_cell: int,
    h_cell: int,
) -> tuple[np.ndarray, np.ndarray]:
    """FAST in the given cells' windows (each cell plus a 3 px margin), in one OpenCV call.

    The windows are tiled into one mosaic up to ``_MOSAIC_TILES`` windows wide (OpenCV's FAST is
    several times slower per pixel on a narrow image), so only detections at least 3 px inside
    their own window are kept: those are exactly the corners a separate call per window would
    find, up to non-maximum suppression against the margin pixels. Tiles past the last cell are
    blank. Returns region pixels and scores.
    """
    height, width = region.shape
    win_h, win_w = h_cell + 2 * _FAST_RADIUS, w_cell + 2 * _FAST_RADIUS
    pad_y = max(0, int(cell_row.max()) * h_cell + win_h - height)
    pad_x = max(0, int(cell_col.max()) * w_cell + win_w - width)
    padded = cv2.copyMakeBorder(region, 0, pad_y, 0, pad_x, cv2.BORDER_REPLICATE) if pad_x or pad_y else region
    n_tiles = len(cell_row)
    per_row = min(n_tiles, _MOSAIC_TILES)
    n_rows = -(-n_tiles // per_row)
    # cell (i, j)'s window is padded[i*h_cell : i*h_cell + win_h, j*w_cell : j*w_cell + win_w]
    step_y, step_x = padded.strides
    cells = np.lib.stride_tricks.as_strided(
        padded,
        ((padded.shape[0] - win_h) // h_cell + 1, (padded.shape[1] - win_w) // w_cell + 1, win_h, win_w),
        (h_cell * step_y, w_cell * step_x, step_y, step_x),
        writeable=False,
    )
    tile = np.arange(n_tiles)
    mosaic = np.zeros((n_rows, win_h, per_row, win_w), np.uint8)  # tile t at mosaic row t // per_row, column t % per_row
    mosaic[tile // per_row, :, tile % per_row, :] = cells[cell_row, cell_col]
    xy, response = _fast(detector, mosaic.reshape(n_rows * win_h, per_row * win_w))
    if len(xy) == 0:
        return xy, response
    xy_int = xy.astype(np.int64)
    tile_row, local_y = np.divmod(xy_int[:, 1], win_h)
    tile_col, local_x = np.divmod(xy_int[:, 0], win_w)
    tile = tile_row * per_row + tile_col
    keep = (
        (tile < n_tiles)  # the blank tiles padding the last mosaic row hold no cell
        & (local_y >= _FAST_RADIUS)
        & (local_y < win_h - _FAST_RADIUS)
        & (local_x >= _FAST_RADIUS)
        & (local_x < win_w - _FAST_RADIUS)
    )
    tile = tile[keep]
    x = local_x[keep] + cell_col[tile] * w_cell
    y = local_y[keep] + cell_row[tile] * h_cell
    inside = (x < width - _FAST_RADIUS) & (y < height - _FAST_RADIUS)
    return np.stack([x[inside], y[inside]], axis=1).astype(np.float32), response[keep][inside]


def _fast(detector: cv2.FastFeatureDetector, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return _keypoint_arrays(detector.detect(image))


_RESPONSE = operator.attrgetter("response")


def _keypoint_arrays(keypoints: list[cv2.KeyPoint]) -> tuple[np.ndarray, np.ndarray]:
    if not keypoints:
        return np.zeros((0, 2), np.float32), np.zeros(0, np.float32)
    xy = cv2.KeyPoint_convert(keypoints).astype(np.float32).reshape(-1, 2)
    response = np.fromiter(map(_RESPONSE, keypoints), np.float32, len(keypoints))
    return xy, response
