"""ATE and RPE of an estimated trajectory against ground truth, computed with evo.

The estimate is associated with the ground truth by stamp (``evo.core.sync``), aligned to it with
evo's Umeyama (SE(3) for stereo/RGB-D, Sim(3) for monocular, or not at all), then evo's APE and
RPE metrics run on the aligned copies. ``Evaluation.to_json()`` gives the ``metrics.json``
sections documented in ``zenslam.service.evaluation.report``.
"""

from __future__ import annotations

import copy
import logging
from dataclasses import dataclass
from typing import Literal

from typing import TYPE_CHECKING

import numpy as np

from zenslam.errors import TrajectoryError
from zenslam.trajectory import Trajectory

# evo is imported where it is used: with pandas, scipy and matplotlib behind it, it is the largest
# import of a process (benchmarks/footprint.md), and the run's hub, which imports this module to
# build its command line, needs it only once its stages have exited.
if TYPE_CHECKING:
    from evo.core.trajectory import PoseTrajectory3D

logger = logging.getLogger(__name__)

Alignment = Literal["se3", "sim3", "none"]
DeltaUnit = Literal["frames", "m"]

_MIN_MATCHED_POSES = 3  # Umeyama needs three non-collinear points; fewer cannot be compared


@dataclass(frozen=True)
class EvaluationConfig:
    """How an estimate is compared with ground truth."""

    alignment: Alignment = "se3"  # se3 for stereo/RGB-D, sim3 (scale too) for monocular, none
    association: Literal["time", "index"] = "time"  # index: stamps are frame indices (KITTI files), equal ones pair
    max_time_diff_ns: int = 10_000_000  # ns, largest stamp difference of an associated pair (time association)
    rpe_delta: float = 1.0  # distance between the poses of an RPE pair, in rpe_delta_unit
    rpe_delta_unit: DeltaUnit = "frames"  # frames (matched poses) or m (path length along the ground truth)


@dataclass(frozen=True)
class AteResult:
    """Absolute trajectory error: statistics of the position error after alignment, metres."""

    rmse_m: float
    mean_m: float
    median_m: float
    max_m: float
    rmse_percent_of_path: float | None  # 100 * rmse / ground-truth path length; None for a zero-length path
    alignment: Alignment
    scale: float | None  # sim3 only: the factor applied to the estimate, p_gt ~ scale * R @ p_est + t
    matched_poses: int
    estimate_poses: int
    ground_truth_poses: int


@dataclass(frozen=True)
class RpeResult:
    """Relative pose error over pairs ``delta`` apart, after the same alignment as the ATE."""

    delta: float
    delta_unit: DeltaUnit
    trans_rmse_m: float  # RMSE of the translation part of the relative error, metres
    rot_rmse_deg: float  # RMSE of the rotation angle of the relative error, degrees
    pairs: int


@dataclass(frozen=True, eq=False)
class Evaluation:
    """Results of one comparison, with the aligned matched positions for plotting."""

    ate: AteResult
    rpe: RpeResult
    path_length_m: float  # path length of the matched ground truth, metres
    S_gt_est: np.ndarray  # (4, 4) the similarity applied to the estimate: [scale * R, t; 0, 1]
    T_world_cam_gt: np.ndarray  # (M, 4, 4) matched ground-truth poses
    T_world_cam_est_aligned: np.ndarray  # (M, 4, 4) matched estimate poses after alignment (in the gt world)
    stamps_ns: np.ndarray  # (M,) int64 stamps of the matched ground-truth poses, nanoseconds

    @property
    def p_world_gt(self) -> np.ndarray:
        """Matched ground-truth camera centres, (M, 3) metres."""
        return self.T_world_cam_gt[:, :3, 3]

    @property
    def p_world_est_aligned(self) -> np.ndarray:
        """Matched estimated camera centres after alignment, (M, 3) metres in the ground-truth world."""
        return self.T_world_cam_est_aligned[:, :3, 3]

    def to_json(self) -> dict[str, object]:
        """The ``ate``, ``rpe`` and ``path_length_m`` sections of ``metrics.json`` as a JSON-ready dict."""
        return {
            "ate": {
                "rmse_m": self.ate.rmse_m,
                "mean_m": self.ate.mean_m,
                "median_m": self.ate.median_m,
                "max_m": self.ate.max_m,
                "rmse_percent_of_path": self.ate.rmse_percent_of_path,
                "alignment": self.ate.alignment,
                "scale": self.ate.scale,
                "matched_poses": self.ate.matched_poses,
                "estimate_poses": self.ate.estimate_poses,
                "ground_truth_poses": self.ate.ground_truth_poses,
            },
            "rpe": {
                "delta": self.rpe.delta,
                "delta_unit": self.rpe.delta_unit,
                "trans_rmse_m": self.rpe.trans_rmse_m,
                "rot_rmse_deg": self.rpe.rot_rmse_deg,
                "pairs": self.rpe.pairs,
            },
            "path_length_m": self.path_length_m,
        }


def evaluate(estimate: Trajectory, ground_truth: Trajectory, config: EvaluationConfig | None = None) -> Evaluation:
    """ATE and RPE of ``estimate`` against ``ground_truth`` (both T_world_cam, metres, stamps in ns).

    Raises TrajectoryError when fewer than 3 poses associate or the alignment is degenerate.
    """
    from evo.core import metrics

    config = config or EvaluationConfig()
    ref, est = associate(estimate, ground_truth, config)
    t0_ns = _common_origin_ns(estimate, ground_truth)
    est, S_gt_est, scale = _align(ref, est, config.alignment)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    stats = ape.get_all_statistics()
    path_length_m = float(ref.path_length)
    rmse_m = float(stats["rmse"])
    ate = AteResult(
        rmse_m=rmse_m,
        mean_m=float(stats["mean"]),
        median_m=float(stats["median"]),
        max_m=float(stats["max"]),
        rmse_percent_of_path=100.0 * rmse_m / path_length_m if path_length_m > 0.0 else None,
        alignment=config.alignment,
        scale=scale,
        matched_poses=ref.num_poses,
        estimate_poses=len(estimate),
        ground_truth_poses=len(ground_truth),
    )
    return Evaluation(
        ate=ate,
        rpe=_rpe(ref, est, config),
        path_length_m=path_length_m,
        S_gt_est=S_gt_est,
        T_world_cam_gt=np.array(ref.poses_se3),
        T_world_cam_est_aligned=np.array(est.poses_se3),
        stamps_ns=t0_ns + np.round(np.asarray(ref.timestamps) * 1e9).astype(np.int64),
    )


def associate(
    estimate: Trajectory, ground_truth: Trajectory, config: EvaluationConfig
) -> tuple[PoseTrajectory3D, PoseTrajectory3D]:
    """Matched copies (ground truth, estimate) as evo trajectories, stamps in seconds from a common origin.

    Time association pairs each pose with the nearest stamp within ``config.max_time_diff_ns``;
    index association pairs equal stamps (frame indices).
    """
    from evo.core import sync

    for name, trajectory in (("estimate", estimate), ("ground truth", ground_truth)):
        if len(trajectory) == 0:
            raise TrajectoryError(f"the {name} trajectory has no poses; nothing to compare")
    t0_ns = _common_origin_ns(estimate, ground_truth)
    est = _to_evo(estimate, t0_ns, "estimate")
    ref = _to_evo(ground_truth, t0_ns, "ground truth")
    max_diff_s = 0.0 if config.association == "index" else config.max_time_diff_ns * 1e-9
    try:
        ref, est = sync.associate_trajectories(ref, est, max_diff=max_diff_s)
    except sync.SyncException:
        matched = 0
    else:
        matched = ref.num_poses
    if matched < _MIN_MATCHED_POSES:
        raise TrajectoryError(
            f"only {matched} poses associate ({config.association} association, max difference "
            f"{config.max_time_diff_ns if config.association == 'time' else 0} ns), at least {_MIN_MATCHED_POSES} "
            f"are needed: estimate {_describe_stamps(estimate)}, ground truth {_describe_stamps(ground_truth)}; "
            f"check both files use the same clock (KITTI files without a times file are stamped by frame index)"
        )
    logger.info("associated %d of %d estimate poses with ground truth", matched, len(estimate))
    return ref, est


def _common_origin_ns(estimate: Trajectory, ground_truth: Trajectory) -> int:
    """The stamp (ns) that evo's seconds count from: a common origin keeps ns resolution in float64
    seconds (1.4e18 ns would not)."""
    return int(min(estimate.stamps_ns[0], ground_truth.stamps_ns[0]))


def _to_evo(trajectory: Trajectory, t0_ns: int, name: str) -> PoseTrajectory3D:
    from evo.core.trajectory import PoseTrajectory3D

    stamps_s = (np.asarray(trajectory.stamps_ns, dtype=np.int64) - t0_ns).astype(np.float64) * 1e-9
    poses = [np.array(T, dtype=np.float64) for T in np.asarray(trajectory.T_world_cam)]
    return PoseTrajectory3D(timestamps=stamps_s, poses_se3=poses, name=name)


def _describe_stamps(trajectory: Trajectory) -> str:
    stamps = np.asarray(trajectory.stamps_ns)
    return f"{len(stamps)} poses stamped {int(stamps[0])} .. {int(stamps[-1])} ns"


def _align(
    ref: PoseTrajectory3D, est: PoseTrajectory3D, alignment: Alignment
) -> tuple[PoseTrajectory3D, np.ndarray, float | None]:
    """An aligned copy of ``est``, the similarity applied (4x4) and the scale (sim3 only)."""
    from evo import EvoException
    from evo.core import lie_algebra

    est = copy.deepcopy(est)  # evo aligns in place
    if alignment == "none":
        return est, np.eye(4), None
    try:
        R, t, s = est.align(ref, correct_scale=alignment == "sim3")
    except EvoException as exc:
        raise TrajectoryError(
            f"{alignment} alignment of {ref.num_poses} matched poses failed ({exc}); "
            f"the trajectory is degenerate (e.g. a single point or a line): use --align none"
        ) from exc
    return est, lie_algebra.sim3(R, t, s), float(s) if alignment == "sim3" else None


def _rpe(ref: PoseTrajectory3D, est: PoseTrajectory3D, config: EvaluationConfig) -> RpeResult:
    from evo import EvoException
    from evo.core import metrics
    from evo.core.units import Unit

    unit = Unit.frames if config.rpe_delta_unit == "frames" else Unit.meters
    rmse = {}
    for relation in (metrics.PoseRelation.translation_part, metrics.PoseRelation.rotation_angle_deg):
        try:
            # Pairs come from the ground truth so that a metre delta means metres actually travelled.
            rpe = metrics.RPE(relation, delta=config.rpe_delta, delta_unit=unit, pairs_from_reference=True)
            rpe.process_data((ref, est))
        except EvoException as exc:
            raise TrajectoryError(
                f"RPE with delta {config.rpe_delta} {config.rpe_delta_unit} failed on "
                f"{ref.num_poses} matched poses ({exc}); choose a smaller delta (a whole number of frames)"
            ) from exc
        rmse[relation] = float(rpe.get_statistic(metrics.StatisticsType.rmse))
    return RpeResult(
        delta=float(config.rpe_delta),
        delta_unit=config.rpe_delta_unit,
        trans_rmse_m=rmse[metrics.PoseRelation.translation_part],
        rot_rmse_deg=rmse[metrics.PoseRelation.rotation_angle_deg],
        pairs=len(rpe.error),
    )
