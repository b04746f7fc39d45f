"""OpenCV's ORB.compute as the ORB extractor once called it, and the blur it applies inside: the references
of the compiled rBRIEF kernel, which must give ORB.compute's bytes on ORB.compute's blurred image.

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


def reference_blur(image: np.ndarray) -> np.ndarray:
    """The blur ORB.compute applies: GaussianBlur on a view into its border-extended copy of the image,
    which takes the separable filter with float32 Gaussian taps (on this CPU's dispatch path)."""
    taps = cv2.getGaussianKernel(7, 2.0, cv2.CV_32F)
    return cv2.sepFilter2D(image, -1, taps, taps, borderType=cv2.BORDER_REFLECT_101)


def reference_baseline_blur(image: np.ndarray) -> np.ndarray:
    """``reference_blur`` as OpenCV's SSE baseline path computes it, in numpy float32: the rows with the
    7 taps in order, then the columns symmetrically (the centre tap, then each pair of rows summed
    before its tap), rounded half to even. Equal to sepFilter2D with OpenCV pinned to its baseline."""
    taps = cv2.getGaussianKernel(7, 2.0, cv2.CV_32F).ravel().astype(np.float32)
    rows, cols = image.shape
    padded = np.pad(image.astype(np.float32), ((0, 0), (3, 3)), mode="reflect")  # numpy's reflect is REFLECT_101
    filtered = taps[0] * padded[:, :cols]
    for k in range(1, 7):
        filtered = filtered + taps[k] * padded[:, k : k + cols]
    padded = np.pad(filtered, ((3, 3), (0, 0)), mode="reflect")
    out = taps[3] * padded[3 : 3 + rows]
    for k in (1, 2, 3):
        out = out + taps[3 + k] * (padded[3 - k : 3 - k + rows] + padded[3 + k : 3 + k + rows])
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


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
