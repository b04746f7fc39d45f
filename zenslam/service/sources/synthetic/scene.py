"""The synthetic room: floor, ceiling, walls, boxes and pillars as textured planar rectangles, split into tiles.

World frame: z up, floor at z = 0; the room spans x in [-5, 5], y in [-4, 4], z in [0, 3] metres.
Every trajectory keeps at least 1 m from every surface.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from zenslam.service.sources.synthetic.textures import procedural_texture, texture_pyramid

@dataclass(frozen=True, eq=False)
class Quad:
    """A planar rectangle {origin + s * axis_s + t * axis_t : 0 <= s <= size_s, 0 <= t <= size_t} (metres).

    Its visible side faces ``normal = axis_s x axis_t``; axes are unit vectors in the world frame.
    """

    origin_world: np.ndarray  # (3,) metres
    axis_s: np.ndarray  # (3,) unit
    axis_t: np.ndarray  # (3,) unit
    size_m: tuple[float, float]

    @property
    def normal(self) -> np.ndarray:
        """Unit normal of the visible side, world frame."""
        return np.cross(self.axis_s, self.axis_t)

    def corners_world(self) -> np.ndarray:
        """The 4 corners (4, 3) in metres, in order around the rectangle."""
        s, t = self.size_m
        a, b = self.axis_s * s, self.axis_t * t
        o = self.origin_world
        return np.stack([o, o + a, o + a + b, o + b])

    def point(self, s_m: np.ndarray, t_m: np.ndarray) -> np.ndarray:
        """World points (N, 3) at plane coordinates s, t (metres)."""
        return self.origin_world + np.outer(s_m, self.axis_s) + np.outer(t_m, self.axis_t)


@dataclass(frozen=True, eq=False)
class Tile:
    """Part of a surface: its rectangle, its surface's plane frame and a mip pyramid of its texture.

    Texel (i, j) of pyramid level L (column i, row j) has its centre at surface plane coordinates
    s = (2^L i + texel_offset[0] + 0.5) / texels_per_m, t = (2^L j + texel_offset[1] + 0.5) / texels_per_m.
    """

    quad: Quad  # the tile rectangle
    surface: Quad  # the whole surface the tile belongs to (its origin anchors the texture)
    surface_index: int
    texel_offset: tuple[int, int]  # (column, row) of the pyramid's level-0 texel (0, 0) in the surface texture
    texels_per_m: float
    pyramid: tuple[np.ndarray, ...]  # uint8 textures, level 0 first, each half the size of the previous


@dataclass(frozen=True, eq=False)
class Scene:
    """All surfaces and their tiles; built once per (seed, texture resolution, tile size)."""

    surfaces: tuple[Quad, ...]
    tiles: tuple[Tile, ...]
    seed: int
    texels_per_m: float
    tile_m: float


def _axis_face(lo: np.ndarray, hi: np.ndarray, axis: int, at_high: bool, facing: int) -> Quad:
    """The face of the axis-aligned box [lo, hi] normal to ``axis``, visible from the +/- ``facing`` side."""
    e = np.eye(3)
    a_idx, b_idx = (axis + 1) % 3, (axis + 2) % 3
    if facing < 0:
        a_idx, b_idx = b_idx, a_idx  # cyclic order gives +axis normal; swapping flips it
    origin = lo.astype(float).copy()
    origin[axis] = hi[axis] if at_high else lo[axis]
    size = (float(hi[a_idx] - lo[a_idx]), float(hi[b_idx] - lo[b_idx]))
    return Quad(origin, e[a_idx], e[b_idx], size)


def _box_faces(lo: tuple[float, ...], hi: tuple[float, ...], inward: bool, skip_z: bool) -> list[Quad]:
    """The faces of a box, seen from outside (an object) or inside (the room); ``skip_z`` drops top and bottom."""
    lo_a, hi_a = np.asarray(lo, float), np.asarray(hi, float)
    faces = []
    for axis in range(3):
        if skip_z and axis == 2:
            continue
        for at_high in (False, True):
            facing = 1 if at_high else -1
            faces.append(_axis_face(lo_a, hi_a, axis, at_high, -facing if inward else facing))
    return faces


def room_surfaces() -> tuple[Quad, ...]:
    """The fixed layout: a 10 x 8 x 3 m room, boxes along the walls and four floor-to-ceiling pillars."""
    surfaces = _box_faces((-5.0, -4.0, 0.0), (5.0, 4.0, 3.0), inward=True, skip_z=False)
    boxes = [  # (centre x, centre y, size x, size y, height) in metres, standing on the floor
        (-1.5, 3.35, 1.4, 0.8, 1.0),
        (2.0, -3.35, 1.0, 0.8, 0.7),
        (4.4, 1.0, 0.6, 1.2, 1.2),
        (-4.4, -1.5, 0.6, 1.0, 0.8),
        (0.6, 3.5, 0.6, 0.5, 1.6),
    ]
    for cx, cy, sx, sy, h in boxes:
        faces = _box_faces((cx - sx / 2, cy - sy / 2, 0.0), (cx + sx / 2, cy + sy / 2, h), inward=False, skip_z=True)
        top = _axis_face(np.array([cx - sx / 2, cy - sy / 2, 0.0]), np.array([cx + sx / 2, cy + sy / 2, h]), 2, True, 1)
        surfaces += tuple(faces) + (top,)
    for cx, cy in ((4.0, 3.2), (-4.0, 3.2), (-3.6, -3.3), (3.9, -3.1)):
        surfaces += tuple(_box_faces((cx - 0.2, cy - 0.2, 0.0), (cx + 0.2, cy + 0.2, 3.0), inward=False, skip_z=True))
    return surfaces


def _split(length_m: float, tile_m: float) -> list[tuple[float, float]]:
    n = max(1, math.ceil(length_m / tile_m - 1e-9))
    edges = [length_m * i / n for i in range(n + 1)]
    return list(zip(edges[:-1], edges[1:]))


def _tiles_of(
    surface: Quad, index: int, texture: np.ndarray, texels_per_m: float, tile_m: float, margin_texels: int = 16
) -> list[Tile]:
    """Cut ``surface`` into tiles; each keeps ``margin_texels`` of its neighbours' texture so that
    bilinear and mip sampling along tile edges is seamless."""
    tiles = []
    rows, cols = texture.shape
    for s0, s1 in _split(surface.size_m[0], tile_m):
        for t0, t1 in _split(surface.size_m[1], tile_m):
            origin = surface.origin_world + s0 * surface.axis_s + t0 * surface.axis_t
            quad = Quad(origin, surface.axis_s, surface.axis_t, (s1 - s0, t1 - t0))
            c0 = max(0, math.floor(s0 * texels_per_m) - margin_texels)
            c1 = min(cols, math.ceil(s1 * texels_per_m) + margin_texels)
            r0 = max(0, math.floor(t0 * texels_per_m) - margin_texels)
            r1 = min(rows, math.ceil(t1 * texels_per_m) + margin_texels)
            pyramid = texture_pyramid(texture[r0:r1, c0:c1])
            tiles.append(Tile(quad, surface, index, (c0, r0), texels_per_m, pyramid))
    return tiles


def build_scene(seed: int, texels_per_m: float, tile_m: float) -> Scene:
    """Generate every surface's texture (deterministic from ``seed``) and cut the surfaces into tiles."""
    surfaces = room_surfaces()
    tiles: list[Tile] = []
    for index, surface in enumerate(surfaces):
        size_s, size_t = surface.size_m
        shape = (max(1, math.ceil(size_t * texels_per_m)), max(1, math.ceil(size_s * texels_per_m)))
        rng = np.random.default_rng([seed, index])
        texture = procedural_texture(shape, texels_per_m, rng)
        tiles.extend(_tiles_of(surface, index, texture, texels_per_m, tile_m))
    return Scene(surfaces, tuple(tiles), seed, texels_per_m, tile_m)
