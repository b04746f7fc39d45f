"""The orientation of an ORB keypoint: the direction of its intensity centroid in a radius-15 disc, compiled."""

from __future__ import annotations

import math

import numpy as np

from zenslam.compiled import kernel

HALF_PATCH = 15  # level pixels: intensity-centroid radius


def disc_half_widths() -> np.ndarray:
    """(16,) int64 u_max[|v|]: the disc's half width at row offset v, as ORB-SLAM / OpenCV build it."""
    u_max = np.zeros(HALF_PATCH + 1, np.int64)
    v_max = int(math.floor(HALF_PATCH * math.sqrt(2.0) / 2 + 1))
    v_min = int(math.ceil(HALF_PATCH * math.sqrt(2.0) / 2))
    for v in range(v_max + 1):
        u_max[v] = int(round(math.sqrt(HALF_PATCH**2 - v * v)))
    # make the circle symmetric under transposition, as ORB-SLAM / OpenCV do
    v0 = 0
    for v in range(HALF_PATCH, v_min - 1, -1):
        while u_max[v0] == u_max[v0 + 1]:
            v0 += 1
        u_max[v] = v0
        v0 += 1
    return u_max


def intensity_centroid_angles(image: np.ndarray, xy: np.ndarray, u_max: np.ndarray) -> np.ndarray:
    """Orientation (degrees in [0, 360), image axes) of the intensity centroid around each (K, 2) level pixel ``xy``.

    ``image`` is the grey uint8 level image, ``u_max`` the ``disc_half_widths``. Every keypoint must
    lie at least HALF_PATCH pixels inside the image.
    """
    if len(xy) == 0:
        return np.zeros(0, np.float32)
    moments = _centroid_moments(np.ascontiguousarray(image), np.asarray(xy, np.float64), u_max)
    # The integer moments are exact in float32 (|m| < 2**24); the angle is numpy's float32 arctan2.
    angle = np.degrees(np.arctan2(moments[:, 1], moments[:, 0]))
    return np.mod(angle, 360.0).astype(np.float32)


@kernel
def _centroid_moments(image, xy, u_max):
    """(K, 2) float32 (m_10, m_01): the disc's intensities weighted by their column and row offsets."""
    rows, cols = image.shape
    moments = np.empty((len(xy), 2), np.float32)
    for k in range(len(xy)):
        u0 = np.int64(np.rint(xy[k, 0]))
        v0 = np.int64(np.rint(xy[k, 1]))
        if not (HALF_PATCH <= u0 < cols - HALF_PATCH and HALF_PATCH <= v0 < rows - HALF_PATCH):
            raise IndexError("keypoint closer than 15 px to the image border")
        m10 = 0
        m01 = 0
        for dv in range(-HALF_PATCH, HALF_PATCH + 1):
            half = u_max[abs(dv)]
            row = image[v0 + dv, u0 - half : u0 + half + 1]
            row_sum = np.int32(0)  # int32 sums: at most 31 * 255 * 15, and they vectorise wider
            weighted = np.int32(0)
            for j in range(len(row)):
                value = np.int32(row[j])
                row_sum += value
                weighted += np.int32(j) * value
            m10 += weighted - half * row_sum  # sum of (j - half) * value
            m01 += dv * row_sum
        moments[k, 0] = m10
        moments[k, 1] = m01
    return moments
