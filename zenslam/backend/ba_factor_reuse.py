"""Local BA's reprojection factors kept from one window to the next for observations that did not change."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from zenslam.camera import PinholeCalibration

if TYPE_CHECKING:
    from zenslam.backend.local_ba import BAProblem


def _measurements(problem: BAProblem) -> np.ndarray:
    """(O, 6) what a factor is made of besides its keys: u, v, stereo (1/0), right u (0 mono), 1/sigma^2,
    right-u sigma scale."""
    scale = np.ones(len(problem.obs_point)) if problem.obs_right_sigma_scale is None else problem.obs_right_sigma_scale
    stereo = np.isfinite(problem.obs_right_u)
    right_u = np.where(stereo, problem.obs_right_u, 0.0)
    return np.column_stack([problem.obs_px, stereo, right_u, problem.obs_inv_sigma2, scale])


@dataclass(frozen=True)
class FactorTable:
    """The factors one window was solved with, by (keyframe id, point id) and what they measure.

    gtsam factors are immutable once built, so a factor with the same keys, measurement, noise and
    calibration is the same factor: reusing it gives the same solve, bit for bit, without the
    ~1.5 us of Python per factor of building it again (consecutive windows share ~80% of them).
    """

    calibration: PinholeCalibration
    keyframe_ids: np.ndarray  # (F,) int64
    point_ids: np.ndarray  # (F,) int64
    measurements: np.ndarray  # (F, 6), see _measurements
    robust: np.ndarray  # (F,) bool: built with the Huber kernel
    factors: list  # (F,) gtsam factors

    @staticmethod
    def of(problem: BAProblem, factors: dict[int, object], robust: dict[int, bool]) -> FactorTable:
        """The table of ``factors`` (by observation row of ``problem``), built with kernels ``robust``."""
        rows = np.array(sorted(factors), dtype=np.int64)
        return FactorTable(
            calibration=problem.calibration,
            keyframe_ids=problem.keyframe_ids[problem.obs_keyframe[rows]],
            point_ids=problem.point_ids[problem.obs_point[rows]],
            measurements=_measurements(problem)[rows],
            robust=np.array([robust[r] for r in rows.tolist()], dtype=bool),
            factors=[factors[r] for r in rows.tolist()],
        )

    def reusable(self, problem: BAProblem, robust: bool) -> dict[int, object]:
        """Factors of this table valid for observation rows of ``problem`` with the kernel ``robust``."""
        if not self.factors or self.calibration != problem.calibration:
            return {}
        n = len(self.factors)
        kf_ids = np.concatenate([self.keyframe_ids, problem.keyframe_ids[problem.obs_keyframe]])
        point_ids = np.concatenate([self.point_ids, problem.point_ids[problem.obs_point]])
        # one integer per (keyframe, point) pair over both tables, then a 1-D join
        _, kf_code = np.unique(kf_ids, return_inverse=True)
        _, point_code = np.unique(point_ids, return_inverse=True)
        code = point_code.reshape(-1).astype(np.int64) * (int(kf_code.max()) + 1) + kf_code.reshape(-1)
        _, old, new = np.intersect1d(code[:n], code[n:], return_indices=True)
        same = (self.robust[old] == robust) & np.all(self.measurements[old] == _measurements(problem)[new], axis=1)
        return {r: self.factors[i] for i, r in zip(old[same].tolist(), new[same].tolist())}
