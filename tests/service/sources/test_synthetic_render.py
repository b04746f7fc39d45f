"""Rendered images and depth of the synthetic scene agree with its geometry, calibration and ground truth."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from zenslam.service.sources.synthetic import SceneConfig, SyntheticSource, scene_config
from zenslam.service.sources.synthetic.scene import Scene, build_scene, room_surfaces

SMALL = {"width": 320, "height": 240, "fx": 230.0, "fy": 230.0, "cx": 159.5, "cy": 119.5, "texels_per_m": 128.0}


def small_config(name: str = "loop", **overrides) -> SceneConfig:
    return scene_config(name, **{**SMALL, **overrides})


@pytest.fixture(scope="module")
def small_scene() -> Scene:
    return build_scene(seed=0, texels_per_m=SMALL["texels_per_m"], tile_m=2.0)


@pytest.fixture(scope="module")
def stereo_source(small_scene: Scene) -> SyntheticSource:
    return SyntheticSource(small_config("loop", sensor="stereo"), scene=small_scene)


@pytest.fixture(scope="module")
def rgbd_source(small_scene: Scene) -> SyntheticSource:
    return SyntheticSource(small_config("figure_eight", sensor="rgbd"), scene=small_scene)


def first_hits(T_world_cam: np.ndarray, K: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Independent ray caster: (surface index, depth z in m) of the first surface hit through pixels uv (N, 2)."""
    rays_cam = np.column_stack([(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(uv))])
    rays = rays_cam @ T_world_cam[:3, :3].T  # world directions whose camera z component is 1
    centre = T_world_cam[:3, 3]
    best_z = np.full(len(uv), np.inf)
    best_i = np.full(len(uv), -1)
    for index, quad in enumerate(room_surfaces()):
        n = quad.normal
        denom = rays @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            z = ((quad.origin_world - centre) @ n) / denom
        hit = centre + z[:, None] * rays
        s = (hit - quad.origin_world) @ quad.axis_s
        t = (hit - quad.origin_world) @ quad.axis_t
        inside = (z > 1e-6) & (s >= 0) & (s <= quad.size_m[0]) & (t >= 0) & (t <= quad.size_m[1])
        closer = inside & (z < best_z)
        best_z[closer], best_i[closer] = z[closer], index
    return best_i, best_z


def sample_visible_pixels(T_world_cam: np.ndarray, K: np.ndarray, shape: tuple[int, int], rng: np.random.Generator):
    """Points sampled on every surface, projected and snapped to pixel centres, kept where the 3D point is
    the first hit and the surface is also first hit 2 px around (away from occlusion edges).

    Returns integer pixels (N, 2) and the depth z (N,) of the surface point at each pixel centre.
    """
    h, w = shape
    T_cam_world = np.linalg.inv(T_world_cam)
    pixels, surfaces = [], []
    for index, quad in enumerate(room_surfaces()):
        st = rng.uniform(0.0, 1.0, size=(200, 2)) * quad.size_m
        p_cam = quad.point(st[:, 0], st[:, 1]) @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
        front = p_cam[:, 2] > 0.1
        uv = p_cam[front, :2] / p_cam[front, 2:3] @ np.diag(K[:2, :2].diagonal()) + K[:2, 2]
        uv = np.round(uv)
        keep = (uv[:, 0] >= 3) & (uv[:, 0] < w - 3) & (uv[:, 1] >= 3) & (uv[:, 1] < h - 3)
        pixels.append(uv[keep])
        surfaces.append(np.full(int(keep.sum()), index))
    uv, surface = np.concatenate(pixels), np.concatenate(surfaces)
    hit, z = first_hits(T_world_cam, K, uv)
    ok = hit == surface
    for du, dv in ((-2, -2), (-2, 2), (2, -2), (2, 2), (0, 0)):
        ok &= first_hits(T_world_cam, K, uv + (du, dv))[0] == surface
    return uv[ok].astype(int), z[ok]


def test_rendered_depth_equals_surface_depth_at_sampled_points(rgbd_source: SyntheticSource) -> None:
    rng = np.random.default_rng(5)
    K = rgbd_source.calibration.K
    gt = rgbd_source.ground_truth()
    for index in (0, 150, 333, 777):
        frame = rgbd_source.frame(index)
        assert frame.depth_m is not None and frame.depth_m.dtype == np.float32
        assert frame.depth_m.min() > 0.5, "the closed room must cover every pixel"
        uv, z = sample_visible_pixels(gt.T_world_cam[index], K, frame.depth_m.shape, rng)
        assert len(uv) >= 100, f"frame {index}: only {len(uv)} visible samples"
        rendered = frame.depth_m[uv[:, 1], uv[:, 0]]
        np.testing.assert_allclose(rendered, z, rtol=1e-3)


def patch_ncc(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum() + 1e-12))


def single_surface(T_world_cam: np.ndarray, K: np.ndarray, uv: np.ndarray, half: int) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel uv (N, 2): the surface seen by every pixel of the (2*half+1)^2 window around it (-1 if
    the window straddles an edge) and the depth at the centre."""
    offsets = np.array([(du, dv) for dv in range(-half, half + 1) for du in range(-half, half + 1)], float)
    hit, z = first_hits(T_world_cam, K, (uv[:, None, :] + offsets).reshape(-1, 2))
    hit, z = hit.reshape(len(uv), -1), z.reshape(len(uv), -1)
    centre = len(offsets) // 2
    return np.where(np.all(hit == hit[:, :1], axis=1), hit[:, centre], -1), z[:, centre]


def test_stereo_right_image_matches_left_shifted_by_disparity(stereo_source: SyntheticSource) -> None:
    cal = stereo_source.calibration
    K, bf = cal.K, cal.bf
    normals = np.stack([quad.normal for quad in room_surfaces()])
    rng = np.random.default_rng(9)
    scores = []
    for index in (0, 200):
        frame = stereo_source.frame(index)
        T_left = stereo_source.ground_truth().T_world_cam[index]
        T_right = T_left @ np.array([[1, 0, 0, cal.baseline_m], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])
        uv, z = sample_visible_pixels(T_left, K, frame.left.shape, rng)
        uv_right = np.column_stack([uv[:, 0] - bf / z, uv[:, 1]])
        inside = (uv_right[:, 0] >= 12) & (uv[:, 0] < cal.width - 12) & (uv[:, 1] >= 12) & (uv[:, 1] < cal.height - 12)
        uv, z, uv_right = uv[inside], z[inside], uv_right[inside]
        surface, _ = single_surface(T_left, K, uv.astype(float), 6)
        surface_right, z_right = single_surface(T_right, K, uv_right, 6)
        # Keep patches on one surface in both views, not occluded in the right one, and seen within
        # 60 degrees of the normal (beyond, the two views foreshorten the patch differently).
        rays = np.column_stack([uv, np.ones(len(uv))]) @ np.linalg.inv(K).T
        normals_cam = normals[surface] @ T_left[:3, :3]
        cos_incidence = np.abs(np.einsum("ij,ij->i", rays, normals_cam)) / np.linalg.norm(rays, axis=1)
        keep = (surface >= 0) & (surface == surface_right) & (np.abs(z_right / z - 1) < 1e-6) & (cos_incidence > 0.5)
        left, right = frame.left.astype(np.float32), frame.right.astype(np.float32)
        for (u, v), (u_right, _) in zip(uv[keep], uv_right[keep]):
            left_patch = left[v - 5 : v + 6, u - 5 : u + 6]
            if left_patch.std() < 8:
                continue  # untextured patch: correlation is meaningless
            scores.append(patch_ncc(left_patch, cv2.getRectSubPix(right, (11, 11), (float(u_right), float(v)))))
    scores = np.array(scores)
    assert len(scores) >= 200
    assert np.median(scores) > 0.98
    assert np.mean(scores > 0.9) >= 0.97, f"NCC at most 0.9 on {np.sum(scores <= 0.9)} of {len(scores)} patches"


def test_every_pixel_depth_matches_an_independent_ray_caster(small_scene: Scene) -> None:
    """Exact coverage: each pixel centre shows the first surface its ray meets (edges included)."""
    small = {"width": 160, "height": 120, "fx": 115.0, "fy": 115.0, "cx": 79.5, "cy": 59.5, "texels_per_m": 128.0}
    config = scene_config("figure_eight", **small)
    source = SyntheticSource(config, scene=small_scene)
    K = source.calibration.K
    v, u = np.mgrid[0:120, 0:160]
    uv = np.column_stack([u.ravel(), v.ravel()]).astype(float)
    for T_world_cam in source.ground_truth().T_world_cam[::300]:
        depth = source.render(T_world_cam).depth_m().ravel()
        _, z = first_hits(T_world_cam, K, uv)
        wrong = np.abs(depth / z - 1) > 1e-3
        assert wrong.sum() <= 2, f"{wrong.sum()} of {len(z)} pixels show the wrong surface"


def test_disparity_mismatch_is_detected(stereo_source: SyntheticSource) -> None:
    """The check above can fail: a wrong disparity (2 px off) gives clearly lower correlation."""
    frame = stereo_source.frame(90)
    left, right = frame.left.astype(np.float32), frame.right.astype(np.float32)
    depth = stereo_source.render(stereo_source.ground_truth().T_world_cam[90]).depth_m()
    bf = stereo_source.calibration.bf
    good, bad = [], []
    for v in range(40, 200, 20):
        for u in range(60, 300, 20):
            u_r = u - bf / depth[v, u]
            patch = left[v - 5 : v + 6, u - 5 : u + 6]
            good.append(patch_ncc(patch, cv2.getRectSubPix(right, (11, 11), (float(u_r), float(v)))))
            bad.append(patch_ncc(patch, cv2.getRectSubPix(right, (11, 11), (float(u_r - 2), float(v)))))
    assert np.median(good) > np.median(bad) + 0.2


def test_same_seed_gives_identical_frames_and_other_seed_different_textures() -> None:
    config = small_config("loop", sensor="stereo", duration_s=1.0, frame_rate_hz=20.0, texels_per_m=64.0)
    a, b = SyntheticSource(config), SyntheticSource(config)  # each builds its own textures
    for index in (0, 7, 20):
        fa, fb = a.frame(index), b.frame(index)
        assert fa.left.tobytes() == fb.left.tobytes()
        assert fa.right.tobytes() == fb.right.tobytes()
    other = SyntheticSource(small_config("loop", sensor="stereo", duration_s=1.0, frame_rate_hz=20.0, texels_per_m=64.0, seed=1))
    diff = np.abs(a.frame(0).left.astype(int) - other.frame(0).left.astype(int))
    assert diff.mean() > 20, "a different seed must give different textures"
    np.testing.assert_array_equal(a.ground_truth().T_world_cam, other.ground_truth().T_world_cam)


def test_iteration_is_lazy_and_matches_random_access() -> None:
    source = SyntheticSource(small_config("still", sensor="mono", duration_s=0.5))
    frames = list(source)
    assert [f.index for f in frames] == list(range(11))
    assert [f.stamp_ns for f in frames] == source.stamps_ns().tolist()
    assert frames[3].right is None and frames[3].depth_m is None
    assert frames[3].left.tobytes() == source.frame(3).left.tobytes()
    assert frames[0].left.tobytes() == frames[10].left.tobytes(), "a still camera sees the same image"


@pytest.fixture(scope="module")
def full_size_source() -> SyntheticSource:
    return SyntheticSource(scene_config("loop", sensor="mono"))


def orb_coverage(grey: np.ndarray, orb: cv2.ORB) -> tuple[int, int]:
    """Number of ORB keypoints and of occupied cells in a 4x4 grid."""
    keypoints = orb.detect(grey, None)
    pts = np.array([kp.pt for kp in keypoints]).reshape(-1, 2)
    h, w = grey.shape
    cells = {(int(x * 4 // w), int(y * 4 // h)) for x, y in pts}
    return len(keypoints), len(cells)


def test_orb_finds_many_well_spread_keypoints_along_the_loop(full_size_source: SyntheticSource) -> None:
    orb = cv2.ORB_create(1500)
    gt = full_size_source.ground_truth()
    for index in range(0, len(gt), 100):
        grey = full_size_source.render(gt.T_world_cam[index]).grey
        assert grey.shape == (480, 640) and grey.dtype == np.uint8
        count, cells = orb_coverage(grey, orb)
        assert count >= 800, f"frame {index}: {count} ORB keypoints"
        assert cells >= 12, f"frame {index}: keypoints in only {cells} of 16 cells"


def test_photometric_effects_change_the_image_deterministically(small_scene: Scene) -> None:
    def left_image(**photometric) -> np.ndarray:
        config = small_config("loop", sensor="mono", duration_s=2.0, frame_rate_hz=20.0, photometric=photometric)
        return SyntheticSource(config, scene=small_scene).frame(30).left

    def sharpness(img: np.ndarray) -> float:
        return float(np.abs(cv2.Laplacian(img.astype(np.float32), cv2.CV_32F)).mean())

    clean = left_image()
    effects = {"noise_sigma": 4.0, "defocus_sigma_px": 1.5, "motion_blur_exposure_s": 0.05, "gain_amplitude": 0.3}
    images = {}
    for name, value in effects.items():
        images[name] = left_image(**{name: value, "gain_period_s": 4.0})
        assert images[name].tobytes() == left_image(**{name: value, "gain_period_s": 4.0}).tobytes(), name
        assert np.abs(images[name].astype(int) - clean.astype(int)).mean() > 1.0, name
    noise = images["noise_sigma"].astype(float) - clean
    assert noise.std() == pytest.approx(4.0, rel=0.1)
    assert sharpness(images["defocus_sigma_px"]) < 0.7 * sharpness(clean)
    assert sharpness(images["motion_blur_exposure_s"]) < 0.9 * sharpness(clean)
    # t = 1.5 s with a 4 s period: gain = 1 + 0.3 sin(3 pi / 4) ~ 1.21
    dim = clean < 150
    ratio = images["gain_amplitude"][dim].mean() / clean[dim].mean()
    assert ratio == pytest.approx(1 + 0.3 * np.sin(3 * np.pi / 4), abs=0.02)


def test_motion_blur_kernel_follows_the_image_motion() -> None:
    from zenslam.service.sources.synthetic.photometric import motion_blur_kernel

    assert motion_blur_kernel((0.4, 0.3)) is None  # under a pixel: no blur
    kernel = motion_blur_kernel((6.0, 0.0))
    assert kernel.sum() == pytest.approx(1.0)
    rows, cols = np.nonzero(kernel)
    assert set(rows) == {kernel.shape[0] // 2} and np.ptp(cols) == 6  # a horizontal 7-tap line
    diagonal = motion_blur_kernel((4.0, 4.0))
    rows, cols = np.nonzero(diagonal)
    np.testing.assert_array_equal(rows - rows.mean(), cols - cols.mean())  # along the 45-degree motion
