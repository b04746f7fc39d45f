"""The corridor scenes: a closed 68 m ring driven twice, sparse deterministic textures, aliased walls."""

from __future__ import annotations

import numpy as np
import pytest

from zenslam.errors import ConfigError
from zenslam.geometry import so3_log
from zenslam.service.sources import open_source
from zenslam.service.sources.synthetic import SyntheticSource, TextureConfig, scene_config
from zenslam.service.sources.synthetic.corridor import CorridorLayout, CorridorPath, corridor_surfaces
from zenslam.service.sources.synthetic.scene import build_scene, surface_textures
from zenslam.service.sources.synthetic.textures import panel_texture
from zenslam.service.sources.synthetic.trajectories import make_trajectory

from zenslam.service.sources.synthetic.quad import Quad

SMALL = {"width": 160, "height": 120, "fx": 115.0, "fy": 115.0, "cx": 79.5, "cy": 59.5, "texels_per_m": 32.0}


def distance_to_rectangle(p: np.ndarray, quad: Quad) -> np.ndarray:
    """Euclidean distance (N,) from points p (N, 3) to the rectangle ``quad``."""
    rel = p - quad.origin_world
    s = np.clip(rel @ quad.axis_s, 0.0, quad.size_m[0])
    t = np.clip(rel @ quad.axis_t, 0.0, quad.size_m[1])
    return np.linalg.norm(p - quad.point(s, t), axis=1)


def first_hit_depth(T_world_cam: np.ndarray, K: np.ndarray, uv: np.ndarray, surfaces: tuple[Quad, ...]) -> np.ndarray:
    """Independent ray caster: depth z (N,) in metres of the first surface hit through pixels uv (N, 2); inf if none."""
    rays = np.column_stack([(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(uv))])
    rays = rays @ T_world_cam[:3, :3].T  # world directions whose camera z component is 1
    centre = T_world_cam[:3, 3]
    best_z = np.full(len(uv), np.inf)
    for quad in surfaces:
        with np.errstate(divide="ignore", invalid="ignore"):
            z = ((quad.origin_world - centre) @ quad.normal) / (rays @ quad.normal)
        hit = centre + z[:, None] * rays
        s = (hit - quad.origin_world) @ quad.axis_s
        t = (hit - quad.origin_world) @ quad.axis_t
        inside = (z > 1e-6) & (s >= 0) & (s <= quad.size_m[0]) & (t >= 0) & (t <= quad.size_m[1])
        best_z = np.where(inside & (z < best_z), z, best_z)
    return best_z


def test_presets_name_the_sensor_rate_and_laps() -> None:
    for name in ("corridor", "corridor_aliased"):
        config = scene_config(name)
        assert (config.trajectory, config.world, config.laps, config.frame_rate_hz) == ("corridor", "corridor", 2, 10.0)
        assert (config.width, config.height, config.sensor) == (640, 480, "stereo")
        assert config.texture.sparse and config.scene_name == name
    assert scene_config("corridor").texture.wall_repeat_m == 0.0
    assert scene_config("corridor_aliased").texture.wall_repeat_m > 0.0
    source = open_source("synthetic:corridor_aliased/rgbd")
    assert source.name == "synthetic:corridor_aliased" and source.sensor == "rgbd"
    assert open_source("synthetic:corridor/mono").sensor == "mono"


def test_each_lap_is_at_least_60_m_and_ends_exactly_at_the_start_pose() -> None:
    config = scene_config("corridor")
    trajectory = make_trajectory(config)
    lap_s = config.duration_s / config.laps
    T = trajectory.T_world_cam(np.array([0.0, lap_s, 2 * lap_s, 0.3 * lap_s, 1.3 * lap_s]))
    np.testing.assert_allclose(T[1], T[0], atol=1e-9)
    np.testing.assert_allclose(T[2], T[0], atol=1e-9)
    np.testing.assert_allclose(T[4], T[3], atol=1e-9)
    p = trajectory.kinematics(np.linspace(0.0, lap_s, 20001)).p_world
    horizontal = np.linalg.norm(np.diff(p[:, :2], axis=0), axis=1).sum()
    assert horizontal == pytest.approx(CorridorLayout().lap_m, rel=1e-6)
    assert horizontal >= 60.0
    # The lap is a frame boundary: the revisit frame repeats the first frame's pose.
    frames_per_lap = lap_s * config.frame_rate_hz
    assert frames_per_lap == round(frames_per_lap)
    gt = SyntheticSource(config).ground_truth()
    np.testing.assert_allclose(gt.T_world_cam[round(frames_per_lap)], gt.T_world_cam[0], atol=1e-9)


def test_the_path_turns_four_times_a_lap_and_keeps_a_metre_from_every_surface() -> None:
    config = scene_config("corridor")
    kin = make_trajectory(config).kinematics(np.arange(0.0, config.duration_s, 0.02))
    nearest = min(distance_to_rectangle(kin.p_world, quad).min() for quad in corridor_surfaces(CorridorLayout()))
    assert nearest >= 1.0, f"the camera comes within {nearest:.2f} m of a surface"
    down = kin.R_world_cam[:, :, 1]
    assert np.all(down[:, 2] < -np.cos(np.radians(15)))  # images stay upright
    heading = np.unwrap(np.arctan2(kin.v_world[:, 1], kin.v_world[:, 0]))
    assert heading[-1] - heading[0] == pytest.approx(2 * 2 * np.pi, abs=0.01)  # two counter-clockwise laps


def test_corridor_derivatives_match_finite_differences() -> None:
    trajectory = make_trajectory(scene_config("corridor"))
    t = np.linspace(0.3, 89.0, 41)  # straights and turns
    h = 1e-5
    kin, after, before = trajectory.kinematics(t), trajectory.kinematics(t + h), trajectory.kinematics(t - h)
    np.testing.assert_allclose((after.p_world - before.p_world) / (2 * h), kin.v_world, atol=1e-7)
    np.testing.assert_allclose((after.v_world - before.v_world) / (2 * h), kin.a_world, atol=1e-7)
    np.testing.assert_allclose((after.omega_world - before.omega_world) / (2 * h), kin.alpha_world, atol=1e-7)
    for i in range(len(t)):
        omega = so3_log(after.R_world_cam[i] @ before.R_world_cam[i].T) / (2 * h)
        np.testing.assert_allclose(omega, kin.omega_world[i], atol=1e-7)


def test_the_centre_line_is_continuous_through_every_turn() -> None:
    path = CorridorPath(CorridorLayout())
    arc = np.linspace(0.0, 2 * path.layout.lap_m, 100001)
    p = path.derivatives(arc, 0)
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    np.testing.assert_allclose(step, arc[1] - arc[0], rtol=1e-6)  # unit speed, no jump anywhere
    np.testing.assert_allclose(np.linalg.norm(path.derivatives(arc, 1), axis=1), 1.0, atol=1e-12)


def test_every_pixel_shows_the_first_corridor_surface_its_ray_meets() -> None:
    config = scene_config("corridor", **SMALL)
    source = SyntheticSource(config)
    surfaces = corridor_surfaces(CorridorLayout())
    K = source.calibration.K
    v, u = np.mgrid[0:120, 0:160]
    uv = np.column_stack([u.ravel(), v.ravel()]).astype(float)
    for T_world_cam in source.ground_truth().T_world_cam[::75]:
        depth = source.render(T_world_cam).depth_m().ravel()
        z = first_hit_depth(T_world_cam, K, uv, surfaces)
        assert np.all(np.isfinite(z)), "the closed corridor must cover every pixel"
        wrong = np.abs(depth / z - 1) > 1e-3
        assert wrong.sum() <= 2, f"{wrong.sum()} of {len(z)} pixels show the wrong surface"


def test_same_seed_gives_the_same_corridor_bytes_and_another_seed_other_textures() -> None:
    config = scene_config("corridor", sensor="stereo", **SMALL)
    a, b = SyntheticSource(config), SyntheticSource(config)  # each builds its own textures
    for index in (0, 333):
        assert a.frame(index).left.tobytes() == b.frame(index).left.tobytes()
        assert a.frame(index).right.tobytes() == b.frame(index).right.tobytes()
    other = SyntheticSource(scene_config("corridor", sensor="stereo", seed=1, **SMALL))
    assert a.frame(0).left.tobytes() != other.frame(0).left.tobytes()


def test_panels_cover_the_requested_share_at_the_requested_contrast() -> None:
    texels_per_m = 64.0
    shape = (round(3.0 * texels_per_m), round(30.0 * texels_per_m))
    texture = panel_texture(shape, texels_per_m, 0.15, 0.35, np.random.default_rng(3))
    again = panel_texture(shape, texels_per_m, 0.15, 0.35, np.random.default_rng(3))
    assert texture.tobytes() == again.tobytes()
    # The background stays within +-10 grey levels of 128 (plus rounding); panel texels leave that band.
    outside_background = np.abs(texture.astype(int) - 128) > 12
    assert 0.03 < outside_background.mean() < 0.15
    # Reduced contrast: panels span far less than the full 0..255 of the procedural texture.
    assert np.percentile(texture, 99.5) - np.percentile(texture, 0.5) < 0.5 * 255
    full = panel_texture(shape, texels_per_m, 1.0, 1.0, np.random.default_rng(3))
    assert np.abs(full.astype(int) - 128).mean() > 2 * np.abs(texture.astype(int) - 128).mean()


def _wall_textures(texture: TextureConfig, texels_per_m: float = 32.0) -> tuple[list[np.ndarray], list[bool]]:
    surfaces = corridor_surfaces(CorridorLayout())
    textures = list(surface_textures(surfaces, 0, texels_per_m, texture))
    return textures, [abs(q.normal[2]) < 1e-9 for q in surfaces]


def test_aliased_walls_repeat_every_segment_and_floors_do_not() -> None:
    texels_per_m = 32.0
    config = scene_config("corridor_aliased")
    period = round(config.texture.wall_repeat_m * texels_per_m)
    textures, is_wall = _wall_textures(config.texture, texels_per_m)
    outer, inner = textures[0], textures[4]  # the first outer wall and the first of the block's walls
    for wall in (outer, inner):
        assert wall.shape[1] > 2 * period
        np.testing.assert_array_equal(wall[:, period:], wall[:, :-period])
    n = min(outer.shape[1], inner.shape[1])
    assert not np.array_equal(outer[:, :n], inner[:, :n]), "the two sides of the corridor differ"
    for texture, wall in zip(textures, is_wall):
        if not wall:
            assert not np.array_equal(texture[:, period:2 * period], texture[:, :period])
    # Without repetition, no wall repeats.
    plain, _ = _wall_textures(scene_config("corridor").texture, texels_per_m)
    assert not np.array_equal(plain[0][:, period:2 * period], plain[0][:, :period])


def test_a_corridor_scene_is_refused_for_a_room_config() -> None:
    config = scene_config("corridor", **SMALL)
    scene = build_scene(config.seed, config.texels_per_m, config.tile_m, config.world, config.texture)
    SyntheticSource(config, scene=scene)
    with pytest.raises(ConfigError, match="world=corridor"):
        SyntheticSource(scene_config("loop", **SMALL), scene=scene)
