"""The synthetic renderer's per-pixel work as numpy formulated it before ``tile_raster`` compiled it: the reference
the compiled rasteriser must equal bit for bit (tests/service/sources/test_tile_raster.py).

Every step is an IEEE-754 elementwise operation that numpy rounds exactly (+, -, *, /, floor, rint),
so a pixel is the exact bilinear interpolation at its projected centre, rounded half to even.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.service.sources.synthetic.renderer import Rendering
from zenslam.service.sources.synthetic.scene import Tile


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


def _clip(poly: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """Sutherland-Hodgman: the part of convex polygon ``poly`` (k, 3) with plane[:3] . p + plane[3] >= 0."""
    d = poly @ plane[:3] + plane[3]
    out = []
    k = len(poly)
    for i in range(k):
        j = (i + 1) % k
        if d[i] >= 0:
            out.append(poly[i])
        if (d[i] >= 0) != (d[j] >= 0):
            out.append(poly[i] + (d[i] / (d[i] - d[j])) * (poly[j] - poly[i]))
    return np.array(out).reshape(-1, 3)


class NumpyRenderer:
    """The former ``Renderer``, whole: per tile, numpy on the pixels of its bounding box."""

    def __init__(self, tiles: Sequence[Tile], calibration: PinholeCalibration, near_m: float, margin_px: float = 2.0):
        self._tiles = tuple(tiles)
        self._cal = calibration
        self._K = calibration.K
        self._u = np.arange(calibration.width, dtype=np.float32)[None, :]
        self._v = np.arange(calibration.height, dtype=np.float32)[:, None]
        self._corners = np.stack([t.quad.corners_world() for t in self._tiles])  # (N, 4, 3)
        self._normals = np.stack([t.quad.normal for t in self._tiles])
        self._near_m = near_m
        self._frustum = self._frustum_planes(near_m, margin_px)

    def _frustum_planes(self, near_m: float, margin_px: float) -> np.ndarray:
        """(5, 4) planes a . p_cam + b >= 0: near plane and the image borders widened by ``margin_px``."""
        c = self._cal
        right, bottom = c.width - 1 - c.cx + margin_px, c.height - 1 - c.cy + margin_px
        return np.array(
            [
                [0.0, 0.0, 1.0, -near_m],
                [c.fx, 0.0, c.cx + margin_px, 0.0],
                [-c.fx, 0.0, right, 0.0],
                [0.0, c.fy, c.cy + margin_px, 0.0],
                [0.0, -c.fy, bottom, 0.0],
            ]
        )

    def render(self, T_world_cam: np.ndarray) -> Rendering:
        """Render the view of the camera at pose ``T_world_cam`` (4x4, camera to world)."""
        c = self._cal
        R_cw = T_world_cam[:3, :3].T
        t_cw = -R_cw @ T_world_cam[:3, 3]
        grey = np.zeros((c.height, c.width), np.uint8)
        inv_depth = np.zeros((c.height, c.width), np.float32)
        corners_cam = self._corners @ R_cw.T + t_cw  # (N, 4, 3)
        facing = np.einsum("nj,nj->n", T_world_cam[:3, 3] - self._corners[:, 0], self._normals) > 1e-9
        side = corners_cam @ self._frustum[:, :3].T + self._frustum[:, 3]  # (N, 4, 5)
        outside = np.any(np.all(side < 0, axis=1), axis=1)
        candidates = np.flatnonzero(facing & ~outside)
        # Front to back, so hidden tiles fail the depth test early and skip their texture warp.
        order = candidates[np.argsort(corners_cam[candidates, :, 2].min(axis=1), kind="stable")]
        for i in order:
            poly = corners_cam[i]
            crosses_near = bool(np.any(side[i, :, 0] < 0))
            for plane_index in np.flatnonzero(np.any(side[i] < 0, axis=0)):
                poly = _clip(poly, self._frustum[plane_index])
                if len(poly) < 3:
                    break
            if len(poly) >= 3:
                self._draw(self._tiles[i], poly, crosses_near, (R_cw, t_cw), grey, inv_depth)
        return Rendering(grey, inv_depth)

    def _draw(
        self,
        tile: Tile,
        poly_cam: np.ndarray,
        crosses_near: bool,
        pose_cw: tuple[np.ndarray, np.ndarray],
        grey: np.ndarray,
        inv_depth: np.ndarray,
    ) -> None:
        """Z-test and texture one tile whose frustum-clipped polygon is ``poly_cam`` (k, 3), in place.

        ``pose_cw`` is (R_cam_world, t_cam_world); ``crosses_near`` says the tile reaches closer than near_m.
        """
        c = self._cal
        R_cw, t_cw = pose_cw
        uv = poly_cam[:, :2] / poly_cam[:, 2:3] * (c.fx, c.fy) + (c.cx, c.cy)
        x0, y0 = max(0, math.floor(uv[:, 0].min())), max(0, math.floor(uv[:, 1].min()))
        x1, y1 = min(c.width, math.ceil(uv[:, 0].max()) + 1), min(c.height, math.ceil(uv[:, 1].max()) + 1)
        if x1 <= x0 or y1 <= y0:
            return
        # A plane n . p = d seen along the ray K^-1 (u, v, 1) has 1/z affine in (u, v).
        n_cam = R_cw @ tile.quad.normal
        d = float(n_cam @ poly_cam[0])
        a, b = n_cam[0] / (c.fx * d), n_cam[1] / (c.fy * d)
        k = (n_cam[2] - n_cam[0] * c.cx / c.fx - n_cam[1] * c.cy / c.fy) / d
        iz = (self._u[:, x0:x1] * np.float32(a) + np.float32(k)) + self._v[y0:y1] * np.float32(b)
        zb = inv_depth[y0:y1, x0:x1]
        visible = iz > zb
        if crosses_near:
            visible &= iz < np.float32(1.0 / self._near_m)
        if not self._inside_tile(tile, R_cw, t_cw, (x0, y0, x1, y1), visible):
            return
        np.copyto(zb, iz, where=visible)
        level = self._mip_level(tile, self._homography(tile, 0, R_cw, t_cw), uv)
        H_img_tex = self._homography(tile, level, R_cw, t_cw)
        M = np.linalg.inv(H_img_tex)  # image pixel -> texel of the chosen level
        cols = np.arange(x0, x1, dtype=np.float64)[None, :]
        rows = np.arange(y0, y1, dtype=np.float64)[:, None]
        grey[y0:y1, x0:x1][visible] = sample_bilinear(tile.pyramid[level], M, cols, rows, visible)

    def _inside_tile(
        self, tile: Tile, R_cw: np.ndarray, t_cw: np.ndarray, roi: tuple[int, int, int, int], visible: np.ndarray
    ) -> bool:
        """Clear ``visible`` where the pixel centre's ray misses the tile rectangle; False if nothing is left.

        The ray through pixel p meets the plane at tile coordinates (s, t, 1) / z = G p with G the inverse
        of the tile-plane-to-image homography, so each of s >= 0, s <= size_s, t >= 0, t <= size_t is a
        half-plane in the image (for z > 0; pixels seeing the plane behind the camera fail the depth test).
        Exact pixel-centre coverage matters: a pixel wrongly given to a face's extension past a convex
        edge would carry that face's depth and texture.
        """
        x0, y0, x1, y1 = roi
        quad = tile.quad
        plane_to_cam = np.column_stack([R_cw @ quad.axis_s, R_cw @ quad.axis_t, R_cw @ quad.origin_world + t_cw])
        G = np.linalg.inv(self._K @ plane_to_cam)
        size_s, size_t = quad.size_m
        corners = np.array([[x0, y0, 1.0], [x1 - 1, y0, 1.0], [x0, y1 - 1, 1.0], [x1 - 1, y1 - 1, 1.0]])
        for edge in (G[0], size_s * G[2] - G[0], G[1], size_t * G[2] - G[1]):
            edge = edge / math.hypot(edge[0], edge[1])  # signed distance to the edge line, pixels
            edge[2] += 1e-3  # a hair of overlap so coplanar neighbours leave no gap
            at_corners = corners @ edge
            if np.all(at_corners >= 0):
                continue
            if np.all(at_corners < 0):
                return False
            e = self._u[:, x0:x1] * np.float32(edge[0]) + (self._v[y0:y1] * np.float32(edge[1]) + np.float32(edge[2]))
            visible &= e >= 0
        return bool(visible.any())

    def _homography(self, tile: Tile, level: int, R_cw: np.ndarray, t_cw: np.ndarray) -> np.ndarray:
        """3x3 map from texel (column, row) of pyramid ``level`` to image pixel (homogeneous)."""
        surf = tile.surface
        scale = 2.0**level / tile.texels_per_m
        texel_to_plane = np.array(
            [
                [scale, 0.0, (tile.texel_offset[0] + 0.5) / tile.texels_per_m],
                [0.0, scale, (tile.texel_offset[1] + 0.5) / tile.texels_per_m],
                [0.0, 0.0, 1.0],
            ]
        )
        plane_to_cam = np.column_stack([R_cw @ surf.axis_s, R_cw @ surf.axis_t, R_cw @ surf.origin_world + t_cw])
        return self._K @ plane_to_cam @ texel_to_plane

    @staticmethod
    def _mip_level(tile: Tile, H_img_tex0: np.ndarray, uv: np.ndarray) -> int:
        """Pyramid level whose texels are about one pixel across at the polygon's image centroid.

        As in OpenGL's mipmapping, the footprint is the longer of the texel-space derivatives along u
        and v (so grazing surfaces blur rather than alias), rounded to the nearest level.
        """
        G = np.linalg.inv(H_img_tex0)  # image pixel -> level-0 texel (homogeneous)
        p = np.array([*uv.mean(axis=0), 1.0])
        x = G @ p
        J = (G[:2, :2] * x[2] - np.outer(x[:2], G[2, :2])) / x[2] ** 2  # d texel / d (u, v)
        texels_per_px = float(np.linalg.norm(J, axis=0).max())
        if texels_per_px <= 1.0:
            return 0
        return min(int(math.floor(math.log2(texels_per_px) + 0.5)), len(tile.pyramid) - 1)
