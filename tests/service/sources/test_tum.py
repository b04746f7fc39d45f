"""TUM RGB-D reader and writer: round trip, association, intrinsics presets, malformed input."""

import logging
from pathlib import Path

import numpy as np
import pytest

from zenslam.camera import PinholeCalibration
from zenslam.errors import CalibrationError, DatasetError, ImageReadError, TimestampError
from zenslam.geometry import make_T, so3_exp
from zenslam.service.sources.csv_util import associate_stamps
from zenslam.service.sources.frame import SensorFrame
from zenslam.service.sources.images import write_png
from zenslam.service.sources.tum import TumConfig, TumSource, write_tum_rgbd
from zenslam.trajectory import Trajectory

CAL = PinholeCalibration(fx=50.0, fy=52.0, cx=31.5, cy=23.5, width=64, height=48)
T0 = 1_305_031_102_175_304_000  # a freiburg1-like stamp, microsecond-aligned


def synthetic_frames(n: int = 4, shape=(48, 64), seed: int = 5) -> list[SensorFrame]:
    """Random textures and a depth ramp from 0.5 m to ~6 m with a few unknown pixels."""
    rng = np.random.default_rng(seed)
    frames = []
    for i in range(n):
        depth = np.linspace(0.5, 6.0, shape[0] * shape[1], dtype=np.float32).reshape(shape) + 0.01 * i
        depth[0, :5] = 0.0
        left = rng.integers(0, 256, size=shape, dtype=np.uint8)
        frames.append(SensorFrame(index=i, stamp_ns=T0 + i * 33_333_000 + 17_000, left=left, depth_m=depth))
    return frames


def random_trajectory(n: int, seed: int = 9) -> Trajectory:
    rng = np.random.default_rng(seed)
    poses = np.array([make_T(so3_exp(rng.normal(size=3)), rng.normal(size=3) * 3) for _ in range(n)])
    return Trajectory(T0 - 5_000_000 + np.arange(n, dtype=np.int64) * 10_000_000, poses)


def test_round_trip_images_depth_stamps_and_poses(tmp_path: Path):
    frames = synthetic_frames()
    gt = random_trajectory(7)
    assert write_tum_rgbd(tmp_path / "seq", frames, gt, calibration=CAL) == 4
    source = TumSource(tmp_path / "seq")
    assert source.sensor == "rgbd" and source.name == "tum/seq" and len(source) == 4
    assert source.calibration.fx == CAL.fx and source.calibration.baseline_m == pytest.approx(40.0 / CAL.fx)
    np.testing.assert_array_equal(source.stamps_ns(), [f.stamp_ns for f in frames])
    back = list(source)
    for original, read in zip(frames, back):
        assert read.stamp_ns == original.stamp_ns and read.right is None
        np.testing.assert_array_equal(read.left, original.left)
        assert read.depth_m.dtype == np.float32
        np.testing.assert_allclose(read.depth_m, original.depth_m, atol=0.5 / 5000 + 1e-6)
        np.testing.assert_array_equal(read.depth_m == 0, original.depth_m == 0)
    gt_back = source.ground_truth()
    np.testing.assert_array_equal(gt_back.stamps_ns, gt.stamps_ns)
    np.testing.assert_allclose(gt_back.T_world_cam, gt.T_world_cam, atol=1e-6)
    assert source.imu() is None


def test_writer_rounds_to_microseconds_and_refuses_collisions(tmp_path: Path, caplog):
    frame = synthetic_frames(1)[0]
    shifted = SensorFrame(0, frame.stamp_ns + 400, frame.left, depth_m=frame.depth_m)
    with caplog.at_level(logging.WARNING):
        write_tum_rgbd(tmp_path / "a", [shifted], calibration=CAL)
    assert "1 of 1 stamps rounded" in caplog.text
    assert TumSource(tmp_path / "a").stamps_ns().tolist() == [frame.stamp_ns]
    twin = SensorFrame(1, frame.stamp_ns + 200, frame.left, depth_m=frame.depth_m)
    with pytest.raises(TimestampError, match=r"cannot write .*b: stamp 1 .* at least 1 us"):
        write_tum_rgbd(tmp_path / "b", [frame, twin])


def test_writer_stores_unstorable_depth_as_unknown(tmp_path: Path):
    frame = synthetic_frames(1)[0]
    depth = frame.depth_m.copy()
    depth[1, 1], depth[1, 2], depth[1, 3] = 20.0, np.nan, -1.0
    write_tum_rgbd(tmp_path, [SensorFrame(0, T0, frame.left, depth_m=depth)], calibration=CAL)
    back = next(iter(TumSource(tmp_path)))
    assert back.depth_m[1, 1:4].tolist() == [0.0, 0.0, 0.0]
    assert back.depth_m[1, 4] == pytest.approx(depth[1, 4], abs=1e-4)


def test_writer_needs_depth(tmp_path: Path):
    with pytest.raises(DatasetError, match=r"frame 3 cannot be written"):
        write_tum_rgbd(tmp_path, [SensorFrame(3, T0, np.zeros((4, 4), np.uint8))])


def _brute_force_associate(a, b, max_diff):
    """TUM associate.py, literally: all candidate pairs sorted by difference, taken greedily."""
    candidates = sorted((abs(x - y), i, j) for i, x in enumerate(a) for j, y in enumerate(b) if abs(x - y) <= max_diff)
    used_a, used_b, pairs = set(), set(), []
    for _, i, j in candidates:
        if i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
            pairs.append((i, j))
    return sorted(pairs)


def test_association_matches_tum_associate_py():
    rng = np.random.default_rng(11)
    for _ in range(20):
        a = np.sort(rng.choice(1_000_000, size=40, replace=False)).astype(np.int64) * 1000
        b = np.sort(rng.choice(1_000_000, size=35, replace=False)).astype(np.int64) * 1000
        ia, ib = associate_stamps(a, b, 20_000_000)
        assert list(zip(ia.tolist(), ib.tolist())) == _brute_force_associate(a.tolist(), b.tolist(), 20_000_000)


def test_association_is_one_to_one_and_bounded():
    ia, ib = associate_stamps(np.array([0, 10, 20, 100]), np.array([11, 12, 200]), 5)
    assert ia.tolist() == [1] and ib.tolist() == [0]  # 11 goes to its nearest (10); 12 then has nobody within 5
    ia, ib = associate_stamps(np.array([], dtype=np.int64), np.array([1]), 5)
    assert ia.size == ib.size == 0


def _write_lists(folder: Path, rgb: list[tuple[str, str]], depth: list[tuple[str, str]]) -> None:
    (folder / "rgb.txt").write_text("# color images\n# timestamp filename\n" + "".join(f"{s} {f}\n" for s, f in rgb))
    (folder / "depth.txt").write_text("# depth maps\n" + "".join(f"{s} {f}\n" for s, f in depth))


def make_tum(folder: Path, n: int = 3, shape=(480, 640)) -> Path:
    """A fake TUM sequence at 30 Hz with depth 4 ms after colour (as in TUM's files)."""
    rng = np.random.default_rng(1)
    rgb, depth = [], []
    for i in range(n):
        stamp = 1305031102.175304 + i / 30
        write_png(folder / "rgb" / f"{i}.png", rng.integers(0, 255, size=(*shape, 3), dtype=np.uint8))
        write_png(folder / "depth" / f"{i}.png", np.full(shape, 5000 + i, np.uint16))
        rgb.append((f"{stamp:.6f}", f"rgb/{i}.png"))
        depth.append((f"{stamp + 0.004:.6f}", f"depth/{i}.png"))
    _write_lists(folder, rgb, depth)
    return folder


def test_fr3_preset_by_folder_name(tmp_path: Path):
    source = TumSource(make_tum(tmp_path / "rgbd_dataset_freiburg3_office"))
    cal = source.calibration
    assert (cal.fx, cal.fy, cal.cx, cal.cy, cal.width, cal.height) == (535.4, 539.2, 320.1, 247.6, 640, 480)
    assert cal.bf == pytest.approx(40.0)
    frames = list(source)
    assert len(frames) == 3 and frames[0].left.shape == (480, 640)
    assert frames[2].depth_m[100, 100] == pytest.approx(5002 / 5000)
    assert source.stamps_ns()[0] == 1_305_031_102_175_304_000


def test_fr1_preset_undistorts_colour_and_depth(tmp_path: Path):
    folder = make_tum(tmp_path / "rgbd_dataset_freiburg1_xyz", n=1)
    frame = next(iter(TumSource(folder)))
    assert TumSource(folder).calibration.fx == 517.306408
    # Undistortion moves pixels: the border that maps outside the raw image becomes unknown depth.
    assert frame.depth_m[240, 320] == pytest.approx(1.0)
    assert 0 < np.count_nonzero(frame.depth_m == 0) < 0.2 * frame.depth_m.size
    assert set(np.unique(frame.depth_m).tolist()) <= {0.0, 1.0}  # nearest neighbour: no blended depths


def test_explicit_preset_and_calibration_override_the_folder_name(tmp_path: Path):
    folder = make_tum(tmp_path / "rgbd_dataset_freiburg3_office", n=1)
    assert TumSource(folder, TumConfig(intrinsics="fr2")).calibration.fx == 520.908620
    custom = PinholeCalibration(600.0, 600.0, 320.0, 240.0, 640, 480, baseline_m=0.08)
    assert TumSource(folder, calibration=custom).calibration == custom
    assert TumSource(folder, TumConfig(virtual_bf_px_m=53.54)).calibration.baseline_m == pytest.approx(0.1)


def test_unknown_camera_is_a_calibration_error(tmp_path: Path):
    folder = make_tum(tmp_path / "my_sequence", n=1)
    with pytest.raises(CalibrationError, match=r"my_sequence: no calibration\.yaml.*freiburgN"):
        TumSource(folder)


def test_association_drops_far_depth_and_missing_files(tmp_path: Path, caplog):
    folder = make_tum(tmp_path / "rgbd_dataset_freiburg3_x", n=3)
    rgb = [("1.000000", "rgb/0.png"), ("1.033333", "rgb/1.png"), ("1.066667", "rgb/2.png"), ("1.1", "rgb/gone.png")]
    depth = [("1.010000", "depth/0.png"), ("1.090000", "depth/2.png"), ("1.1", "depth/1.png")]
    _write_lists(folder, rgb, depth)
    with caplog.at_level(logging.WARNING):
        source = TumSource(folder)
    assert "dropped 1 listed images whose file is missing (rgb 1, depth 0)" in caplog.text
    # Within 20 ms only 1.000-1.010 pairs; at 25 ms 1.0667-1.090 (23 ms) pairs too, while 1.0333 (23 ms from
    # 1.010) loses that depth to its closer rival: associations are one-to-one.
    assert source.stamps_ns().tolist() == [1_000_000_000]
    assert len(TumSource(folder, TumConfig(max_difference_ns=25_000_000))) == 2


def test_missing_folder_and_missing_rgb_list(tmp_path: Path):
    with pytest.raises(DatasetError, match=r"nowhere does not exist"):
        TumSource(tmp_path / "nowhere", calibration=CAL)
    folder = make_tum(tmp_path / "rgbd_dataset_freiburg3_x", n=1)
    (folder / "rgb.txt").unlink()
    with pytest.raises(DatasetError, match=r"rgb\.txt does not exist"):
        TumSource(folder)


def test_rgb_stamps_not_increasing(tmp_path: Path):
    folder = make_tum(tmp_path / "rgbd_dataset_freiburg3_x", n=1)
    _write_lists(folder, [("2.0", "rgb/0.png"), ("1.0", "rgb/0.png")], [("1.0", "depth/0.png")])
    with pytest.raises(TimestampError, match=r"rgb\.txt must strictly increase: line 4"):
        TumSource(folder)


def test_corrupt_depth_fails_when_reached(tmp_path: Path):
    folder = make_tum(tmp_path / "rgbd_dataset_freiburg3_x", n=2)
    (folder / "depth" / "1.png").write_bytes(b"garbage")
    frames = iter(TumSource(folder))
    next(frames)
    with pytest.raises(ImageReadError, match=r"depth/1\.png could not be decoded"):
        next(frames)


def test_eight_bit_depth_and_wrong_size_are_image_errors(tmp_path: Path):
    folder = make_tum(tmp_path / "rgbd_dataset_freiburg3_x", n=1)
    write_png(folder / "depth" / "0.png", np.zeros((480, 640), np.uint8))
    with pytest.raises(ImageReadError, match=r"depth/0\.png is uint8 .*16-bit"):
        next(iter(TumSource(folder)))
    write_png(folder / "rgb" / "0.png", np.zeros((240, 320), np.uint8))
    with pytest.raises(ImageReadError, match=r"rgb/0\.png is 320x240 pixels but the calibration expects 640x480"):
        next(iter(TumSource(folder)))


def test_ground_truth_xyzw_order_and_absence(tmp_path: Path):
    folder = make_tum(tmp_path / "rgbd_dataset_freiburg3_x", n=1)
    assert TumSource(folder).ground_truth() is None
    # 90 degrees about z: q_xyzw = (0, 0, sin 45, cos 45).
    (folder / "groundtruth.txt").write_text("# ground truth\n1305031102.1753 1.0 2.0 3.0 0 0 0.7071068 0.7071068\n")
    gt = TumSource(folder).ground_truth()
    assert gt.stamps_ns.tolist() == [1_305_031_102_175_300_000]
    np.testing.assert_allclose(gt.T_world_cam[0][:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-7)
    np.testing.assert_allclose(gt.positions[0], [1, 2, 3])
