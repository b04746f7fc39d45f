"""The frontend's configuration: the ``frontend`` section of a run's YAML (keys equal the field names)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from zenslam.errors import ConfigError
from zenslam.frontend.keyframe_decision import KeyframeDecisionConfig
from zenslam.frontend.orb_extractor import OrbConfig
from zenslam.frontend.stereo_matcher import StereoMatchConfig
from zenslam.frontend.tracking_config import TrackingConfig
from zenslam.pose_optimizer import PoseOptimizerConfig

# Where the frontend's config holds its copy of the run's ``map`` section (``MapRulesConfig``),
# which the local map builds its covisibility graph with; the service fills it from ``map``.
MAP_RULES_PATH = ("tracking", "local_map", "map_rules")

@dataclass(frozen=True)
class FrontendConfig:
    """Tracking (ORB, stereo, pose optimisation, local map, keyframe decision) and the node's inbox."""

    orb: OrbConfig = field(default_factory=OrbConfig)
    stereo: StereoMatchConfig = field(default_factory=StereoMatchConfig)
    # A round of pose optimisation stops once a step is below 1e-5 (rad, m): half the time of the
    # optimiser's own 1e-9 for the same trajectory.
    pose: PoseOptimizerConfig = field(default_factory=lambda: PoseOptimizerConfig(step_tolerance=1e-5))
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    keyframe: KeyframeDecisionConfig = field(default_factory=KeyframeDecisionConfig)
    # Map updates the frontend's inbox holds before the backend's send blocks (lossless: never dropped).
    map_update_queue: int = 256  # map updates
    update_timeout_s: float = 300.0  # lockstep: seconds the frontend waits for the backend's update of one keyframe
    # Lockstep: the map updates of a keyframe made at frame n are applied before frame n + this
    # (1: before the next frame, the backend idle while tracking runs). With more, tracking goes on
    # for that many frames beside local mapping, as ORB-SLAM's tracking thread does beside its
    # local-mapping thread; where each update is applied is still fixed by the frame count, not
    # by time, so the run stays deterministic. Local mapping counts as busy meanwhile, so fewer
    # keyframes are made: faster, and less accurate where the map's accuracy comes from its
    # keyframes (docs/configuration.md). Frames that may ask the backend for relocalisation
    # candidates (tracking lost, a run entering or localising in a saved map) wait for every update.
    lockstep_lag_frames: int = 1
    # The bag-of-words vocabulary a lost frame is relocalised with: a file (zenslam's format or DBoW2's
    # ORBvoc.txt), None for the one shipped with zenslam. Loaded at start when relocalisation is on.
    vocabulary: str | None = None
    # Seconds a lost frame waits for the backend's relocalisation candidates (the backend answers
    # between two keyframes: in lockstep at once, otherwise after the keyframe it is mapping).
    relocalisation_timeout_s: float = 30.0

    def __post_init__(self) -> None:
        if self.map_update_queue < 1:
            raise ConfigError(f"frontend.map_update_queue={self.map_update_queue} must be at least 1 message")
        if self.lockstep_lag_frames < 1:
            raise ConfigError(f"frontend.lockstep_lag_frames={self.lockstep_lag_frames} must be at least 1 frame")
        if not self.update_timeout_s > 0:
            raise ConfigError(f"frontend.update_timeout_s={self.update_timeout_s} must be a positive number of seconds")
        if not self.relocalisation_timeout_s > 0:
            raise ConfigError(f"frontend.relocalisation_timeout_s={self.relocalisation_timeout_s} must be a positive number of seconds")


def entering_map(config: FrontendConfig, next_keyframe_id: int, next_point_id: int) -> FrontendConfig:
    """``config`` for a frontend that starts in a map it did not make (a saved map, or the backend's
    after the frontend restarted): frames stay lost until one relocalises into the map, and the
    keyframe and point ids it makes start past the map's (``next_*``), so none collides with one there."""
    tracking = config.tracking
    local_map = dataclasses.replace(
        tracking.local_map,
        keyframe_id_start=max(tracking.local_map.keyframe_id_start, int(next_keyframe_id)),
        point_id_start=max(tracking.local_map.point_id_start, int(next_point_id)),
    )
    return dataclasses.replace(config, tracking=dataclasses.replace(tracking, start_in_map=True, local_map=local_map))
