"""The synthetic renderer's pixel work, compiled: a textured tile's z-test and coverage, and bilinear texture sampling.

``Renderer._draw`` works out, per tile, the plane's inverse depth as an affine function of the
pixel, the image half-planes of the tile's edges and the image-to-texel map of its mip level;
``raster_tile`` then visits each pixel of the tile's bounding box once.

The texture is sampled here rather than by ``cv2.warpPerspective``, whose output is not a function
of its input alone: OpenCV 4.14 quantises source coordinates to 1/32 texel, 5.0 does not, and
5.0's AVX2 path rounds differently from its baseline path. A synthetic scene is the input of every
synthetic test and benchmark, many of them run in process with the machine's own kernels, so it
must not change with the machine. Every step is an IEEE-754 operation rounded exactly (+, -, *, /,
floor, rint) in the precision the former numpy rasteriser used (float32 for the inverse depth,
the edge tests and the interpolation, float64 for the texel coordinates), in its order, so the
images have its bits (tests/service/sources/test_tile_raster.py keeps it and compares). numba
without fastmath neither contracts nor reorders floating-point operations, so that holds on every
x86-64 target. The homographies come from 3x3 products and inverses (the renderer's, numpy's).
"""

from __future__ import annotations

import numpy as np

from zenslam.compiled import inlined_kernel, kernel

_INT32_MIN = -(2**31)


def raster_tile(
    grey: np.ndarray,
    inv_depth: np.ndarray,
    roi: tuple[int, int, int, int],
    plane: tuple[np.float32, np.float32, np.float32],
    near_limit: np.float32 | None,
    edges: np.ndarray,
    texture: np.ndarray,
    M: np.ndarray,
) -> None:
    """Draw one tile into ``grey`` (uint8, H x W) and ``inv_depth`` (float32, H x W), in place.

    ``roi`` = (x0, y0, x1, y1), the half-open pixel box to visit. ``plane`` = (a, b, k), float32:
    the tile's inverse depth at pixel (u, v) is (u * a + k) + v * b. A pixel is drawn when that
    exceeds ``inv_depth`` there, is below ``near_limit`` (when given: the tile crosses the near
    plane) and is on the non-negative side of every row (e0, e1, e2) of ``edges`` (float32,
    m x 3: u * e0 + (v * e1 + e2) >= 0). A drawn pixel takes the tile's inverse depth and
    ``sample_bilinear``'s value of ``texture`` through ``M``.
    """
    x0, y0, x1, y1 = (int(v) for v in roi)
    a, b, k = (np.float32(v) for v in plane)
    near = near_limit is not None
    limit = np.float32(near_limit) if near else np.float32(0.0)
    edges = np.ascontiguousarray(edges, np.float32).reshape(-1, 3)
    _raster(grey, inv_depth, x0, y0, x1, y1, a, b, k, near, limit, edges, _texture(texture), _matrix(M))


def sample_bilinear(
    texture: np.ndarray, M: np.ndarray, cols: np.ndarray, rows: np.ndarray, mask: np.ndarray | None = None
) -> np.ndarray:
    """Texture values (uint8) at pixels (``cols``, ``rows``), which ``M`` maps to texels.

    ``texture`` is uint8 (H, W); ``M`` (3, 3) maps a pixel (column, row, 1) to a homogeneous texel
    (column, row) with texel centres at integer coordinates, as ``cv2.warpPerspective`` with
    ``WARP_INVERSE_MAP`` reads it. ``cols`` and ``rows`` are float64 arrays that broadcast together
    (a row of columns and a column of rows give a block), and the result has their broadcast shape;
    with ``mask`` (of that shape) only the masked pixels, in row-major order (as ``block[mask]``).
    Each value is the exact bilinear interpolation at the pixel's texel, rounded half to even;
    texels past the border are reflected (BORDER_REFLECT_101).
    """
    cols, rows = np.broadcast_arrays(np.asarray(cols, np.float64), np.asarray(rows, np.float64))
    if mask is not None:
        cols, rows = cols[mask], rows[mask]
    values = _sample_points(_texture(texture), _matrix(M), np.ascontiguousarray(cols).ravel(), np.ascontiguousarray(rows).ravel())
    return values.reshape(cols.shape)


def _texture(texture: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(texture, np.uint8)


def _matrix(M: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(M, np.float64).reshape(3, 3)


@inlined_kernel
def _reflect_101(index, size):
    """``index`` folded into [0, size) as BORDER_REFLECT_101 folds it (-1 -> 1, size -> size - 2)."""
    if size == 1:
        return 0
    if 0 <= index < size:
        return index
    period = 2 * size - 2
    folded = index % period  # numba's % on integers is Python's: in [0, period)
    return period - folded if folded >= size else folded


@inlined_kernel
def _texel_index(floor):
    """``floor`` (a float64 integer) as int32, as numpy converts it on x86-64: out of int32's range
    (a ray grazing the plane), int32's minimum."""
    if -2147483648.0 <= floor < 2147483648.0:
        return np.int64(floor)
    return np.int64(_INT32_MIN)


@inlined_kernel
def _next_int32(index):
    """index + 1 in int32 arithmetic (wrapping at its maximum), as numpy adds 1 to an int32 array."""
    return np.int64(_INT32_MIN) if index == 2147483647 else index + 1


@inlined_kernel
def _sample(texture, M, col, row):
    """The bilinear texture value at pixel (``col``, ``row``), float64: see ``sample_bilinear``."""
    height, width = texture.shape
    w = (M[2, 0] * col + M[2, 2]) + M[2, 1] * row
    x = ((M[0, 0] * col + M[0, 2]) + M[0, 1] * row) / w
    y = ((M[1, 0] * col + M[1, 2]) + M[1, 1] * row) / w
    x_floor, y_floor = np.floor(x), np.floor(y)
    fx, fy = np.float32(x - x_floor), np.float32(y - y_floor)
    xi, yi = _texel_index(x_floor), _texel_index(y_floor)
    c0, c1 = _reflect_101(xi, width), _reflect_101(_next_int32(xi), width)
    r0, r1 = _reflect_101(yi, height), _reflect_101(_next_int32(yi), height)
    top_left, top_right = np.float32(texture[r0, c0]), np.float32(texture[r0, c1])
    bottom_left, bottom_right = np.float32(texture[r1, c0]), np.float32(texture[r1, c1])
    top = top_left + fx * (top_right - top_left)
    bottom = bottom_left + fx * (bottom_right - bottom_left)
    return np.uint8(np.rint(top + fy * (bottom - top)))  # a convex combination of bytes stays in [0, 255]


@kernel
def _sample_points(texture, M, cols, rows):
    out = np.empty(len(cols), np.uint8)
    for i in range(len(cols)):
        out[i] = _sample(texture, M, cols[i], rows[i])
    return out


@kernel
def _raster(grey, inv_depth, x0, y0, x1, y1, a, b, k, near, limit, edges, texture, M):
    for y in range(y0, y1):
        v = np.float32(y)
        for x in range(x0, x1):
            u = np.float32(x)
            iz = (u * a + k) + v * b
            if not iz > inv_depth[y, x] or (near and not iz < limit):
                continue
            covered = True
            for e in range(edges.shape[0]):
                if not u * edges[e, 0] + (v * edges[e, 1] + edges[e, 2]) >= np.float32(0.0):
                    covered = False
                    break
            if covered:
                inv_depth[y, x] = iz
                grey[y, x] = _sample(texture, M, np.float64(x), np.float64(y))
