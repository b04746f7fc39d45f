"""Z-buffered rasteriser of textured planar tiles for a pinhole camera: grey image and exact per-pixel depth.

Each tile facing the camera is clipped to the view frustum; inside the image bounding box of its
projection the texture is resampled through the plane's homography (bilinear, from a mip level
chosen by the tile's texel-per-pixel footprint), and the plane's inverse depth, affine in pixel
coordinates, drives the z-buffer; ``tile_raster`` does the per-pixel work, with the same bits on
every CPU and OpenCV version. Pixel (u, v) is centred at integer coordinates.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.service.sources.synthetic.quad import Quad
from zenslam.service.sources.synthetic.scene import Tile


@dataclass(frozen=True)
class Rendering:
    """One camera's view: ``grey`` uint8 (H, W) and ``inv_depth`` float32 (H, W) in 1/m, 0 where empty."""

    grey: np.ndarray
    inv_depth: np.ndarray

    def depth_m(self) -> np.ndarray:
        """Depth along the optical axis (float32, metres), 0 where no surface was hit."""
        depth = np.zeros_like(self.inv_depth)
        np.divide(1.0, self.inv_depth, out=depth, where=self.inv_depth > 0)
        return depth


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


def _plane_to_cam(quad: Quad, R_cw: np.ndarray, t_cw: np.ndarray) -> np.ndarray:
    """3x3 map from the plane coordinates (s, t, 1) of ``quad``'s plane to camera coordinates, C-contiguous
    (as ``np.column_stack`` lays it out: the products with it take the same BLAS path)."""
    M = np.empty((3, 3))
    M[:, 0] = R_cw @ quad.axis_s
    M[:, 1] = R_cw @ quad.axis_t
    M[:, 2] = R_cw @ quad.origin_world + t_cw
    return M


class Renderer:
    """Renders a fixed set of tiles for one camera calibration; ``render`` takes the camera pose."""

    def __init__(self, tiles: Sequence[Tile], calibration: PinholeCalibration, near_m: float, margin_px: float = 2.0):
        self._tiles = tuple(tiles)
        self._cal = calibration
        self._K = calibration.K
        self._corners = np.stack([t.quad.corners_world() for t in self._tiles])  # (N, 4, 3)
        self._normals = np.stack([t.quad.normal for t in self._tiles])
        self._near_m = near_m
        # The compiled pixel loop is imported with the renderer, which a synthetic source builds at
        # its first frame: a source of recorded frames (KITTI, EuRoC, a bus) never loads numba.
        from zenslam.service.sources.synthetic.tile_raster import raster_tile

        self._raster_tile = raster_tile
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
                self._draw(i, poly, crosses_near, (R_cw, t_cw), grey, inv_depth)
        return Rendering(grey, inv_depth)

    def _draw(
        self,
        index: int,
        poly_cam: np.ndarray,
        crosses_near: bool,
        pose_cw: tuple[np.ndarray, np.ndarray],
        grey: np.ndarray,
        inv_depth: np.ndarray,
    ) -> None:
        """Z-test and texture tile ``index``, whose frustum-clipped polygon is ``poly_cam`` (k, 3), in place.

        ``pose_cw`` is (R_cam_world, t_cam_world); ``crosses_near`` says the tile reaches closer than near_m.
        """
        c = self._cal
        tile = self._tiles[index]
        R_cw, t_cw = pose_cw
        uv = poly_cam[:, :2] / poly_cam[:, 2:3] * (c.fx, c.fy) + (c.cx, c.cy)
        x0, y0 = max(0, math.floor(uv[:, 0].min())), max(0, math.floor(uv[:, 1].min()))
        x1, y1 = min(c.width, math.ceil(uv[:, 0].max()) + 1), min(c.height, math.ceil(uv[:, 1].max()) + 1)
        if x1 <= x0 or y1 <= y0:
            return
        # A plane n . p = d seen along the ray K^-1 (u, v, 1) has 1/z affine in (u, v).
        n_cam = R_cw @ self._normals[index]
        d = float(n_cam @ poly_cam[0])
        a, b = n_cam[0] / (c.fx * d), n_cam[1] / (c.fy * d)
        k = (n_cam[2] - n_cam[0] * c.cx / c.fx - n_cam[1] * c.cy / c.fy) / d
        edges = self._edge_half_planes(tile, R_cw, t_cw, (x0, y0, x1, y1))
        if edges is None:
            return
        level = self._mip_level(tile, self._homography(tile, 0, R_cw, t_cw), uv)
        M = np.linalg.inv(self._homography(tile, level, R_cw, t_cw))  # image pixel -> texel of the chosen level
        near_limit = np.float32(1.0 / self._near_m) if crosses_near else None
        plane = (np.float32(a), np.float32(b), np.float32(k))
        self._raster_tile(grey, inv_depth, (x0, y0, x1, y1), plane, near_limit, edges, tile.pyramid[level], M)

    def _edge_half_planes(
        self, tile: Tile, R_cw: np.ndarray, t_cw: np.ndarray, roi: tuple[int, int, int, int]
    ) -> np.ndarray | None:
        """The tile's edges as image half-planes (m, 3) float32 rows (e0, e1, e2), u * e0 + (v * e1 + e2) >= 0
        inside, for the edges that cut the box ``roi``; None when one leaves the whole box outside.

        The ray through pixel p meets the plane at tile coordinates (s, t, 1) / z = G p with G the inverse
        of the tile-plane-to-image homography, so each of s >= 0, s <= size_s, t >= 0, t <= size_t is a
        half-plane in the image (for z > 0; pixels seeing the plane behind the camera fail the depth test).
        Exact pixel-centre coverage matters: a pixel wrongly given to a face's extension past a convex
        edge would carry that face's depth and texture.
        """
        x0, y0, x1, y1 = roi
        quad = tile.quad
        G = np.linalg.inv(self._K @ _plane_to_cam(quad, R_cw, t_cw))
        size_s, size_t = quad.size_m
        corners = np.array([[x0, y0, 1.0], [x1 - 1, y0, 1.0], [x0, y1 - 1, 1.0], [x1 - 1, y1 - 1, 1.0]])
        cutting = []
        for edge in (G[0], size_s * G[2] - G[0], G[1], size_t * G[2] - G[1]):
            edge = edge / math.hypot(edge[0], edge[1])  # signed distance to the edge line, pixels
            edge[2] += 1e-3  # a hair of overlap so coplanar neighbours leave no gap
            at_corners = corners @ edge
            if (at_corners >= 0).all():
                continue
            if (at_corners < 0).all():
                return None
            cutting.append(edge)
        return np.array(cutting, np.float32).reshape(-1, 3)

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
        return self._K @ _plane_to_cam(surf, R_cw, t_cw) @ texel_to_plane

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
