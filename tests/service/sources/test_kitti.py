"""KITTI odometry reader: the real clip, fake sequences for every malformed-input case, image_0 alone as mono."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from zenslam.errors import CalibrationError, DatasetError, ImageReadError, TimestampError
from zenslam.service.sources import open_source
from zenslam.service.sources.images import write_png
from zenslam.service.sources.kitti import KittiSource

P0 = "P0: 700 0 300 0 0 700 100 0 0 0 1 0"
P1 = "P1: 700 0 300 -350 0 700 100 0 0 0 1 0"  # baseline 0.5 m


def make_kitti(root: Path, n: int = 3, shape=(20, 32), poses: bool = True) -> Path:
    """A fake KITTI tree <root>/sequences/07 with n random stereo pairs; returns the sequence folder."""
    seq = root / "sequences" / "07"
    rng = np.random.default_rng(7)
    for folder in ("image_0", "image_1"):
        for i in range(n):
            write_png(seq / folder / f"{i:06d}.png", rng.integers(0, 255, size=shape, dtype=np.uint8))
    (seq / "calib.txt").write_text(f"{P0}\n{P1}\nP2: {P0[4:]}\nP3: {P1[4:]}\nTr: 1 0 0 0 0 1 0 0 0 0 1 0\n")
    (seq / "times.txt").write_text("".join(f"{0.1 * i:e}\n" for i in range(n)))
    if poses:
        (root / "poses").mkdir(parents=True, exist_ok=True)
        rows = [f"1 0 0 {i} 0 1 0 0 0 0 1 {2 * i}" for i in range(n)]
        (root / "poses" / "07.txt").write_text("\n".join(rows) + "\n")
    return seq


@pytest.mark.dataset
def test_kitti_clip_loads_51_rectified_pairs(kitti_root: Path):
    source = KittiSource(kitti_root / "sequences" / "06")
    assert source.name == "kitti/06" and source.sensor == "stereo"
    assert len(source) == 51
    cal = source.calibration
    assert (cal.width, cal.height) == (1226, 370)
    assert cal.fx == pytest.approx(707.0912, abs=1e-6) and cal.fy == pytest.approx(707.0912, abs=1e-6)
    assert cal.baseline_m == pytest.approx(0.5372, abs=1e-4)
    stamps = source.stamps_ns()
    assert stamps.dtype == np.int64 and stamps[0] == 0 and stamps[1] == 104_498_900
    frames = list(source)
    assert [f.index for f in frames] == list(range(51))
    assert all(f.left.shape == (370, 1226) and f.right.shape == (370, 1226) for f in frames)
    assert frames[0].left.dtype == np.uint8 and frames[0].depth_m is None
    np.testing.assert_array_equal([f.stamp_ns for f in frames], stamps)
    gt = source.ground_truth()
    assert gt is not None and len(gt) == 51
    np.testing.assert_allclose(gt.T_world_cam[0], np.eye(4), atol=1e-9)
    np.testing.assert_array_equal(gt.stamps_ns, stamps)
    assert 50.0 < gt.path_length_m() < 70.0  # the README's "about 60 m"
    assert source.imu() is None


def test_fake_sequence_reads_lazily_with_ground_truth(tmp_path: Path):
    seq = make_kitti(tmp_path)
    source = KittiSource(seq)
    assert len(source) == 3 and source.calibration.baseline_m == pytest.approx(0.5)
    assert (source.calibration.width, source.calibration.height) == (32, 20)
    np.testing.assert_array_equal(source.stamps_ns(), [0, 100_000_000, 200_000_000])
    gt = source.ground_truth()
    np.testing.assert_allclose(gt.positions[2], [2.0, 0.0, 4.0])
    # Images are read during iteration: deleting one after indexing fails only when it is reached.
    (seq / "image_1" / "000002.png").unlink()
    frames = iter(source)
    assert next(frames).index == 0 and next(frames).index == 1
    with pytest.raises(ImageReadError, match=r"image_1/000002\.png does not exist"):
        next(frames)


def test_missing_ground_truth_is_none(tmp_path: Path):
    assert KittiSource(make_kitti(tmp_path, poses=False)).ground_truth() is None


def test_ground_truth_count_mismatch_names_both_counts(tmp_path: Path):
    seq = make_kitti(tmp_path)
    (tmp_path / "poses" / "07.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n")
    with pytest.raises(DatasetError, match=r"07\.txt has 1 poses but the sequence has 3 frames"):
        KittiSource(seq).ground_truth()


def test_missing_sequence_folder(tmp_path: Path):
    with pytest.raises(DatasetError, match=r"sequences/99 does not exist"):
        KittiSource(tmp_path / "sequences" / "99")


def test_missing_image_folder(tmp_path: Path):
    seq = make_kitti(tmp_path)
    for p in (seq / "image_1").iterdir():
        p.unlink()
    (seq / "image_1").rmdir()
    with pytest.raises(DatasetError, match=r"image_1 does not exist.*--sensor mono"):
        KittiSource(seq)


def test_missing_calib(tmp_path: Path):
    seq = make_kitti(tmp_path)
    (seq / "calib.txt").unlink()
    with pytest.raises(CalibrationError, match=r"calib\.txt does not exist"):
        KittiSource(seq)


@pytest.mark.parametrize(
    "calib, message",
    [
        (f"{P0}\nP1: 700 0 300 0 0 700 100 0 0 0 1 0\n", r"P1\[0,3\]=0\.0 gives baseline"),
        (f"P0: 0 0 300 0 0 700 100 0 0 0 1 0\n{P1}\n", r"P0\[0,0\]=0\.0.*must be positive"),
        (f"{P0}\n", r"lacks \['P1'\]"),
        (f"{P0}\nP1: 700 0 300\n", r"P1 has 3 values, expected 12"),
        (f"{P0}\nP1: 700 0 300 -350 0 700 x 0 0 0 1 0\n", r"line 2: expected numbers"),
    ],
)
def test_invalid_calibration_names_file_and_problem(tmp_path: Path, calib: str, message: str):
    seq = make_kitti(tmp_path)
    (seq / "calib.txt").write_text(calib)
    with pytest.raises(DatasetError, match=r"calib\.txt.*" + message):
        KittiSource(seq)


def test_corrupt_image_fails_when_iteration_reaches_it(tmp_path: Path):
    seq = make_kitti(tmp_path)
    (seq / "image_0" / "000001.png").write_bytes(b"not a png at all")
    frames = iter(KittiSource(seq))
    assert next(frames).index == 0
    with pytest.raises(ImageReadError, match=r"image_0/000001\.png could not be decoded"):
        next(frames)


def test_image_size_differing_from_the_first_image(tmp_path: Path):
    seq = make_kitti(tmp_path)
    write_png(seq / "image_1" / "000000.png", np.zeros((21, 32), np.uint8))
    with pytest.raises(ImageReadError, match=r"image_1/000000\.png is 32x21 pixels but the calibration expects 32x20"):
        next(iter(KittiSource(seq)))


def test_times_not_increasing(tmp_path: Path):
    seq = make_kitti(tmp_path)
    (seq / "times.txt").write_text("0.0\n0.2\n0.1\n")
    with pytest.raises(TimestampError, match=r"times\.txt must strictly increase: line 3"):
        KittiSource(seq)


def test_times_count_differs_from_images(tmp_path: Path):
    seq = make_kitti(tmp_path)
    (seq / "times.txt").write_text("0.0\n0.1\n")
    with pytest.raises(DatasetError, match=r"3 images in image_0 but 2 stamps in .*times\.txt"):
        KittiSource(seq)


def test_left_right_counts_differ(tmp_path: Path):
    seq = make_kitti(tmp_path)
    (seq / "image_1" / "000002.png").unlink()
    with pytest.raises(DatasetError, match=r"image_0 has 3 images but image_1 has 2"):
        KittiSource(seq)


def test_gap_in_image_numbering(tmp_path: Path):
    seq = make_kitti(tmp_path)
    for folder in ("image_0", "image_1"):
        (seq / folder / "000001.png").rename(seq / folder / "000005.png")
    with pytest.raises(DatasetError, match=r"image 1 is 000002\.png, expected 000001\.png"):
        KittiSource(seq)


def _left_images_only(seq: Path) -> Path:
    """``seq`` without image_1: how monocular KITTI clips are shared."""
    for p in (seq / "image_1").iterdir():
        p.unlink()
    (seq / "image_1").rmdir()
    return seq


def test_image_0_alone_plays_as_mono(tmp_path: Path):
    seq = _left_images_only(make_kitti(tmp_path))
    (seq / "calib.txt").write_text(f"{P0}\n")  # a monocular clip needs P0 alone
    source = open_source(f"kitti:{seq}", "mono")
    assert source.sensor == "mono" and source.name == "kitti/07" and len(source) == 3
    assert source.calibration.baseline_m is None and source.calibration.fx == pytest.approx(700.0)
    frames = list(source)
    assert [f.index for f in frames] == [0, 1, 2]
    assert all(f.left.shape == (20, 32) and f.right is None and f.depth_m is None for f in frames)
    np.testing.assert_allclose(source.ground_truth().positions[2], [2.0, 0.0, 4.0])


def test_image_0_alone_gives_its_ground_truth_to_a_run_of_another_source(tmp_path: Path):
    """``--ground-truth kitti:<folder>`` (e.g. for frames published over zenoh) needs the poses only."""
    from zenslam.service.run_input import read_ground_truth

    seq = _left_images_only(make_kitti(tmp_path))
    (seq / "calib.txt").write_text(f"{P0}\n")
    np.testing.assert_allclose(read_ground_truth(f"kitti:{seq}").positions[2], [2.0, 0.0, 4.0])
    np.testing.assert_allclose(read_ground_truth(f"kitti:{make_kitti(tmp_path / 'stereo')}").positions[2], [2.0, 0.0, 4.0])


def test_stereo_sequence_played_mono_keeps_its_left_images(tmp_path: Path):
    source = open_source(f"kitti:{make_kitti(tmp_path)}", "mono")
    assert source.sensor == "mono" and source.calibration.baseline_m is None
    assert source.name == "kitti/07 (left images, monocular)"  # the stereo reader, viewed as mono
    assert next(iter(source)).right is None


@pytest.mark.parametrize("sensor", [None, "stereo"])
def test_image_0_alone_without_mono_names_the_sensor_option(tmp_path: Path, sensor):
    seq = _left_images_only(make_kitti(tmp_path))
    with pytest.raises(DatasetError, match=r"image_1 does not exist.*`--sensor mono` .*runs a sequence with image_0 alone"):
        open_source(f"kitti:{seq}", sensor)


def test_image_0_alone_as_mono_still_checks_the_left_numbering(tmp_path: Path):
    seq = _left_images_only(make_kitti(tmp_path))
    (seq / "image_0" / "000001.png").rename(seq / "image_0" / "000005.png")
    with pytest.raises(DatasetError, match=r"image 1 is 000002\.png, expected 000001\.png"):
        KittiSource(seq, mono_allowed=True)


@pytest.mark.extended  # a whole run: CI runs it after the README's command; the reader's own tests above cover the folder
@pytest.mark.dataset
@pytest.mark.integration
def test_run_with_sensor_mono_on_a_clip_of_image_0_alone(kitti_root: Path, tmp_path: Path):
    """``zenslam run kitti:... --sensor mono`` on the clip's left images alone (linked, not copied)."""
    seq = tmp_path / "kitti" / "sequences" / "06"
    seq.mkdir(parents=True)
    clip = kitti_root / "sequences" / "06"
    (seq / "image_0").symlink_to(clip / "image_0")
    for name in ("calib.txt", "times.txt"):
        (seq / name).symlink_to(clip / name)
    (tmp_path / "kitti" / "poses").symlink_to(kitti_root / "poses")
    command = [sys.executable, "-m", "zenslam.service.cli", "run", f"kitti:{seq}", "--max-frames", "15",
               "--output", str(tmp_path), "--run-id", "mono", "--no-progress"]
    refused = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert refused.returncode == 2 and "`--sensor mono`" in refused.stderr, refused.stderr[-2000:]
    result = subprocess.run([*command, "--sensor", "mono"], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    metrics = json.loads((tmp_path / "mono" / "metrics.json").read_text())
    assert metrics["frames"] == 15 and metrics["run"]["completed"]
    assert "sensor: mono" in (tmp_path / "mono" / "config.yaml").read_text()
