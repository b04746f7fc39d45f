"""The synthetic worlds as textured planar rectangles split into tiles: the room, or the corridor ring.

The room: floor, ceiling, walls, boxes and pillars; world frame z up, floor at z = 0; the room spans
x in [-5, 5], y in [-4, 4], z in [0, 3] metres. The corridor: see ``corridor``. Every trajectory
keeps at least 1 m from every surface.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from zenslam.service.sources.synthetic.config import TextureConfig, World
from zenslam.service.sources.synthetic.corridor import CorridorLayout, corridor_surfaces
from zenslam.service.sources.synthetic.quad import Quad
from zenslam.service.sources.synthetic.textures import panel_texture, procedural_texture, texture_pyramid

__all__ = ["Quad", "Scene", "Tile", "build_scene", "room_surfaces", "surface_textures", "world_surfaces"]


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
    """All surfaces and their tiles; built once per (seed, texture resolution, tile size, world, texture style)."""

    surfaces: tuple[Quad, ...]
    tiles: tuple[Tile, ...]
    seed: int
    texels_per_m: float
    tile_m: float
    world: World = "room"
    texture: TextureConfig = TextureConfig()


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


def world_surfaces(world: World) -> tuple[Quad, ...]:
    """The fixed surfaces of ``world``: the room's, or the corridor ring's (default layout)."""
    return room_surfaces() if world == "room" else corridor_surfaces(CorridorLayout())


def _texture_shape(surface: Quad, texels_per_m: float) -> tuple[int, int]:
    size_s, size_t = surface.size_m
    return (max(1, math.ceil(size_t * texels_per_m)), max(1, math.ceil(size_s * texels_per_m)))


def _styled_texture(
    shape: tuple[int, int], texels_per_m: float, texture: TextureConfig, rng: np.random.Generator
) -> np.ndarray:
    if texture.sparse:
        return panel_texture(shape, texels_per_m, texture.coverage, texture.contrast, rng)
    return procedural_texture(shape, texels_per_m, rng)


def _is_wall(surface: Quad) -> bool:
    return abs(float(surface.normal[2])) < 1e-9


def _runs_up(surface: Quad) -> bool:
    """True when the wall's s axis (texture columns) runs up it, so its texture rows run along it."""
    return abs(float(surface.axis_s[2])) > 0.5


def _wall_strip_key(surface: Quad) -> int:
    """0 for walls facing the vertical axis through the origin (the corridor's outer walls), 1 for the others."""
    centre = surface.corners_world().mean(axis=0)
    return 0 if float(surface.normal[:2] @ centre[:2]) < 0 else 1


def _repeated_wall(surface: Quad, shape: tuple[int, int], strip: np.ndarray) -> np.ndarray:
    """The wall's texture of ``shape`` as ``strip`` (rows up from the wall's foot, columns along it) end to end."""
    rows, cols = (shape[1], shape[0]) if _runs_up(surface) else shape
    wall = np.tile(strip[:rows], (1, math.ceil(cols / strip.shape[1])))[:, :cols]
    return np.ascontiguousarray(wall.T if _runs_up(surface) else wall)


def surface_textures(
    surfaces: tuple[Quad, ...], seed: int, texels_per_m: float, texture: TextureConfig
) -> Iterator[np.ndarray]:
    """Each surface's texture in turn (uint8, rows along axis_t, columns along axis_s), deterministic from ``seed``.

    With ``texture.wall_repeat_m`` every wall (vertical surface) is one strip of that length laid end
    to end from the wall's start; walls facing the vertical axis through the origin share one strip,
    the others another, so a stretch of wall looks like every other one a whole number of strips
    away. Floors and ceilings stay unique.
    """
    strips: dict[int, np.ndarray] = {}
    walls = [q for q in surfaces if _is_wall(q)]
    if texture.wall_repeat_m > 0 and walls:
        height_m = max(q.size_m[0] if _runs_up(q) else q.size_m[1] for q in walls)
        strip_shape = (math.ceil(height_m * texels_per_m), max(1, round(texture.wall_repeat_m * texels_per_m)))
        for key in sorted({_wall_strip_key(q) for q in walls}):
            strips[key] = _styled_texture(strip_shape, texels_per_m, texture, np.random.default_rng([seed, 0x57, key]))
    for index, surface in enumerate(surfaces):
        shape = _texture_shape(surface, texels_per_m)
        if strips and _is_wall(surface):
            yield _repeated_wall(surface, shape, strips[_wall_strip_key(surface)])
        else:
            yield _styled_texture(shape, texels_per_m, texture, np.random.default_rng([seed, index]))


def build_scene(
    seed: int, texels_per_m: float, tile_m: float, world: World = "room", texture: TextureConfig = TextureConfig()
) -> Scene:
    """Generate every surface's texture (deterministic from ``seed``) and cut the surfaces into tiles."""
    surfaces = world_surfaces(world)
    tiles: list[Tile] = []
    for index, (surface, surface_texture) in enumerate(
        zip(surfaces, surface_textures(surfaces, seed, texels_per_m, texture), strict=True)
    ):
        tiles.extend(_tiles_of(surface, index, surface_texture, texels_per_m, tile_m))
    return Scene(surfaces, tuple(tiles), seed, texels_per_m, tile_m, world, texture)
