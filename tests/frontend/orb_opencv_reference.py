"""OpenCV's ORB.compute as the ORB extractor once called it, the reference its compiled rBRIEF kernel must equal byte for byte.

tests/frontend/test_orb_descriptor.py compares them; benchmarks/compiled_kernels.py times one against the other.
"""

from __future__ import annotations

import cv2
import numpy as np

_PATCH_SIZE = 31
_EDGE_THRESHOLD = 19


def reference_orb() -> cv2.ORB:
    """An ORB that only describes: one level, the extractor's border and patch."""
    return cv2.ORB_create(nfeatures=4800, nlevels=1, edgeThreshold=_EDGE_THRESHOLD, firstLevel=0, WTA_K=2, patchSize=_PATCH_SIZE)


def reference_describe(image: np.ndarray, xy: np.ndarray, angle_deg: np.ndarray, orb: cv2.ORB | None = None) -> np.ndarray:
    """(K, 32) uint8: ORB.compute on keypoints at (K, 2) level pixels ``xy`` with angles ``angle_deg`` (degrees).

    ORB.compute blurs its border-extended copy of the image (7x7, sigma 2, BORDER_REFLECT_101) and
    steers the pattern by the given angle; it does not recompute orientation for provided keypoints.
    """
    if len(xy) == 0:
        return np.zeros((0, 32), np.uint8)
    xy32 = np.asarray(xy, np.float32)
    sizes = [float(_PATCH_SIZE)] * len(xy)
    keypoints = list(map(cv2.KeyPoint, xy32[:, 0].tolist(), xy32[:, 1].tolist(), sizes, np.asarray(angle_deg, np.float32).tolist()))
    kept, descriptors = (orb or reference_orb()).compute(image, keypoints)
    if descriptors is None or len(kept) != len(xy):
        raise RuntimeError(f"ORB.compute dropped keypoints ({len(xy)} in, {len(kept)} out)")
    return descriptors
