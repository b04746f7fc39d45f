"""Starting a monocular map: a reference frame, then the first later frame with enough parallax
(ORB-SLAM's MonocularInitialization).

The first frame with enough keypoints becomes the reference. Each following frame is matched to
it (``search_for_initialisation``, each keypoint searched around where it was last found); too few
matches make that frame the new reference. With enough matches, the two-view reconstruction
(homography or fundamental matrix, ``two_view_initializer``) either refuses (not enough parallax,
an ambiguous motion, too few points) and the next frame tries again, or gives the motion and the
triangulated points. Their scale is unknown: the points' median depth in the reference camera is
set to 1, as ORB-SLAM does.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from zenslam.frontend.frame import Frame
from zenslam.frontend.initialisation_matching import InitialisationMatchingConfig, search_for_initialisation
from zenslam.frontend.two_view_initializer import TwoViewConfig, TwoViewResult, initialize_two_view


@dataclass(frozen=True)
class MonocularInitialisationConfig:
    """ORB-SLAM's monocular initialisation thresholds."""

    min_keypoints: int = 100  # a reference frame (and its partner) needs more keypoints than this
    features_factor: int = 8  # frames looking for the initial pair are extracted with this many times orb.n_features
    min_matches: int = 100  # fewer matches to the reference: the current frame becomes the reference
    median_depth: float = 1.0  # the map's scale: median depth of the first points in the reference camera (map units)
    matching: InitialisationMatchingConfig = field(default_factory=InitialisationMatchingConfig)
    two_view: TwoViewConfig = field(default_factory=TwoViewConfig)


@dataclass(frozen=True)
class InitialMap:
    """Two frames and the points triangulated between them, in the reference camera's frame."""

    reference: Frame
    current: Frame
    T_cur_ref: np.ndarray  # (4, 4) reference camera -> current camera, translation in map units
    reference_keypoints: np.ndarray  # (P,) int64 keypoint of each point in the reference frame
    current_keypoints: np.ndarray  # (P,) int64 keypoint of each point in the current frame
    p_ref: np.ndarray  # (P, 3) points in the reference camera frame, map units
    model: str  # the two-view model the motion came from: homography or fundamental
    parallax_deg: float


class MonocularInitialiser:
    """Holds the reference frame between calls to ``try_frame``."""

    def __init__(self, config: MonocularInitialisationConfig | None = None) -> None:
        self.config = config or MonocularInitialisationConfig()
        self._reference: Frame | None = None
        self._last_px: np.ndarray | None = None  # (N, 2) where each reference keypoint was last matched

    def reset(self) -> None:
        self._reference = None
        self._last_px = None

    def try_frame(self, frame: Frame) -> InitialMap | str:
        """The initial map from the reference and ``frame``, or why not yet (a lost-reason string)."""
        config = self.config
        if self._reference is None:
            if frame.n_keypoints <= config.min_keypoints:
                return "too_few_keypoints_for_init"
            self._set_reference(frame)
            return "waiting_for_second_frame"
        if frame.n_keypoints <= config.min_keypoints:
            self.reset()
            return "too_few_keypoints_for_init"
        match = search_for_initialisation(self._reference, frame, self._last_px, config.matching)
        matched = np.flatnonzero(match >= 0)
        if len(matched) < config.min_matches:
            self._set_reference(frame)
            return "too_few_initialisation_matches"
        self._last_px[matched] = frame.features.px[match[matched]]
        result = initialize_two_view(
            self._reference.features.px[matched].astype(np.float64),
            frame.features.px[match[matched]].astype(np.float64),
            frame.calibration.K,
            self._reference.features.level_sigma2[self._reference.features.level[matched]],
            config.two_view,
        )
        if not isinstance(result, TwoViewResult):
            return "waiting_for_parallax" if result.reason == "low_parallax" else f"two_view_refused_{result.reason}"
        return self._initial_map(frame, matched, match[matched], result)

    def _set_reference(self, frame: Frame) -> None:
        self._reference = frame
        self._last_px = frame.features.px.astype(np.float64).copy()

    def _initial_map(self, frame: Frame, ref_kps: np.ndarray, cur_kps: np.ndarray, result: TwoViewResult) -> InitialMap | str:
        good = np.asarray(result.triangulated, dtype=bool)
        p_ref = np.asarray(result.p_ref, dtype=np.float64)
        depth = np.median(p_ref[:, 2]) if len(p_ref) else 0.0
        if not depth > 0:
            return "two_view_refused_points_behind"
        scale = self.config.median_depth / depth
        T_cur_ref = np.array(result.T_cur_ref, dtype=np.float64)
        T_cur_ref[:3, 3] *= scale
        reference = self._reference
        self.reset()
        return InitialMap(
            reference=reference,
            current=frame,
            T_cur_ref=T_cur_ref,
            reference_keypoints=ref_kps[good].astype(np.int64),
            current_keypoints=cur_kps[good].astype(np.int64),
            p_ref=p_ref * scale,
            model=result.model,
            parallax_deg=float(result.parallax_deg),
        )
