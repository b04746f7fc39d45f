"""The essential-graph optimisation's settings, result and error, and the similarity decomposition
that ``pose_graph`` and ``pose_graph_solver`` both use (below both, so neither imports the other's types)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from zenslam.errors import ZenslamError

RobustMethod = Literal["cauchy", "gnc", "none"]


class PoseGraphError(ZenslamError):
    """The pose graph names a keyframe without a pose, has no fixed keyframe, or a pose is not a similarity."""


@dataclass(frozen=True)
class PoseGraphConfig:
    """Settings of the essential-graph optimisation (ORB-SLAM: 20 iterations, identity information)."""

    iterations: int = 20  # Levenberg-Marquardt iterations at most (count)
    # Noise of every edge's relative pose: rotation (rad), translation (map units: metres for
    # stereo/RGB-D), log scale (Sim(3) graphs, unitless). Only their ratios matter without
    # robust kernels; with them, a loop edge is judged against the chain's ability to absorb it.
    sigma_rotation_rad: float = 0.002
    sigma_translation_m: float = 0.01
    sigma_log_scale: float = 0.01
    robust: RobustMethod = "cauchy"
    cauchy_k: float = 1.0  # Cauchy kernel width on the whitened residual norm (unitless)
    # A new loop whose every edge ends with a robust weight below this is rejected: the result is
    # then the poses before correction (the optimum of the graph without it) and ``loop_rejected``
    # is set. 0 keeps whatever the optimiser returned (ORB-SLAM has no rejection here).
    reject_below_weight: float = 0.5
    # GNC: a loop edge is an inlier when its whitened squared error is below the chi2 quantile of
    # this probability for its dimension (gtsam's setInlierCostThresholdsAtProbability).
    gnc_inlier_probability: float = 0.99
    gnc_loss: Literal["tls", "gm"] = "tls"
    relative_error_tolerance: float = 1e-6  # LM stops when the error drops by less than this fraction
    # Covisibility edges are relative poses of the same map poses the spanning tree already links, not
    # independent measurements: given each the full information (ORB-SLAM's identity), the many
    # covisibility edges per keyframe make the chain so stiff that it rejects true loops of a few
    # centimetres. "shared": their sigmas times sqrt(covisibility edges / other edges), so together
    # they weigh what the spanning tree and loop edges weigh. "full": every edge at the sigmas above.
    # Stereo / RGB-D (SE(3) graphs): "full". The stiff chain costs some true loops, but it is also what
    # stops a correction that verification got centimetres wrong, which with metric depth does more
    # harm than a loop left open (benchmarks/loop_closing.md).
    covisibility_information: Literal["full", "shared"] = "full"
    # Monocular (Sim(3) graphs): "shared". Their true loops carry scale drift besides, which a stiff
    # chain cannot take, so it rejects nearly every one; the wrong loops sharing lets through are
    # refused first by loop closing's ``drift_budget_monocular``.
    covisibility_information_monocular: Literal["full", "shared"] = "shared"

    def __post_init__(self) -> None:
        sigmas = (self.sigma_rotation_rad, self.sigma_translation_m, self.sigma_log_scale, self.cauchy_k)
        if not all(math.isfinite(v) and v > 0 for v in sigmas):
            raise PoseGraphError(f"pose graph sigmas and cauchy_k must be positive, got {sigmas}")
        if self.iterations < 1:
            raise PoseGraphError(f"pose_graph.iterations={self.iterations} must be at least 1")
        for name in ("covisibility_information", "covisibility_information_monocular"):
            if getattr(self, name) not in ("full", "shared"):
                raise PoseGraphError(f"pose_graph.{name}={getattr(self, name)!r} must be 'full' or 'shared'")


@dataclass(frozen=True)
class PoseGraphResult:
    """Optimised keyframe poses; ``S_world_cam_initial`` is where each started (the poses the map's
    points agree with when the corrected neighbourhood's points were moved with it)."""

    T_world_cam: dict[int, np.ndarray]  # (4, 4) rigid camera -> world: rotation and camera centre
    scale: dict[int, float]  # s of the optimised similarity (1.0 in rigid graphs)
    S_world_cam_initial: dict[int, np.ndarray]  # (4, 4) [[s R, c], [0, 1]] initial values
    loop_edge_weights: dict[tuple[int, int], float]  # (a, b), a < b -> final robust weight in [0, 1]
    stats: dict = field(default_factory=dict)  # time_ms, n_edges, initial/final_error, start, ...

    def S_world_cam(self, kf_id: int) -> np.ndarray:
        """The optimised pose of ``kf_id`` as a (4, 4) similarity [[s R, c], [0, 1]]."""
        S = self.T_world_cam[kf_id].copy()
        S[:3, :3] *= self.scale[kf_id]
        return S


def similarity_parts(S: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """R (..., 3, 3), c (..., 3) and s (...) of similarities [[s R, c], [0, 1]] (4, 4) or (K, 4, 4);
    PoseGraphError naming the first one that is not a similarity with s > 0."""
    S = np.asarray(S, dtype=float)
    if S.shape[-2:] != (4, 4):
        raise PoseGraphError(f"poses must be 4x4 similarities, got shape {S.shape}")
    A = S[..., :3, :3]
    s = np.cbrt(np.linalg.det(A))
    gram = np.einsum("...ji,...jk->...ik", A, A)
    s2 = np.maximum(s, 1e-300)[..., None, None] ** 2
    ok = (s > 0) & np.isfinite(S).all(axis=(-2, -1)) & (np.abs(gram - s2 * np.eye(3)) <= 1e-6 * s2).all(axis=(-2, -1))
    if not np.all(ok):
        bad = S if S.ndim == 2 else S[np.flatnonzero(~ok)[0]]
        raise PoseGraphError(f"pose {bad.tolist()} is not a similarity [[s R, c], [0, 1]] with s > 0")
    return A / s[..., None, None], S[..., :3, 3].copy(), s
