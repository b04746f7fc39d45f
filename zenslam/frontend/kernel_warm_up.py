"""The frontend's compiled kernels made ready before its first frame.

numba compiles a kernel at its first call, or loads it from its on-disk cache: a first start on a
machine compiles every kernel of the frontend (seconds), each later start loads them (under a
second, most of it numba's own start). Called while the stage starts, that time is spent before
the stage says it is alive, so no frame waits for it and a live camera drops none.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.frontend.feature_matcher import search_by_projection
from zenslam.frontend.orb_extractor import OrbConfig, OrbExtractor
from zenslam.frontend.stereo_matcher import match_stereo
from zenslam.map_point_rules import representative_descriptors
from zenslam.pose_optimizer import load_compiled_kernel

logger = logging.getLogger(__name__)

_IMAGE_SIDE_PX = 96  # a grey image large enough for two pyramid levels of ORB features


def warm_up_kernels() -> float:
    """Run every compiled kernel of the frontend once on small inputs; returns the seconds it took."""
    start = time.perf_counter()
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (_IMAGE_SIDE_PX, _IMAGE_SIDE_PX), dtype=np.uint8)
    image[:, _IMAGE_SIDE_PX // 2 :] = 128  # flat: cells without FAST(ini) corners, which take the FAST(min) path
    features, pyramid = OrbExtractor(OrbConfig(n_features=64, n_levels=2, threads=1)).extract(image)
    px, level, descriptors = features.px, features.level, features.descriptors
    search_by_projection(px, level, descriptors, px, level, descriptors, 4.0)
    match_stereo(features, features, pyramid, pyramid, PinholeCalibration(90.0, 90.0, 48.0, 48.0, 96, 96, baseline_m=0.1))
    representative_descriptors(descriptors[None, :3])
    load_compiled_kernel()
    seconds = time.perf_counter() - start
    logger.info("compiled kernels ready in %.1f s (a first start on a machine compiles them)", seconds)
    return seconds
