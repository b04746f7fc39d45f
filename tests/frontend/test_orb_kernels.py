"""The compiled quadtree and intensity-centroid kernels give exactly what the numpy formulation they replace gave."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from zenslam.frontend import orb_extractor
from zenslam.frontend.orb_extractor import OrbConfig, OrbExtractor
from zenslam.frontend.orb_orientation import disc_half_widths, intensity_centroid_angles
from zenslam.frontend.orb_quadtree import distribute_quadtree

from test_orb_extractor import textured_image  # noqa: E402  (tests/frontend is on the path under pytest)

_DEPTH = 16
_HALF_PATCH = 15


# ---- the numpy formulation, kept as the reference the kernels must equal bit for bit ----


def reference_quadtree(xy, response, width, height, n_target):
    n_keys = len(xy)
    if n_keys == 0 or n_target <= 0:
        return np.zeros(0, np.int64)
    n_ini = max(1, int(round(width / height)))
    step = width / n_ini
    side = 1 << _DEPTH
    ini = np.minimum(np.maximum((xy[:, 0] / step).astype(np.int64), 0), n_ini - 1)
    ix = np.minimum(np.maximum(((xy[:, 0] - ini * step) * (side / step)).astype(np.int64), 0), side - 1)
    iy = np.minimum(np.maximum((xy[:, 1] * (side / height)).astype(np.int64), 0), side - 1)
    code = (ini << (2 * _DEPTH)) | _spread_bits(ix) | (_spread_bits(iy) << 1)
    order = np.argsort(code, kind="stable")
    code = code[order]
    depth = 0
    while depth + 1 < _DEPTH and n_ini * 4 ** (depth + 2) <= n_target:
        depth += 1
    while depth < _DEPTH:
        depth += 1
        starts = np.flatnonzero(_node_start_mask(code, depth))
        n_to_expand = int(np.count_nonzero(_node_sizes(starts, n_keys) > 1))
        if len(starts) >= n_target or n_to_expand == 0:
            break
        if len(starts) + 3 * n_to_expand > n_target:
            starts = _split_largest_first(code, starts, depth, n_target)
            break
    return np.sort(order[_best_per_node(response[order], starts)])


def _split_largest_first(code, starts, depth, n_target):
    n_keys = len(code)
    while depth < _DEPTH:
        sizes = _node_sizes(starts, n_keys)
        candidates = np.flatnonzero(sizes > 1)
        if len(candidates) == 0:
            return starts
        is_child_start = _node_start_mask(code, depth + 1)
        n_children = np.add.reduceat(is_child_start, starts, dtype=np.int64)
        candidates = candidates[np.argsort(-sizes[candidates], kind="stable")]
        reached = np.flatnonzero(np.cumsum(n_children[candidates] - 1) >= n_target - len(starts))
        chosen = candidates if len(reached) == 0 else candidates[: reached[0] + 1]
        in_chosen = np.zeros(len(starts), bool)
        in_chosen[chosen] = True
        is_child_start &= np.repeat(in_chosen, sizes)
        is_child_start[starts] = True
        new_starts = np.flatnonzero(is_child_start)
        if len(new_starts) >= n_target:
            return new_starts
        starts = new_starts
        depth += 1
    return starts


def _node_start_mask(sorted_code, depth):
    prefix = sorted_code >> (2 * (_DEPTH - depth))
    change = np.empty(len(prefix), bool)
    change[0] = True
    np.not_equal(prefix[1:], prefix[:-1], out=change[1:])
    return change


def _node_sizes(starts, n_keys):
    sizes = np.empty(len(starts), np.int64)
    np.subtract(starts[1:], starts[:-1], out=sizes[:-1])
    sizes[-1] = n_keys - starts[-1]
    return sizes


def _best_per_node(response, starts):
    sizes = _node_sizes(starts, len(response))
    best = np.maximum.reduceat(response, starts)
    candidates = np.flatnonzero(response == np.repeat(best, sizes))
    node = np.repeat(np.arange(len(starts)), sizes)[candidates]
    first = np.ones(len(candidates), bool)
    np.not_equal(node[1:], node[:-1], out=first[1:])
    return candidates[first]


_SPREAD_BYTE = np.array([sum(((v >> bit) & 1) << (2 * bit) for bit in range(8)) for v in range(256)], np.int64)


def _spread_bits(v):
    return _SPREAD_BYTE[v & 0xFF] | (_SPREAD_BYTE[(v >> 8) & 0xFF] << 16)


def reference_angles(image, xy):
    u_max = disc_half_widths()
    offsets = np.arange(-_HALF_PATCH, _HALF_PATCH + 1)
    v_grid, u_grid = np.meshgrid(offsets, offsets, indexing="ij")
    inside = np.abs(u_grid) <= u_max[np.abs(v_grid)]
    weights = np.stack([(u_grid * inside).reshape(-1), (v_grid * inside).reshape(-1)]).astype(np.float32)
    cols = np.rint(xy[:, 0]).astype(np.int64) - _HALF_PATCH
    rows = np.rint(xy[:, 1]).astype(np.int64) - _HALF_PATCH
    step_y, step_x = image.strides
    shape = (image.shape[0] - 30, image.shape[1] - 30, 31, 31)
    windows = np.lib.stride_tricks.as_strided(image, shape, (step_y, step_x, step_y, step_x), writeable=False)[rows, cols]
    moments = np.einsum("nk,ck->nc", windows.reshape(len(xy), -1).astype(np.float32), weights)
    angle = np.degrees(np.arctan2(moments[:, 1], moments[:, 0]))
    return np.mod(angle, 360.0).astype(np.float32)


# ---- the comparisons ----


def random_keypoints(rng: np.random.Generator, width: int, height: int, n: int, dtype) -> tuple[np.ndarray, np.ndarray]:
    """Distinct pixels (as FAST gives them) in [0, width) x [0, height), some clustered, with FAST-like scores."""
    n = min(n, width * height)
    flat = rng.choice(width * height, n, replace=False)
    if rng.random() < 0.5:  # clusters: most keypoints within a few cells
        centres = rng.choice(width * height, 4)
        near = rng.integers(-40, 41, (n, 2)) + np.stack([centres % width, centres // width], 1)[rng.integers(0, 4, n)]
        near = np.clip(near, 0, [width - 1, height - 1])
        flat = np.unique(near[:, 1] * width + near[:, 0])
    xy = np.stack([flat % width, flat // width], 1).astype(dtype)
    response = rng.integers(7, 120, len(xy)).astype(np.float32)  # integer scores: many ties
    return xy, response


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_quadtree_equals_the_numpy_formulation_on_random_keypoints(dtype) -> None:
    rng = np.random.default_rng(41)
    for _ in range(300):
        width, height = int(rng.integers(8, 1300)), int(rng.integers(8, 400))
        xy, response = random_keypoints(rng, width, height, int(rng.integers(0, 6000)), dtype)
        n_target = int(rng.integers(0, 400))
        kept = distribute_quadtree(xy, response, width, height, n_target)
        expected = reference_quadtree(xy, response, width, height, n_target)
        assert kept.dtype == np.int64
        np.testing.assert_array_equal(kept, expected, err_msg=f"{width}x{height}, {len(xy)} keys, target {n_target}")


def test_quadtree_of_sub_pixel_coordinates_equals_the_numpy_formulation() -> None:
    rng = np.random.default_rng(7)
    for _ in range(100):
        xy = rng.uniform(0, [600, 200], (int(rng.integers(1, 3000)), 2))
        response = rng.uniform(0, 50, len(xy))
        n_target = int(rng.integers(1, 300))
        np.testing.assert_array_equal(
            distribute_quadtree(xy, response, 600, 200, n_target), reference_quadtree(xy, response, 600, 200, n_target)
        )


def test_angles_equal_the_numpy_formulation_on_random_images() -> None:
    rng = np.random.default_rng(3)
    for _ in range(50):
        height, width = int(rng.integers(31, 200)), int(rng.integers(31, 300))
        image = rng.integers(0, 256, (height, width), dtype=np.uint8)
        n = int(rng.integers(1, 500))
        xy = np.stack([rng.integers(15, width - 15, n), rng.integers(15, height - 15, n)], 1).astype(np.float64)
        np.testing.assert_array_equal(
            intensity_centroid_angles(image, xy, disc_half_widths()).view(np.uint32), reference_angles(image, xy).view(np.uint32)
        )
    saturated = np.full((40, 40), 255, np.uint8)  # the largest moments, and exact zeros (angle 0)
    saturated[:, 20:] = 0
    xy = np.array([[15.0, 15.0], [20.0, 20.0], [24.0, 24.0]])
    np.testing.assert_array_equal(intensity_centroid_angles(saturated, xy, disc_half_widths()), reference_angles(saturated, xy))


def test_angles_refuse_keypoints_near_the_border() -> None:
    image = np.zeros((50, 50), np.uint8)
    with pytest.raises(IndexError):
        intensity_centroid_angles(image, np.array([[14.0, 25.0]]), disc_half_widths())


def _extract_with_reference(image: np.ndarray) -> tuple:
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(orb_extractor, "distribute_quadtree", reference_quadtree)
        patch.setattr(orb_extractor, "intensity_centroid_angles", lambda image, xy, u_max: reference_angles(image, xy))
        return OrbExtractor(OrbConfig(threads=1)).extract(image)[0]


def _assert_same_features(a, b) -> None:
    for name in ("px", "level", "angle_deg", "response", "descriptors"):
        assert getattr(a, name).tobytes() == getattr(b, name).tobytes(), name


def test_extract_equals_the_numpy_formulation_on_textured_images() -> None:
    for seed in range(3):
        image = textured_image(seed)
        _assert_same_features(OrbExtractor(OrbConfig(threads=1)).extract(image)[0], _extract_with_reference(image))


@pytest.mark.dataset
def test_extract_equals_the_numpy_formulation_on_kitti(kitti_root: Path) -> None:
    import cv2

    folder = kitti_root / "sequences" / "06"
    for index in (0, 25, 50):
        for camera in ("image_0", "image_1"):
            image = cv2.imread(str(folder / camera / f"{index:06d}.png"), cv2.IMREAD_GRAYSCALE)
            _assert_same_features(OrbExtractor(OrbConfig(threads=1)).extract(image)[0], _extract_with_reference(image))


def test_reference_centroid_radius_matches_the_disc() -> None:
    u_max = disc_half_widths()
    assert u_max[0] == _HALF_PATCH and u_max[_HALF_PATCH] == 3
    assert all(u_max[v] >= math.floor(math.sqrt(_HALF_PATCH**2 - v * v)) - 1 for v in range(_HALF_PATCH + 1))
