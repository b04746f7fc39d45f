"""Procedural surface textures (deterministic from a seeded generator) and mip pyramids.

Corner-rich textures all over a surface (the room), or sparse ones: textured panels of reduced
contrast on a plain background (the corridor, where odometry must drift).
"""

from __future__ import annotations

import math

import cv2
import numpy as np


def _blocks(shape: tuple[int, int], cell_texels: float, rng: np.random.Generator) -> np.ndarray:
    """Random grey cells of ~``cell_texels`` size (uint8, ``shape``), at a random sub-cell offset."""
    h, w = shape
    rows, cols = math.ceil(h / cell_texels) + 2, math.ceil(w / cell_texels) + 2
    values = rng.integers(0, 256, size=(rows, cols), dtype=np.uint8)
    big = cv2.resize(values, (round(cols * cell_texels), round(rows * cell_texels)), interpolation=cv2.INTER_NEAREST)
    oy, ox = (int(v) for v in rng.integers(0, max(1, int(cell_texels)), size=2))
    return big[oy : oy + h, ox : ox + w]


def _smooth_field(shape: tuple[int, int], cell_texels: float, rng: np.random.Generator) -> np.ndarray:
    """A smooth random grey field (uint8) varying over ~``cell_texels``: the low-frequency background."""
    h, w = shape
    rows, cols = math.ceil(h / cell_texels) + 2, math.ceil(w / cell_texels) + 2
    values = rng.uniform(50.0, 200.0, size=(rows, cols)).astype(np.float32)
    big = cv2.resize(values, (round(cols * cell_texels), round(rows * cell_texels)), interpolation=cv2.INTER_CUBIC)
    return np.clip(big[:h, :w], 0, 255).astype(np.uint8)


def _draw_rectangles(img: np.ndarray, count: int, texels_per_m: float, rng: np.random.Generator) -> None:
    """Rotated filled rectangles, 3 to 35 cm long, with random grey levels; in place."""
    h, w = img.shape
    centres = rng.uniform((0.0, 0.0), (w, h), size=(count, 2))
    sizes = np.exp(rng.uniform(math.log(0.03), math.log(0.35), size=(count, 2))) * texels_per_m
    angles = rng.uniform(0.0, 180.0, size=count)
    greys = rng.integers(0, 256, size=count)
    for (cx, cy), (sw, sh), angle, grey in zip(centres, sizes, angles, greys):
        corners = cv2.boxPoints(((float(cx), float(cy)), (float(sw), float(sh)), float(angle)))
        cv2.fillConvexPoly(img, np.round(corners * 16).astype(np.int32), int(grey), cv2.LINE_8, 4)


def _draw_blobs(img: np.ndarray, count: int, texels_per_m: float, rng: np.random.Generator) -> None:
    """Filled ellipses, 2 to 15 cm across, with random grey levels; in place."""
    h, w = img.shape
    centres = rng.uniform((0.0, 0.0), (w, h), size=(count, 2))
    axes = np.exp(rng.uniform(math.log(0.01), math.log(0.075), size=(count, 2))) * texels_per_m
    angles = rng.uniform(0.0, 180.0, size=count)
    greys = rng.integers(0, 256, size=count)
    for (cx, cy), (ax, ay), angle, grey in zip(centres, axes, angles, greys):
        cv2.ellipse(img, ((float(cx), float(cy)), (2 * float(ax), 2 * float(ay)), float(angle)), int(grey), -1)


def procedural_texture(shape: tuple[int, int], texels_per_m: float, rng: np.random.Generator) -> np.ndarray:
    """A grey uint8 texture of ``shape`` (rows, cols) at ``texels_per_m``, rich in corners at several scales.

    Layers, coarse to fine: a smooth background, fragments of random-grey checkers with 37, 17 and
    7.5 cm cells (each covering random patches), rotated rectangles and blobs. Nothing repeats, so
    matching does not alias. Sizes are physical, so the look does not depend on the resolution.
    """
    h, w = shape
    img = _smooth_field(shape, 0.6 * texels_per_m, rng)
    for cell_m, coverage in ((0.37, 0.55), (0.17, 0.45), (0.075, 0.35)):
        layer = _blocks(shape, cell_m * texels_per_m, rng)
        patches = _blocks(shape, 2.7 * cell_m * texels_per_m, rng)
        np.copyto(img, layer, where=patches < int(coverage * 256))
    area_m2 = h * w / texels_per_m**2
    _draw_rectangles(img, max(1, round(35 * area_m2)), texels_per_m, rng)
    _draw_blobs(img, max(1, round(12 * area_m2)), texels_per_m, rng)
    # Soften the hard edges a little: bilinear sampling of a step edge aliases when minified.
    return cv2.GaussianBlur(img, (0, 0), 0.6)


def _plain_background(shape: tuple[int, int], texels_per_m: float, rng: np.random.Generator) -> np.ndarray:
    """A plain surface (float32 grey) softly shaded by +-10 grey levels around 128 over ~60 cm: no corners."""
    field = _smooth_field(shape, 0.6 * texels_per_m, rng).astype(np.float32)  # 50..200
    return np.float32(128.0) + (field - np.float32(125.0)) * np.float32(10.0 / 75.0)


def panel_texture(
    shape: tuple[int, int],
    texels_per_m: float,
    coverage: float,
    contrast: float,
    rng: np.random.Generator,
    pitch_m: float = 1.5,
) -> np.ndarray:
    """A grey uint8 texture of ``shape`` (rows, cols): textured panels on a plain background.

    The surface is cut into square cells of ``pitch_m``; each holds one axis-aligned panel of
    ``coverage`` of the cell's area (aspect ratio between 1:2 and 2:1, placed at random inside the
    cell), so panels are spread evenly and every layout is unique. A panel carries the procedural
    texture with its grey levels scaled by ``contrast`` around the background.
    """
    h, w = shape
    img = _plain_background(shape, texels_per_m, rng)
    pitch = pitch_m * texels_per_m
    for row0 in np.arange(0.0, h, pitch):
        for col0 in np.arange(0.0, w, pitch):
            aspect = math.exp(rng.uniform(math.log(0.5), math.log(2.0)))
            panel_w = min(pitch, math.sqrt(coverage * aspect) * pitch)
            panel_h = min(pitch, coverage * pitch * pitch / panel_w)
            x0 = col0 + rng.uniform(0.0, pitch - panel_w)
            y0 = row0 + rng.uniform(0.0, pitch - panel_h)
            c0, r0 = round(x0), round(y0)
            c1, r1 = min(w, round(x0 + panel_w)), min(h, round(y0 + panel_h))
            if c1 <= c0 or r1 <= r0:
                continue  # the cell's panel lies past the surface's edge
            panel = procedural_texture((r1 - r0, c1 - c0), texels_per_m, rng).astype(np.float32)
            img[r0:r1, c0:c1] += np.float32(contrast) * (panel - np.float32(128.0))
    # Soften the panels' borders as procedural_texture softens its edges.
    img = cv2.GaussianBlur(img, (0, 0), 0.6)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def texture_pyramid(texture: np.ndarray, min_size: int = 8) -> tuple[np.ndarray, ...]:
    """Mip levels by cv2.pyrDown until the smaller side would drop below ``min_size`` texels.

    pyrDown centres level-(L+1) texel i on level-L texel 2i, so level-L texel i sits at level-0 texel 2^L i.
    """
    levels = [np.ascontiguousarray(texture)]
    while min(levels[-1].shape) >= 2 * min_size:
        levels.append(cv2.pyrDown(levels[-1]))
    return tuple(levels)
