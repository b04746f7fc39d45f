"""A tracking frame: one image's ORB features, their stereo / RGB-D depth, and a grid for area search."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.errors import CalibrationError, ImageReadError, ZenslamError
from zenslam.frontend.orb_extractor import Features, OrbExtractor
from zenslam.frontend.stereo_matcher import StereoMatchConfig, match_stereo
from zenslam.pose_optimizer import PoseOptimizerConfig, PoseResult, optimize_pose, pose_information, position_sigma

logger = logging.getLogger(__name__)

_GRID_COLS = 64  # cells across the image, as ORB-SLAM's FRAME_GRID_COLS
_GRID_ROWS = 48  # cells down the image, as ORB-SLAM's FRAME_GRID_ROWS


class KeypointGrid:
    """Keypoints bucketed into a cols x rows grid over the image, stored as CSR (cell -> keypoints).

    Cell (cx, cy) covers u in [cx * cell_w, (cx + 1) * cell_w), v likewise, in level-0 pixels.
    Within a cell, keypoints are in ascending index order.
    """

    def __init__(self, px: np.ndarray, width: int, height: int, cols: int = _GRID_COLS, rows: int = _GRID_ROWS):
        self.cols, self.rows = cols, rows
        self.cell_w = width / cols
        self.cell_h = height / rows
        cx = np.clip((px[:, 0] / self.cell_w).astype(np.int64), 0, cols - 1)
        cy = np.clip((px[:, 1] / self.cell_h).astype(np.int64), 0, rows - 1)
        cell = cy * cols + cx
        self.order = np.argsort(cell, kind="stable")
        self.start = np.searchsorted(cell[self.order], np.arange(cols * rows + 1))

    def candidates(self, u: np.ndarray, v: np.ndarray, radius_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(query, keypoint) index pairs of every keypoint in the cells touching each query's square.

        A superset of the keypoints within ``radius_px`` of (u, v); the caller filters exactly.
        """
        x0 = np.clip(np.floor((u - radius_px) / self.cell_w).astype(np.int64), 0, self.cols - 1)
        x1 = np.clip(np.floor((u + radius_px) / self.cell_w).astype(np.int64), 0, self.cols - 1)
        y0 = np.clip(np.floor((v - radius_px) / self.cell_h).astype(np.int64), 0, self.rows - 1)
        y1 = np.clip(np.floor((v + radius_px) / self.cell_h).astype(np.int64), 0, self.rows - 1)
        # one contiguous CSR slice per (query, cell row): cells x0..x1 of a row are adjacent
        n_cell_rows = np.maximum(y1 - y0 + 1, 0)
        query = np.repeat(np.arange(len(u)), n_cell_rows)
        cell_row = np.repeat(y0, n_cell_rows) + _ranges(n_cell_rows)
        begin = self.start[cell_row * self.cols + x0[query]]
        end = self.start[cell_row * self.cols + x1[query] + 1]
        lengths = end - begin
        pair_query = np.repeat(query, lengths)
        pair_keypoint = self.order[np.repeat(begin, lengths) + _ranges(lengths)]
        return pair_query, pair_keypoint


@dataclass(frozen=True, eq=False)
class Frame:
    """One image's features with per-keypoint right coordinate and depth; the tracker holds the pose.

    ``right_u`` (N,) is the keypoint's u in the (real or, for RGB-D, virtual) right image in
    level-0 pixels and ``depth_m`` (N,) its depth in metres along the camera z axis; both are -1
    where unknown (no stereo match, no valid depth, or a mono camera).
    """

    index: int
    stamp_ns: int
    calibration: PinholeCalibration
    features: Features
    right_u: np.ndarray  # (N,) float32, -1 where none
    depth_m: np.ndarray  # (N,) float32, -1 where none
    grid: KeypointGrid = field(init=False, repr=False)

    def __post_init__(self) -> None:
        n = len(self.features)
        if self.right_u.shape != (n,) or self.depth_m.shape != (n,):
            raise ZenslamError(
                f"frame {self.index}: right_u {self.right_u.shape} and depth_m {self.depth_m.shape} must both "
                f"be ({n},), one entry per keypoint; build frames with make_stereo_frame / make_rgbd_frame / "
                "make_mono_frame"
            )
        grid = KeypointGrid(self.features.px, self.calibration.width, self.calibration.height)
        object.__setattr__(self, "grid", grid)

    @property
    def n_keypoints(self) -> int:
        return len(self.features)

    @property
    def has_depth(self) -> np.ndarray:
        """(N,) bool: keypoints with a stereo match or a valid depth reading."""
        return self.depth_m > 0

    def unproject(self, indices: np.ndarray | None = None) -> np.ndarray:
        """p_cam (K, 3) in metres of the keypoints with depth (camera frame: x right, y down, z forward).

        Rows of keypoints without depth are NaN. ``indices`` selects keypoints (default all).
        """
        idx = np.arange(self.n_keypoints) if indices is None else np.asarray(indices)
        c = self.calibration
        px = self.features.px[idx].astype(np.float64)
        z = self.depth_m[idx].astype(np.float64)
        z = np.where(z > 0, z, np.nan)
        return np.stack([(px[:, 0] - c.cx) * z / c.fx, (px[:, 1] - c.cy) * z / c.fy, z], axis=1)

    def indices_in_area(
        self, u: float, v: float, radius_px: float, min_level: int = -1, max_level: int = -1
    ) -> np.ndarray:
        """Keypoints with |u_k - u| < r and |v_k - v| < r (level-0 px), ascending int64 indices.

        ``min_level`` / ``max_level`` (inclusive) filter by pyramid level; -1 means no bound
        (as ORB-SLAM's GetFeaturesInArea).
        """
        query, keypoint = self.indices_in_areas(
            np.array([u], np.float64), np.array([v], np.float64), radius_px, min_level, max_level
        )
        return keypoint

    def indices_in_areas(
        self,
        u: np.ndarray,
        v: np.ndarray,
        radius_px: float | np.ndarray,
        min_level: int | np.ndarray = -1,
        max_level: int | np.ndarray = -1,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Batch ``indices_in_area`` for M queries: (query (K,), keypoint (K,)) int64 pairs.

        Pairs are sorted by query, then keypoint. ``radius_px``, ``min_level`` and ``max_level``
        are scalars or (M,) arrays; a negative level bound means none.
        """
        u = np.asarray(u, np.float64).reshape(-1)
        v = np.asarray(v, np.float64).reshape(-1)
        m = len(u)
        radius = np.broadcast_to(np.asarray(radius_px, np.float64), (m,))
        lo = np.broadcast_to(np.asarray(min_level, np.int64), (m,))
        hi = np.broadcast_to(np.asarray(max_level, np.int64), (m,))
        finite = np.isfinite(u) & np.isfinite(v)
        query, keypoint = self.grid.candidates(np.where(finite, u, -1e9), np.where(finite, v, -1e9), radius)
        px = self.features.px
        level = self.features.level.astype(np.int64)
        keep = (
            finite[query]
            & (np.abs(px[keypoint, 0] - u[query]) < radius[query])
            & (np.abs(px[keypoint, 1] - v[query]) < radius[query])
            & ((lo[query] < 0) | (level[keypoint] >= lo[query]))
            & ((hi[query] < 0) | (level[keypoint] <= hi[query]))
        )
        query, keypoint = query[keep], keypoint[keep]
        order = np.lexsort((keypoint, query))
        return query[order], keypoint[order]


def make_stereo_frame(
    index: int,
    stamp_ns: int,
    left: np.ndarray,
    right: np.ndarray,
    calibration: PinholeCalibration,
    extractor: OrbExtractor,
    stereo_config: StereoMatchConfig | None = None,
    timings_ms: dict[str, float] | None = None,
) -> Frame:
    """Frame from a rectified stereo pair: ORB on both images, then stereo matching for depth.

    If ``timings_ms`` is given, "extraction" and "stereo_matching" wall times (ms) are stored in it.
    """
    if calibration.baseline_m is None:
        raise CalibrationError(f"frame {index}: a stereo frame needs calibration.baseline_m; this calibration is mono")
    _check_size(index, "left", left, calibration)
    _check_size(index, "right", right, calibration)
    t0 = time.perf_counter()
    (features, pyramid), (features_right, pyramid_right) = extractor.extract_pair(left, right)
    t1 = time.perf_counter()
    matches = match_stereo(features, features_right, pyramid, pyramid_right, calibration, stereo_config)
    t2 = time.perf_counter()
    if timings_ms is not None:
        timings_ms["extraction"] = (t1 - t0) * 1e3
        timings_ms["stereo_matching"] = (t2 - t1) * 1e3
    return Frame(index, stamp_ns, calibration, features, matches.right_u, matches.depth_m)


def make_rgbd_frame(
    index: int,
    stamp_ns: int,
    left: np.ndarray,
    depth_m: np.ndarray,
    calibration: PinholeCalibration,
    extractor: OrbExtractor,
    timings_ms: dict[str, float] | None = None,
) -> Frame:
    """Frame from a grey image and its registered depth image (metres, 0 or NaN where unknown).

    Each keypoint takes the depth of its nearest pixel and the virtual right coordinate
    u - bf / depth (ORB-SLAM2's ComputeStereoFromRGBD; bf uses ``calibration.baseline_m``).
    """
    if calibration.baseline_m is None:
        raise CalibrationError(
            f"frame {index}: an RGB-D frame needs calibration.baseline_m (the virtual baseline for bf, "
            "ORB-SLAM's Camera.bf / fx, typically 0.08 m)"
        )
    _check_size(index, "left", left, calibration)
    if depth_m.shape != left.shape or not np.issubdtype(depth_m.dtype, np.floating):
        raise ImageReadError(
            f"frame {index}: depth image has shape {depth_m.shape} dtype {depth_m.dtype}; "
            f"expected float metres of shape {left.shape} (scale integer depth images to metres first)"
        )
    t0 = time.perf_counter()
    features, _ = extractor.extract(left)
    if timings_ms is not None:
        timings_ms["extraction"] = (time.perf_counter() - t0) * 1e3
        timings_ms["stereo_matching"] = 0.0
    right_u, depth = rgbd_right_coordinates(features.px, depth_m, calibration.bf)
    return Frame(index, stamp_ns, calibration, features, right_u, depth)


def rgbd_right_coordinates(px: np.ndarray, depth_image_m: np.ndarray, bf: float) -> tuple[np.ndarray, np.ndarray]:
    """Per keypoint (level-0 px): depth at the nearest pixel and virtual right u = u - bf / depth.

    Returns (right_u, depth_m), both (N,) float32 and -1 where the depth is <= 0 or not finite.
    """
    height, width = depth_image_m.shape
    cols = np.clip(np.rint(px[:, 0]).astype(np.int64), 0, width - 1)
    rows = np.clip(np.rint(px[:, 1]).astype(np.int64), 0, height - 1)
    depth = depth_image_m[rows, cols].astype(np.float64)
    valid = np.isfinite(depth) & (depth > 0)
    safe = np.where(valid, depth, 1.0)
    right_u = np.where(valid, px[:, 0] - bf / safe, -1.0).astype(np.float32)
    return right_u, np.where(valid, depth, -1.0).astype(np.float32)


def make_mono_frame(
    index: int,
    stamp_ns: int,
    left: np.ndarray,
    calibration: PinholeCalibration,
    extractor: OrbExtractor,
    timings_ms: dict[str, float] | None = None,
) -> Frame:
    """Frame from a single grey image: features only, right_u and depth_m all -1."""
    _check_size(index, "image", left, calibration)
    t0 = time.perf_counter()
    features, _ = extractor.extract(left)
    if timings_ms is not None:
        timings_ms["extraction"] = (time.perf_counter() - t0) * 1e3
        timings_ms["stereo_matching"] = 0.0
    none = np.full(len(features), -1.0, np.float32)
    return Frame(index, stamp_ns, calibration, features, none, none.copy())


def _check_size(index: int, name: str, image: np.ndarray, calibration: PinholeCalibration) -> None:
    expected = (calibration.height, calibration.width)
    if getattr(image, "shape", None) != expected:
        raise ImageReadError(
            f"frame {index}: {name} image has shape {getattr(image, 'shape', None)}, but the calibration "
            f"says {calibration.width}x{calibration.height} (HxW {expected}); check the dataset's calibration"
        )


def _ranges(counts: np.ndarray) -> np.ndarray:
    """Concatenated aranges: [0..counts[0]), [0..counts[1]), ... as one int64 array."""
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    ends = np.cumsum(counts)
    return np.arange(total, dtype=np.int64) - np.repeat(ends - counts, counts)


def _observations(frame: Frame, keypoints: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``optimize_pose``'s observation arrays for the frame's ``keypoints``: level-0 pixels, right-image
    u (NaN where not stereo-matched) and the levels' weights."""
    feats = frame.features
    right = frame.right_u[keypoints].astype(float)
    return feats.px[keypoints].astype(float), np.where(right >= 0, right, np.nan), feats.inv_level_sigma2[feats.level[keypoints]]


def optimize_frame_pose(
    frame: Frame, T_cam_world_init: np.ndarray, keypoints: np.ndarray, p_world: np.ndarray, config: PoseOptimizerConfig,
    point_covariance: np.ndarray | None = None,
) -> PoseResult:
    """``optimize_pose`` of ``frame`` from its keypoints ``keypoints`` (K,) observing the points
    ``p_world`` (K, 3): their pixels, right-image coordinates where stereo matched, and their levels'
    weights; inliers are over ``keypoints``. ``point_covariance`` (K, 3, 3): the points' own
    uncertainty (``optimize_pose``), None: exact."""
    return optimize_pose(
        T_cam_world_init, p_world, *_observations(frame, keypoints), frame.calibration, config, point_covariance=point_covariance
    )


def frame_pose_information(
    frame: Frame, T_cam_world: np.ndarray, keypoints: np.ndarray, p_world: np.ndarray, point_covariance: np.ndarray | None = None
) -> np.ndarray:
    """``pose_information`` (6, 6) of the pose ``T_cam_world`` of ``frame`` from its keypoints
    ``keypoints`` observing ``p_world``, weighed as ``optimize_frame_pose`` weighs them."""
    return pose_information(T_cam_world, p_world, *_observations(frame, keypoints), frame.calibration, point_covariance)


def frame_position_sigma(frame: Frame, T_cam_world: np.ndarray, keypoints: np.ndarray, p_world: np.ndarray) -> float:
    """``position_sigma`` of the pose ``T_cam_world`` of ``frame`` from its keypoints ``keypoints``
    observing ``p_world``, weighed as ``optimize_frame_pose`` weighs them."""
    return position_sigma(T_cam_world, p_world, *_observations(frame, keypoints), frame.calibration)
