"""Stereo matching of ORB keypoints on a rectified pair, as ORB-SLAM2's Frame::ComputeStereoMatches."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.errors import CalibrationError, ConfigError
from zenslam.frontend.orb_extractor import Features

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
    # Added to every measured disparity, level-0 px (Middlebury's doffs): a principal-point offset
    # between the rectified images that the calibration does not state. 0: the images as given.
    disparity_offset_px: float = 0.0

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
        if not math.isfinite(self.disparity_offset_px):
            problems.append(f"disparity_offset_px={self.disparity_offset_px} must be a finite number of pixels")
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
    n_matches = _match(
        left, right, left_pyramid, right_pyramid, bf, max_disparity, config, right_u, depth, right_index, sad_out
    )
    logger.debug("stereo: %d of %d left keypoints matched", n_matches, n_left)
    return StereoMatches(right_u, depth, right_index, sad_out)


def _match(
    left: Features,
    right: Features,
    left_pyramid: list[np.ndarray],
    right_pyramid: list[np.ndarray],
    bf: float,
    max_disparity: float,
    config: StereoMatchConfig,
    right_u: np.ndarray,
    depth: np.ndarray,
    right_index: np.ndarray,
    sad_out: np.ndarray,
) -> int:
    """Fill the (N,) outputs of the matched left keypoints; returns how many were matched.

    Each left keypoint's best ORB match, refined by SAD (dropped if the refinement fails), is kept
    if its disparity is in range and its SAD passes the outlier rule. A left keypoint's candidates
    are the right keypoints whose row band (+-row_tolerance * scale of their level) holds its row,
    at a level within level_tolerance of its own, with u in [u_left - max_disparity, u_left]. Each
    match's SAD slide runs on the left keypoint's level.
    """
    # The kernels import numba (~60 MB and most of a second per process): only a process that
    # matches loads it, not every one that imports the frame or its configs.
    from zenslam.descriptor_words import words
    from zenslam.frontend.stereo_kernel import best_descriptor_matches, keep_matches, refine_level_by_sad

    base_shape = left_pyramid[0].shape
    left_px, left_level, right_px, right_level = (_read_only(a) for a in (left.px, left.level, right.px, right.level))
    # u_left - max_disparity in numpy's promotion of the caller's types, held in float64 (exact for
    # float32 too): one compiled signature whether bf is a Python float or a numpy one
    u_low = _read_only((left_px[:, 0] - max_disparity).astype(np.float64))
    i_left, i_right = best_descriptor_matches(
        left_px, left_level, _read_only(words(left.descriptors)), u_low, right_px, right_level, _read_only(words(right.descriptors)),
        _read_only(right.scale_factors.astype(np.float64)), base_shape[0],
        float(config.row_tolerance_px), int(config.level_tolerance), int(config.max_descriptor_distance),
    )  # fmt: skip
    i_left, i_right = _read_only(i_left), _read_only(i_right)
    u_right = np.full(len(i_left), np.nan)
    sad = np.full(len(i_left), np.inf)
    for level in np.unique(left_level[i_left]).tolist():
        image_left, image_right = _read_only(left_pyramid[level]), _read_only(right_pyramid[level])
        refine_level_by_sad(
            image_left, image_right, level, left_px, left_level, right_px, i_left, i_right,
            image_left.shape[1] / base_shape[1], image_left.shape[0] / base_shape[0],
            image_right.shape[1] / base_shape[1], base_shape[1] / image_right.shape[1],
            int(config.sad_half_window_px), int(config.sad_search_px), float(config.max_subpixel_correction_px),
            u_right, sad,
        )  # fmt: skip
    return keep_matches(
        left_px, i_left, i_right, _read_only(u_right), _read_only(sad), float(config.disparity_offset_px),
        float(max_disparity), float(config.outlier_sad_factor), float(bf), right_u, depth, right_index, sad_out,
    )  # fmt: skip


def _read_only(array: np.ndarray) -> np.ndarray:
    """A read-only, C-contiguous view of ``array`` (a copy only if it is not contiguous).

    numba compiles one signature per argument type, and whether an array is writable is part of
    it: images decoded from the bus are read-only, those of an in-process source are not. Inputs
    always passed read-only keep to the one signature the warm-up compiled.
    """
    view = np.ascontiguousarray(array).view()
    view.flags.writeable = False
    return view
