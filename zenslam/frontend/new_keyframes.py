"""The tracker's keyframes: whether a tracked frame becomes one (ORB-SLAM2's NeedNewKeyFrame over
the map cache) and making it, with new points at its near keypoints with depth."""

from __future__ import annotations

import numpy as np

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.frontend.frame import Frame
from zenslam.frontend.keyframe import KeyFrame, select_new_point_keypoints, unproject_keypoints
from zenslam.frontend.keyframe_decision import KeyframeDecisionConfig, KeyframeDecisionInputs, close_point_counts, need_new_keyframe
from zenslam.frontend.local_map import LocalMap
from zenslam.frontend.tracking_config import TrackingConfig
from zenslam.frontend.tracking_state import TrackerState
from zenslam.geometry import invert_T


class KeyframeMaker:
    """Decides and makes keyframes into the map cache; a new keyframe becomes ``state``'s reference."""

    def __init__(
        self, local_map: LocalMap, state: TrackerState, config: TrackingConfig, keyframe_config: KeyframeDecisionConfig,
        calibration: PinholeCalibration, sensor: SensorKind, th_depth_m: float,
    ) -> None:
        self.map = local_map
        self.state = state
        self.config = config
        self.keyframe_config = keyframe_config
        self.calibration = calibration
        self.sensor = sensor
        self.th_depth_m = th_depth_m

    def needed(self, frame: Frame, rows: np.ndarray, n_inliers: int, keyframes_in_flight: int) -> bool:
        """Whether the frame tracked with map rows ``rows`` (-1 none) and ``n_inliers`` becomes a keyframe."""
        if self.config.localization:
            return False  # ORB-SLAM's NeedNewKeyFrame in localisation mode
        state = self.state
        n_kfs = self.map.n_keyframes
        if self.config.start_in_map:
            # The map entered (a saved one, or the backend's after a frontend restart) counts: its
            # keyframes were made before ours, which are numbered from past its newest. Counted as
            # the first own keyframe id (culled ones included); ORB-SLAM's rules below ask only
            # whether the map is new (2 keyframes or fewer) or past one second of keyframes.
            n_kfs += self.config.local_map.keyframe_id_start
        paused = self.config.relocalisation.pause_keyframes and state.recently_relocalised(frame, self.keyframe_config.max_frames)
        if paused and n_kfs > (self.keyframe_config.max_frames or state.camera_fps):
            return False  # ORB-SLAM: no keyframe within a second of a relocalisation
        min_obs = 1 if n_kfs <= 2 else self.config.reference_min_observations
        n_ref = self.map.tracked_points(state.reference_slot, min_obs) if state.reference_slot >= 0 else 0
        tracked_close, untracked_close = close_point_counts(frame.depth_m, rows >= 0, self.th_depth_m)
        inputs = KeyframeDecisionInputs(
            frames_since_last_keyframe=frame.index - state.last_keyframe_index,
            n_keyframes_in_map=n_kfs,
            n_inliers=n_inliers,
            n_reference_tracked=n_ref,
            n_tracked_close=tracked_close,
            n_untracked_close=untracked_close,
            camera_fps=state.camera_fps,
            sensor=self.sensor,
            keyframes_in_flight=keyframes_in_flight,
        )
        return need_new_keyframe(inputs, self.keyframe_config)

    def make(
        self,
        frame: Frame,
        T_cam_world: np.ndarray,
        rows: np.ndarray,
        new_kps: np.ndarray | None = None,
        new_points_world: np.ndarray | None = None,
    ) -> KeyFrame:
        """Make the frame a keyframe with new points at keypoints ``new_kps`` (default: its near
        keypoints with depth; none for a monocular camera), at ``new_points_world`` (default: from
        their depths); updates ``rows`` in place."""
        if new_kps is None and self.calibration.baseline_m is None:
            new_kps = np.zeros(0, dtype=np.int64)  # monocular: local mapping triangulates new points
        elif new_kps is None:
            max_depth_m = self.config.new_points_depth_baselines * self.calibration.baseline_m
            new_kps = select_new_point_keypoints(frame.depth_m, rows >= 0, max_depth_m, self.config.new_points_min)
        T_world_cam = invert_T(T_cam_world)
        feats = frame.features
        new_ids = self.map.new_point_ids(len(new_kps))
        point_ids = np.full(len(rows), -1, dtype=np.int64)
        point_ids[rows >= 0] = self.map.point_ids[rows[rows >= 0]]
        point_ids[new_kps] = new_ids
        keyframe = KeyFrame(
            id=self.map.new_keyframe_id(),
            frame_index=frame.index,
            stamp_ns=frame.stamp_ns,
            T_world_cam=T_world_cam,
            features=feats,
            right_u=frame.right_u,
            depth_m=frame.depth_m,
            map_point_ids=point_ids.astype(np.int64),
            new_point_ids=new_ids,
            new_point_keypoints=new_kps.astype(np.int64),
            new_points_world=(
                unproject_keypoints(feats.px[new_kps], frame.depth_m[new_kps], self.calibration, T_world_cam)
                if new_points_world is None
                else np.asarray(new_points_world, dtype=np.float64).reshape(-1, 3)
            ),
        )
        new_rows = self.map.insert_keyframe(keyframe, point_rows=rows)
        rows[new_kps] = new_rows
        self.state.reference_slot = self.map.slot_of(keyframe.id)
        self.state.last_keyframe_index = frame.index
        return keyframe
