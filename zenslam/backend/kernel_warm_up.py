"""The backend's compiled kernels made ready before its first keyframe.

numba compiles a kernel at its first call, or loads it from its on-disk cache (a machine's first
start compiles, each later start loads, most of a second with numba's own start). Called while
the stage starts, that time is spent before the stage says it is alive, so the first keyframe
does not wait for it, and a lockstep frontend does not wait behind that keyframe.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from zenslam.backend.config import BackendConfig
from zenslam.backend.keyframe import BackendKeyframe
from zenslam.backend.map_point import PointGeometry
from zenslam.backend.point_fusion import match_projected
from zenslam.backend.triangulation import candidate_pairs, fundamental_matrix
from zenslam.camera import PinholeCalibration
from zenslam.geometry import make_T
from zenslam.map_point_rules import mean_viewing_directions, representative_descriptors
from zenslam.vocabulary.vocabulary import Vocabulary

logger = logging.getLogger(__name__)

_CALIBRATION = PinholeCalibration(100.0, 100.0, 50.0, 50.0, 100, 100, baseline_m=0.1)
_POINTS = np.array([[0.0, 0.0, 5.0], [0.5, -0.3, 4.0], [-0.4, 0.2, 6.0], [0.2, 0.4, 5.5]])


def _keyframe(kf_id: int, x_m: float, right: bool) -> BackendKeyframe:
    """A keyframe at ``x_m`` along x seeing ``_POINTS`` (with right-image u for all but the last when ``right``)."""
    T_world_cam = make_T(np.eye(3), np.array([x_m, 0.0, 0.0]))
    p_cam = _POINTS - T_world_cam[:3, 3]
    px = np.column_stack([100.0 * p_cam[:, 0] / p_cam[:, 2] + 50.0, 100.0 * p_cam[:, 1] / p_cam[:, 2] + 50.0])
    n = len(px)
    stereo = right & (np.arange(n) < n - 1)
    return BackendKeyframe(
        id=kf_id, stamp_ns=kf_id, T_world_cam=T_world_cam, calibration=_CALIBRATION, sensor="stereo",
        keypoints_px=px, levels=np.zeros(n, np.int64), angles_deg=np.zeros(n),
        right_u=np.where(stereo, px[:, 0] - _CALIBRATION.bf / p_cam[:, 2], -1.0),
        depth_m=np.where(stereo, p_cam[:, 2], -1.0), descriptors=np.zeros((n, 32), np.uint8),
        scale_factors=1.2 ** np.arange(2), map_point_ids=np.full(n, -1, np.int64),
    )  # fmt: skip


def warm_up_kernels(config: BackendConfig) -> float:
    """Run the compiled kernels of local mapping (the vocabulary's descent, the points' representative
    descriptors and viewing directions, triangulation's pair search, fusion's search by projection
    and, with ``schur_lm``, local BA) once on small inputs; returns the seconds it took."""
    start = time.perf_counter()
    kf1, kf2 = _keyframe(1, 0.0, True), _keyframe(2, 0.5, False)
    words = np.arange(3 * 32, dtype=np.uint8).reshape(3, 32)  # a root and two leaves
    Vocabulary(2, 1, np.array([-1, 0, 0]), words, np.ones(3)).transform(kf1.descriptors)
    representative_descriptors(words[None])
    mean_viewing_directions(_POINTS, np.zeros((len(_POINTS), 2, 3)))
    idx = np.arange(kf1.n_keypoints)
    nodes = np.zeros(kf1.n_keypoints, np.int64)
    mapping = config.local_mapping
    candidate_pairs(kf1, kf2, idx, idx, fundamental_matrix(kf1, kf2), mapping.triangulation, (nodes, nodes))
    normals = _POINTS / np.linalg.norm(_POINTS, axis=1)[:, None]
    far = np.full(len(_POINTS), 100.0)
    match_projected(kf1, PointGeometry(_POINTS, normals, far / 100.0, far), kf2.descriptors, mapping.fusion)
    if config.local_ba.method == "schur_lm":
        from zenslam.backend.schur_ba import load_compiled_kernels

        load_compiled_kernels()
    seconds = time.perf_counter() - start
    logger.info("compiled kernels ready in %.1f s (a first start on a machine compiles them)", seconds)
    return seconds
