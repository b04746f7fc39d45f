"""Configuration of loop closing (the ``backend.loop_closing`` section): plain dataclasses, no gtsam."""

from __future__ import annotations

from dataclasses import dataclass, field

from zenslam.backend.global_ba import GlobalBAConfig
from zenslam.backend.pose_graph_types import PoseGraphConfig
from zenslam.backend.similarity import SimilarityOptimizationConfig, SimilarityRansacConfig
from zenslam.errors import ConfigError


@dataclass(frozen=True)
class LoopDetectionConfig:
    """When a keyframe's database candidates become loops to verify (ORB-SLAM2's values)."""

    min_keyframes: int = 10  # keyframes in the map before any detection
    keyframes_after_loop: int = 10  # keyframes inserted after a closed loop before detecting again
    min_consistency: int = 3  # consecutive keyframes whose candidate groups overlap


@dataclass(frozen=True)
class LoopVerificationConfig:
    """ORB-SLAM2's thresholds for accepting a loop candidate."""

    min_bow_matches: int = 20  # map-point matches by BoW to try a candidate
    bow_ratio: float = 0.75  # best / second-best descriptor distance in SearchByBoW
    ransac: SimilarityRansacConfig = field(default_factory=SimilarityRansacConfig)
    optimization: SimilarityOptimizationConfig = field(default_factory=SimilarityOptimizationConfig)
    sim3_search_radius_px: float = 7.5  # SearchBySim3 window at level 0 (x the level's scale)
    min_optimised_inliers: int = 20  # inliers after the transform's optimisation
    projection_radius_px: float = 10.0  # SearchByProjection window for the loop neighbourhood's points
    min_total_matches: int = 40  # current keyframe's keypoints matched to loop points, to accept


@dataclass(frozen=True)
class LoopClosingConfig:
    """The backend's loop closing (the ``backend.loop_closing`` section)."""

    enabled: bool = True  # detect and close loops; off = odometry with local mapping only
    detection: LoopDetectionConfig = field(default_factory=LoopDetectionConfig)
    verification: LoopVerificationConfig = field(default_factory=LoopVerificationConfig)
    fusion_radius_px: float = 4.0  # window for fusing loop points into the corrected neighbourhood (ORB-SLAM: 4)
    pose_graph: PoseGraphConfig = field(default_factory=PoseGraphConfig)
    # The largest move of the current keyframe's position a loop may make in a stereo / RGB-D map, as
    # a fraction of the keyframes' path from the loop keyframe to it (unitless; None: no limit, as
    # ORB-SLAM). True loops ask for a correction of a small fraction of the path; the wrong ones
    # verification lets through ask for far more, and over a long path the pose graph alone would
    # accept them. A map that drifts more than the budget loses its loops
    # (benchmarks/loop_closing.md).
    drift_budget: float | None = 0.05
    # The same for monocular (Sim(3)) maps, larger because scale drift makes true corrections larger.
    # Their pose graphs share the covisibility information
    # (``pose_graph.covisibility_information_monocular``), which lets true loops through and wrong
    # ones too: this budget is what refuses those (benchmarks/loop_closing.md).
    drift_budget_monocular: float | None = 0.10
    global_ba: GlobalBAConfig = field(default_factory=GlobalBAConfig)  # after each closed loop
    seed: int = 0  # seeds the verification's RANSAC (with the keyframe id, so each keyframe draws its own)

    def __post_init__(self) -> None:
        for name in ("drift_budget", "drift_budget_monocular"):
            value = getattr(self, name)
            if value is not None and not value > 0:
                raise ConfigError(f"backend.loop_closing.{name}={value} must be positive (or null: no limit)")


