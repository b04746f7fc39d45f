"""ORB features as ORB-SLAM extracts them: scale pyramid, per-cell FAST, quadtree distribution, rBRIEF."""

from __future__ import annotations

import logging
import math
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

from zenslam.errors import ConfigError, ImageReadError

logger = logging.getLogger(__name__)

# Constants of the ORB descriptor itself (the rBRIEF pattern is defined on a 31 px patch), not tunables.
_PATCH_SIZE = 31  # level pixels: descriptor / orientation patch diameter
_EDGE_THRESHOLD = 19  # level pixels: keypoints stay this far from the border so the rotated pattern fits
_FAST_RADIUS = 3  # level pixels: FAST never fires closer than this to the image it is given
_MOSAIC_TILES = 24  # windows per mosaic row in the FAST(min) fallback: part of the rule the keypoints follow (orb_fast.fast_in_cells)


@dataclass(frozen=True)
class OrbConfig:
    """ORB extraction parameters; the defaults are ORB-SLAM's."""

    n_features: int = 1200  # keypoints per image, summed over the levels (ORB-SLAM uses 1000-2000)
    scale_factor: float = 1.2  # linear scale between consecutive pyramid levels (> 1)
    n_levels: int = 8  # pyramid levels
    ini_fast_threshold: int = 20  # grey levels: FAST threshold tried first in each cell
    min_fast_threshold: int = 7  # grey levels: FAST threshold for cells where the first finds no corner
    cell_size_px: int = 30  # level pixels: target side of a FAST cell
    threads: int = 2  # threads extracting the two images of a stereo pair (1 = sequential; same output)

    def __post_init__(self) -> None:
        problems = []
        if self.n_features < 1:
            problems.append(f"n_features={self.n_features} must be >= 1")
        if not (math.isfinite(self.scale_factor) and self.scale_factor > 1.0):
            problems.append(f"scale_factor={self.scale_factor} must be > 1")
        if self.n_levels < 1:
            problems.append(f"n_levels={self.n_levels} must be >= 1")
        if not (0 < self.min_fast_threshold <= self.ini_fast_threshold):
            problems.append(
                f"FAST thresholds min={self.min_fast_threshold}, ini={self.ini_fast_threshold} "
                "must satisfy 0 < min_fast_threshold <= ini_fast_threshold"
            )
        if self.cell_size_px < 8:
            problems.append(f"cell_size_px={self.cell_size_px} must be >= 8 pixels")
        if self.threads not in (1, 2):
            problems.append(f"threads={self.threads} must be 1 or 2")
        if problems:
            raise ConfigError("invalid OrbConfig: " + "; ".join(problems))


@dataclass(frozen=True, eq=False)  # arrays: compare fields explicitly
class Features:
    """N ORB keypoints of one image, with the pyramid constants needed to weigh them.

    ``px`` is in level-0 pixels (u right, v down); ``level`` is the pyramid level the keypoint was
    detected at; ``angle_deg`` its intensity-centroid orientation in [0, 360) degrees (image axes);
    ``response`` its FAST score (grey levels); ``descriptors`` the 256-bit rBRIEF strings.
    ``scale_factors[l] = scale_factor**l`` and ``inv_level_sigma2[l] = 1 / scale_factors[l]**2``.
    """

    px: np.ndarray  # (N, 2) float32
    level: np.ndarray  # (N,) int16
    angle_deg: np.ndarray  # (N,) float32
    response: np.ndarray  # (N,) float32
    descriptors: np.ndarray  # (N, 32) uint8
    scale_factors: np.ndarray  # (n_levels,) float64
    inv_level_sigma2: np.ndarray  # (n_levels,) float64

    def __len__(self) -> int:
        return int(self.px.shape[0])

    @property
    def size_px(self) -> np.ndarray:
        """(N,) float32 diameter of each keypoint's patch in level-0 pixels (31 * scale)."""
        return (_PATCH_SIZE * self.scale_factors[self.level]).astype(np.float32)

    @property
    def level_sigma2(self) -> np.ndarray:
        """(n_levels,) variance of a measurement at each level, in level-0 pixels^2."""
        return self.scale_factors**2

    def subset(self, indices: np.ndarray) -> Features:
        """The keypoints at ``indices`` (int array or bool mask), in that order."""
        return Features(
            px=self.px[indices],
            level=self.level[indices],
            angle_deg=self.angle_deg[indices],
            response=self.response[indices],
            descriptors=self.descriptors[indices],
            scale_factors=self.scale_factors,
            inv_level_sigma2=self.inv_level_sigma2,
        )


def features_per_level(n_features: int, scale_factor: float, n_levels: int) -> np.ndarray:
    """Keypoints wanted per level, a geometric series of ratio 1/scale_factor summing to n_features.

    This is ORB-SLAM's split (ORBextractor's mnFeaturesPerLevel): each level gets 1/scale_factor
    of the one below, the last level the remainder.
    """
    factor = 1.0 / scale_factor
    per_scale = n_features * (1.0 - factor) / (1.0 - factor**n_levels)
    counts = np.zeros(n_levels, dtype=np.int64)
    for level in range(n_levels - 1):
        counts[level] = int(round(per_scale))
        per_scale *= factor
    counts[-1] = max(n_features - int(counts[:-1].sum()), 0)
    return counts


class OrbExtractor:
    """Extracts ORB-SLAM-style ORB features from grey images; reusable across frames.

    ``extract`` is deterministic: the same image gives the same features in the same order
    (sorted by level, then row, then column).
    """

    def __init__(self, config: OrbConfig | None = None) -> None:
        self._config = config or OrbConfig()
        c = self._config
        self._scale_factors = c.scale_factor ** np.arange(c.n_levels, dtype=np.float64)
        self._inv_level_sigma2 = 1.0 / self._scale_factors**2
        self._per_level = features_per_level(c.n_features, c.scale_factor, c.n_levels)
        self._disc_half_widths = disc_half_widths()
        self._rbrief_pattern = rbrief_pattern()
        self._executor: ThreadPoolExecutor | None = None
        self._executor_lock = threading.Lock()

    @property
    def config(self) -> OrbConfig:
        return self._config

    @property
    def scale_factors(self) -> np.ndarray:
        """(n_levels,) scale of each level relative to level 0."""
        return self._scale_factors

    @property
    def inv_level_sigma2(self) -> np.ndarray:
        """(n_levels,) 1 / scale**2 per level."""
        return self._inv_level_sigma2

    @property
    def n_per_level(self) -> np.ndarray:
        """(n_levels,) number of keypoints wanted at each level."""
        return self._per_level.copy()

    def build_pyramid(self, image: np.ndarray) -> list[np.ndarray]:
        """Level images: level 0 is ``image``, level l is level l-1 resized (INTER_LINEAR) by 1/scale_factor.

        Every level is a read-only array: numba compiles a kernel once per signature, and read-only
        is part of it. Frames decoded from the bus are read-only, those of an in-process source and
        the resized levels are not; all read-only, the kernels keep to the one signature the
        warm-up compiled, instead of compiling another at a run's first frame.
        """
        _check_image(image)
        pyramid = [np.ascontiguousarray(image).view()]  # a view: the caller's array keeps its flags
        h0, w0 = image.shape
        for level in range(1, self._config.n_levels):
            inv = 1.0 / self._scale_factors[level]
            size = (int(round(w0 * inv)), int(round(h0 * inv)))
            pyramid.append(cv2.resize(pyramid[-1], size, interpolation=cv2.INTER_LINEAR))
        for level_image in pyramid:
            level_image.setflags(write=False)
        return pyramid

    def extract(self, image: np.ndarray) -> tuple[Features, list[np.ndarray]]:
        """ORB features of a grey uint8 image (H, W) and its pyramid (list of level images).

        Keypoint coordinates are level-0 pixels; the pyramid is returned because stereo matching
        refines disparities on the level images.
        """
        c = self._config
        pyramid = self.build_pyramid(image)
        parts = []
        for level, level_image in enumerate(pyramid):
            xy, response = _detect_distributed(level_image, int(self._per_level[level]), c)
            angle = intensity_centroid_angles(level_image, xy, self._disc_half_widths)
            descriptors = describe(level_image, xy, angle, self._rbrief_pattern)
            level_ids = np.full(len(xy), level, np.int16)
            parts.append((level_to_base_px(xy, level_image.shape, image.shape), level_ids, angle, response, descriptors))
        features = Features(
            px=np.concatenate([p[0] for p in parts]).astype(np.float32).reshape(-1, 2),
            level=np.concatenate([p[1] for p in parts]),
            angle_deg=np.concatenate([p[2] for p in parts]).astype(np.float32),
            response=np.concatenate([p[3] for p in parts]).astype(np.float32),
            descriptors=np.concatenate([p[4] for p in parts]).reshape(-1, 32),
            scale_factors=self._scale_factors,
            inv_level_sigma2=self._inv_level_sigma2,
        )
        return features, pyramid

    def extract_pair(
        self, left: np.ndarray, right: np.ndarray
    ) -> tuple[tuple[Features, list[np.ndarray]], tuple[Features, list[np.ndarray]]]:
        """``extract`` on both images of a stereo pair; the right one in a worker thread when threads == 2.

        OpenCV and most numpy work release the GIL, so the two extractions overlap. The output is
        identical to two sequential calls.
        """
        if self._config.threads == 1:
            return self.extract(left), self.extract(right)
        future = self._worker().submit(self.extract, right)
        left_out = self.extract(left)
        return left_out, future.result()

    def _worker(self) -> ThreadPoolExecutor:
        with self._executor_lock:
            if self._executor is None:
                self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="orb-extract")
            return self._executor


# The compiled kernels import numba (~60 MB and most of a second per process): they are imported
# at the first extraction, so the processes that only read an OrbConfig (the supervising
# `zenslam run`, the backend, the recorder) do not load it.


def distribute_quadtree(xy: np.ndarray, response: np.ndarray, width: int, height: int, n_target: int) -> np.ndarray:
    """``orb_quadtree.distribute_quadtree``: the indices of the corners ORB-SLAM's quadtree keeps."""
    from zenslam.frontend import orb_quadtree

    return orb_quadtree.distribute_quadtree(xy, response, width, height, n_target)


def fast_in_cells(
    image: np.ndarray,
    box: tuple[int, int, int, int],
    grid: tuple[int, int, int, int],
    thresholds: tuple[int, int],
    tiles_per_row: int,
) -> tuple[np.ndarray, np.ndarray]:
    """``orb_fast.fast_in_cells`` as float32: (K, 2) FAST corners in the region's pixels, (K,) scores."""
    from zenslam.frontend import orb_fast

    xy, score = orb_fast.fast_in_cells(image, box, grid, thresholds, tiles_per_row)
    return xy.astype(np.float32), score.astype(np.float32)


def intensity_centroid_angles(image: np.ndarray, xy: np.ndarray, u_max: np.ndarray) -> np.ndarray:
    """``orb_orientation.intensity_centroid_angles``: each keypoint's orientation in degrees."""
    from zenslam.frontend import orb_orientation

    return orb_orientation.intensity_centroid_angles(image, xy, u_max)


def disc_half_widths() -> np.ndarray:
    """``orb_orientation.disc_half_widths``: the orientation disc's half width per row offset."""
    from zenslam.frontend import orb_orientation

    return orb_orientation.disc_half_widths()


def describe(image: np.ndarray, xy: np.ndarray, angle_deg: np.ndarray, pattern: np.ndarray) -> np.ndarray:
    """``orb_descriptor.describe``: the (K, 32) rBRIEF descriptors of keypoints on one level image."""
    from zenslam.frontend import orb_descriptor

    return orb_descriptor.describe(image, xy, angle_deg, pattern)


def rbrief_pattern() -> np.ndarray:
    """``orb_descriptor.rbrief_pattern``: the (512, 2) points of OpenCV's ORB tests."""
    from zenslam.frontend import orb_descriptor

    return orb_descriptor.rbrief_pattern()


def level_to_base_px(xy_level: np.ndarray, level_shape: tuple[int, ...], base_shape: tuple[int, ...]) -> np.ndarray:
    """(N, 2) level pixels (u, v) -> level-0 pixels, pixel centres at integers on both.

    cv2.resize maps destination pixel x to source (x + 0.5) * (source size / destination size) - 0.5,
    and chained resizes compose, so a level whose image is (h, w) maps exactly by
    u0 = (u + 0.5) * w0 / w - 0.5 (likewise v with h). ORB-SLAM's u * scale_factor is off by
    -(scale - 1) / 2 px, up to 1.3 px at level 7, so the same point seen at different levels disagreed.
    """
    ratio = np.array([base_shape[1] / level_shape[1], base_shape[0] / level_shape[0]])
    return (np.asarray(xy_level, np.float64) + 0.5) * ratio - 0.5


def base_to_level_px(xy_base: np.ndarray, level_shape: tuple[int, ...], base_shape: tuple[int, ...]) -> np.ndarray:
    """Inverse of ``level_to_base_px``: (N, 2) level-0 pixels -> pixels of the level of shape ``level_shape``."""
    ratio = np.array([level_shape[1] / base_shape[1], level_shape[0] / base_shape[0]])
    return (np.asarray(xy_base, np.float64) + 0.5) * ratio - 0.5


def _check_image(image: np.ndarray) -> None:
    if not isinstance(image, np.ndarray) or image.ndim != 2 or image.dtype != np.uint8:
        shape = getattr(image, "shape", None)
        dtype = getattr(image, "dtype", type(image).__name__)
        raise ImageReadError(
            f"ORB extraction needs a grey uint8 image of shape (H, W); got shape {shape} dtype {dtype}. "
            "Convert colour images with cv2.cvtColor(..., cv2.COLOR_BGR2GRAY)."
        )
    if min(image.shape) < 2 * _EDGE_THRESHOLD + 8:
        raise ImageReadError(f"image of shape {image.shape} is too small for ORB (need at least 46 px per side)")


def _detect_distributed(image: np.ndarray, n_target: int, config: OrbConfig) -> tuple[np.ndarray, np.ndarray]:
    """FAST corners of one level spread by the quadtree: (K, 2) float64 level pixels, (K,) responses."""
    xy, response, width, height = _detect_cells(image, config)
    keep = distribute_quadtree(xy, response, width, height, n_target)
    keep = keep[np.lexsort((xy[keep, 0], xy[keep, 1]))]  # raster order, for a stable output order
    border = _EDGE_THRESHOLD - _FAST_RADIUS
    return xy[keep].astype(np.float64) + border, response[keep]


def _detect_cells(image: np.ndarray, config: OrbConfig) -> tuple[np.ndarray, np.ndarray, int, int]:
    """ORB-SLAM's per-cell FAST, relative to the detection region's corner.

    ORB-SLAM runs FAST(ini) on each ~30 px cell and falls back to FAST(min) where the cell has no
    corner. FAST(ini) with non-maximum suppression equals FAST(min) keeping scores >= ini, so one
    FAST(ini) pass over the whole region plus FAST(min) on the empty cells gives the same corners
    at a fraction of the work (``orb_fast.fast_in_cells``, where the empty cells' windows are a
    mosaic). Returns keypoints (K, 2) float32, responses (K,) float32, and the region's width and
    height (level pixels).
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
    xy, response = fast_in_cells(
        image,
        (border, border, border + width, border + height),
        (n_cols, n_rows, w_cell, h_cell),
        (config.ini_fast_threshold, config.min_fast_threshold),
        _MOSAIC_TILES,
    )
    return xy, response, width, height
