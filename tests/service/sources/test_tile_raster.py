"""The compiled rasteriser gives the synthetic scenes' images and depth the same bits as the numpy formulation it replaced."""

from __future__ import annotations

import numpy as np
import pytest
from renderer_numpy_reference import NumpyRenderer
from renderer_numpy_reference import sample_bilinear as numpy_sample_bilinear

from zenslam.service.sources.synthetic import SyntheticSource, scene_config
from zenslam.service.sources.synthetic.renderer import Renderer
from zenslam.service.sources.synthetic.tile_raster import sample_bilinear

RNG = np.random.default_rng(11)


def renderers(name: str) -> tuple[SyntheticSource, Renderer, NumpyRenderer]:
    source = SyntheticSource(scene_config(name, sensor="stereo"))
    args = (source.scene.tiles, source.calibration, source.config.near_m)
    return source, Renderer(*args), NumpyRenderer(*args)


def assert_same_view(compiled: Renderer, numpy_renderer: NumpyRenderer, T_world_cam: np.ndarray) -> int:
    """Both renderers' grey and inverse depth are equal bit for bit; returns the pixels drawn."""
    ours, theirs = compiled.render(T_world_cam), numpy_renderer.render(T_world_cam)
    assert np.array_equal(ours.grey, theirs.grey)
    assert np.array_equal(ours.inv_depth.view(np.uint32), theirs.inv_depth.view(np.uint32))
    return int(np.count_nonzero(ours.inv_depth))


def random_pose(centre: np.ndarray, spread_m: np.ndarray) -> np.ndarray:
    """A camera anywhere in the box around ``centre``, looking in any direction (grazing walls, crossing the near plane)."""
    axis = RNG.normal(size=3)
    angle = RNG.uniform(0.0, np.pi)
    axis /= np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    T = np.eye(4)
    T[:3, :3] = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K
    T[:3, 3] = centre + RNG.uniform(-1.0, 1.0, 3) * spread_m
    return T


@pytest.mark.parametrize("name", ["loop", "corridor"])
def test_the_scene_along_its_trajectory_renders_the_same(name: str) -> None:
    source, compiled, numpy_renderer = renderers(name)
    poses = source.ground_truth().T_world_cam
    for index in np.linspace(0, len(poses) - 1, 6).astype(int):
        assert assert_same_view(compiled, numpy_renderer, poses[index]) > 0.5 * source.calibration.width * source.calibration.height


@pytest.mark.parametrize("name", ["loop", "corridor"])
def test_random_views_render_the_same(name: str) -> None:
    """Poses off the trajectory: close to the walls (tiles crossing the near plane), grazing views,
    looking up, down and out: every branch of the pixel loop."""
    source, compiled, numpy_renderer = renderers(name)
    positions = source.ground_truth().T_world_cam[:, :3, 3]
    low, high = positions.min(axis=0), positions.max(axis=0)
    drawn = [assert_same_view(compiled, numpy_renderer, random_pose((low + high) / 2, (high - low) / 2 + 1.0)) for _ in range(12)]
    assert sum(d > 0 for d in drawn) >= 8


def test_sampling_equals_the_numpy_formulation_inside_past_the_borders_and_at_grazing_maps() -> None:
    """Maps that keep the plane in front of the camera (w > 0), as at every pixel the renderer draws."""
    texture = RNG.integers(0, 256, size=(29, 41), dtype=np.uint8)
    cols, rows = np.arange(70, dtype=np.float64)[None, :], np.arange(50, dtype=np.float64)[:, None]
    maps = [
        np.eye(3),
        np.array([[0.9, 0.12, -1.7], [-0.05, 1.05, -0.8], [2e-3, -1e-3, 1.0]]),
        np.array([[3.1, -0.4, -60.0], [0.7, 2.9, -45.0], [1e-2, 2e-2, 0.9]]),  # folds many times past the borders
        np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1e-9]]),  # texels past int32's range (a grazing ray)
    ]
    for M in maps:
        assert np.array_equal(sample_bilinear(texture, M, cols, rows), numpy_sample_bilinear(texture, M, cols, rows))
    flat = np.zeros((1, 5), np.uint8) + np.arange(5, dtype=np.uint8)
    assert np.array_equal(sample_bilinear(flat, np.eye(3), cols[:, :7], np.zeros((1, 1))), [[0, 1, 2, 3, 4, 3, 2]])
