"""Relocalisation inside tracking: a lost frame's candidates asked of the backend, matched
(``relocalisation.relocalise``) and tracked in the local map; the backend's keyframes brought
into the cache around the match, and, in a saved map, around each new reference keyframe."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.frontend.cache_eviction import CacheEviction
from zenslam.frontend.frame import Frame
from zenslam.frontend.keyframe import KeyFrame
from zenslam.frontend.local_map import LocalMap
from zenslam.frontend.local_map_tracking import LocalMapPose, LocalMapTracking
from zenslam.frontend.map_sync import restore_keyframes
from zenslam.frontend.point_uncertainty import point_covariances
from zenslam.frontend.relocalisation import BowTransform, PosePrior, keyframes_to_restore, relocalise
from zenslam.frontend.tracking_config import TrackingConfig
from zenslam.frontend.tracking_state import TrackerState
from zenslam.pose_optimizer import PoseOptimizerConfig
from zenslam.schemas.relocalisation import RelocalisationCandidates, RelocalisationQuery

logger = logging.getLogger(__name__)

# Asks the backend for relocalisation candidates; None when it did not answer.
CandidateSource = Callable[[RelocalisationQuery], "RelocalisationCandidates | None"]


class RelocalisationTracking:
    """Relocalises lost frames with ``vocabulary`` and restores the backend's keyframes into the cache.

    ``weighs_points``: the restored points get position covariances (``point_uncertainty``);
    ``max_frames`` is the keyframe decision's (0: one second of frames), the span after a
    relocalisation in which tracking asks for more inliers.
    """

    def __init__(
        self, local_map: LocalMap, state: TrackerState, config: TrackingConfig, pose_config: PoseOptimizerConfig,
        calibration: PinholeCalibration, vocabulary: BowTransform | None, local_map_tracking: LocalMapTracking,
        eviction: CacheEviction, weighs_points: bool, max_frames: float,
    ) -> None:
        self.map = local_map
        self.state = state
        self.config = config
        self.pose_config = pose_config
        self.calibration = calibration
        self.vocabulary = vocabulary  # the bag-of-words vocabulary relocalisation queries and matches with
        self.local_map_tracking = local_map_tracking
        self.eviction = eviction
        self.weighs_points = weighs_points
        self.max_frames = max_frames
        self._window_of = -1  # the saved keyframe whose window was fetched last

    def enabled(self, candidates: CandidateSource | None) -> bool:
        """Whether a lost frame can be relocalised with ``candidates``."""
        return candidates is not None and self.vocabulary is not None and self.config.relocalisation.enabled

    def relocalise(self, frame: Frame, candidates: CandidateSource, prior: PosePrior | None = None) -> tuple[LocalMapPose | None, str]:
        """ORB-SLAM2's ``Relocalization`` then ``TrackLocalMap``: (the pose, "") on success, else
        (None, why not). The matched keyframe and its neighbours re-enter the cache either way. A
        candidate's pose that ``prior`` does not admit is refused."""
        cfg = self.config.relocalisation
        timers = self.state.timers
        start, pose_ms = time.perf_counter(), timers.pose_ms
        timers.ms["relocalisation"] = 0.0
        try:
            if len(frame.features) == 0:
                return None, "relocalisation_no_keypoints"
            bow, fvec = self.vocabulary.transform(frame.features.descriptors)
            query = RelocalisationQuery(frame.stamp_ns, bow.word_ids, bow.weights, cfg.max_candidates, cfg.max_neighbours)
            reply = candidates(query) if len(bow.word_ids) else None
            if reply is None or not reply.candidates:
                return None, "relocalisation_no_candidates"
            found = relocalise(frame, reply, self.vocabulary, cfg, self.pose_config, frame_feature_vector=fvec, prior=prior)
            if found is None:
                return None, "relocalisation_no_candidate_matched"
            self.restore(keyframes_to_restore(reply, found.keyframe_id), reply)
            rows = self.map.rows_of_ids(found.point_ids)
            tracked = self.local_map_tracking.track(frame, found.T_cam_world, rows)
        finally:
            timers.add_less_pose("relocalisation", start, pose_ms)
        min_inliers = max(self.config.min_local_map_inliers, cfg.min_local_map_inliers_after)
        if tracked.n_inliers < min_inliers:
            return None, f"relocalisation_local_map_inliers_below_{min_inliers}"
        self.state.relocalised_at = frame.index
        self.state.n_relocalisations += 1
        logger.info("relocalised at frame %d on keyframe %d (%d inliers)", frame.index, found.keyframe_id, tracked.n_inliers)
        return tracked, ""

    def min_local_map_inliers(self, frame: Frame) -> int:
        """Local-map inliers the frame needs: more within a second of a relocalisation."""
        if self.state.recently_relocalised(frame, self.max_frames):
            return max(self.config.min_local_map_inliers, self.config.relocalisation.min_local_map_inliers_after)
        return self.config.min_local_map_inliers

    def fetch_window(self, frame: Frame, candidates: CandidateSource, unanswered: int) -> None:
        """With a saved map: when the reference keyframe is a saved one whose window was not fetched
        last, bring its covisible neighbours (the backend's) into the cache, so that local-map
        tracking finds the saved map beyond what relocalisation brought. Restored keyframes pace no
        eviction pass (no keyframe is inserted in localisation mode): past the cache's size by the
        keyframes between passes, a pass runs here (``unanswered``: keyframes sent, not answered)."""
        slot = self.state.reference_slot
        reference = self.map.keyframe(slot) if slot >= 0 else None
        if reference is None or reference.id >= self.config.local_map.keyframe_id_start or reference.id == self._window_of:
            return
        self._window_of = int(reference.id)
        started = time.perf_counter()
        cfg = self.config.relocalisation
        empty = np.zeros(0, dtype=np.int64)
        query = RelocalisationQuery(frame.stamp_ns, empty, empty.astype(float), 1, cfg.max_neighbours, window_keyframe_id=int(reference.id))
        reply = candidates(query)
        if reply is not None and reply.candidates:
            self.restore(keyframes_to_restore(reply, int(reference.id)), reply)
        limits = self.config.local_map
        if self.map.n_cached_keyframes > limits.cache_max_keyframes + limits.cache_min_keyframes_between_evictions:
            self.state.evict(self.eviction, unanswered, force=True)
        self.state.timers.ms["map_window"] = (time.perf_counter() - started) * 1e3

    def restore(self, keyframes: list[KeyFrame], reply: RelocalisationCandidates) -> None:
        """Bring the backend's ``keyframes`` (with the reply's points) into the cache; where points are
        weighed, estimate the covariance of every point they observe."""
        slots = restore_keyframes(self.map, keyframes, reply.points)
        if not self.weighs_points or not slots:
            return
        rows = np.unique(np.concatenate([self.map.keyframe_point_rows(slot) for slot in slots]))
        self.map.set_covariances(rows, point_covariances(self.map, rows, self.calibration, self.config.localization_point_max_sigma_m))
