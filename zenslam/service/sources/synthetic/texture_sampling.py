"""Bilinear texture sampling through a homography, with the same bits on every CPU and OpenCV version.

The renderer used ``cv2.warpPerspective`` for this, but its output is not a function of its input
alone: OpenCV 4.14 quantises source coordinates to 1/32 texel, 5.0 does not, and 5.0's AVX2 path
rounds differently from its baseline path (the same call gave other pixels with
``OPENCV_CPU_DISABLE=AVX2``). A synthetic scene is the input of every synthetic test and benchmark,
many of them run in process with the machine's own kernels, so it must not change with the machine.
Every step here is an IEEE-754 elementwise operation that numpy rounds exactly (+, -, *, /, floor,
rint), so a pixel is the exact bilinear interpolation at its projected centre, rounded half to even.
The homography itself comes from 3x3 products and an inverse (the renderer's); the frames came out
the same under every OpenBLAS core type and numpy dispatch tried (benchmarks/synthetic_scenes.md),
and the stages pin those kernels anyway (``runtime.cpu_kernels``).
"""

from __future__ import annotations

import numpy as np


def reflect_101(index: np.ndarray, size: int) -> np.ndarray:
    """``index`` folded into [0, size) as OpenCV's BORDER_REFLECT_101 does (-1 -> 1, size -> size - 2)."""
    if size == 1:
        return np.zeros_like(index)
    low, high = int(index.min(initial=0)), int(index.max(initial=0))
    if low >= 0 and high < size:
        return index  # every texel inside
    period = 2 * size - 2
    index = np.mod(index, period)
    return np.where(index >= size, period - index, index)


def sample_bilinear(
    texture: np.ndarray, M: np.ndarray, cols: np.ndarray, rows: np.ndarray, mask: np.ndarray | None = None
) -> np.ndarray:
    """Texture values (uint8) at pixels (``cols``, ``rows``), which ``M`` maps to texels.

    ``texture`` is uint8 (H, W); ``M`` (3, 3) maps a pixel (column, row, 1) to a homogeneous texel
    (column, row) with texel centres at integer coordinates, as ``cv2.warpPerspective`` with
    ``WARP_INVERSE_MAP`` reads it. ``cols`` and ``rows`` are float64 arrays that broadcast together
    (a row of columns and a column of rows give a block), and the result has their broadcast shape;
    with ``mask`` (of that shape) only the masked pixels are sampled, returned in row-major order
    (as ``block[mask]``). Texels past the border are reflected (BORDER_REFLECT_101).
    """
    w = (M[2, 0] * cols + M[2, 2]) + M[2, 1] * rows
    x = ((M[0, 0] * cols + M[0, 2]) + M[0, 1] * rows) / w
    y = ((M[1, 0] * cols + M[1, 2]) + M[1, 1] * rows) / w
    if mask is not None:
        x, y = x[mask], y[mask]
    x_floor = np.floor(x)
    y_floor = np.floor(y)
    fx = (x - x_floor).astype(np.float32)
    fy = (y - y_floor).astype(np.float32)
    xi = x_floor.astype(np.int32)
    yi = y_floor.astype(np.int32)
    height, width = texture.shape
    flat = texture.ravel()
    if xi.size and xi.min() >= 0 and xi.max() < width - 1 and yi.min() >= 0 and yi.max() < height - 1:
        top_left_index = yi * width + xi  # the common case: all four texels inside, no border to fold
        top_right_index = top_left_index + 1
        bottom_left_index = top_left_index + width
        bottom_right_index = bottom_left_index + 1
    else:
        x0, x1 = reflect_101(xi, width), reflect_101(xi + 1, width)
        row0, row1 = reflect_101(yi, height) * width, reflect_101(yi + 1, height) * width
        top_left_index, top_right_index = row0 + x0, row0 + x1
        bottom_left_index, bottom_right_index = row1 + x0, row1 + x1
    top_left = np.take(flat, top_left_index).astype(np.float32)
    top_right = np.take(flat, top_right_index).astype(np.float32)
    bottom_left = np.take(flat, bottom_left_index).astype(np.float32)
    bottom_right = np.take(flat, bottom_right_index).astype(np.float32)
    top = top_left + fx * (top_right - top_left)
    bottom = bottom_left + fx * (bottom_right - bottom_left)
    value = top + fy * (bottom - top)
    return np.rint(value).astype(np.uint8)  # a convex combination of uint8 values stays in [0, 255]
