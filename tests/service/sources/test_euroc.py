"""EuRoC reader: the real micro clip (pairing, rectification, IMU, ground truth) and fake malformed sequences."""

import logging
from pathlib import Path

import cv2
import numpy as np
import pytest

from zenslam.errors import CalibrationError, DatasetError, ImageReadError, TimestampError
from zenslam.geometry import invert_T, so3_log
from zenslam.service.sources.euroc import EurocConfig, EurocSource, read_asl_camera
from zenslam.service.sources.images import read_grey, write_png

# EuRoC's own cam0/cam1 calibration with images scaled to a quarter (188x120) to keep fakes small.
CAM_YAML = """%YAML:1.0
sensor_type: camera
T_BS:
  cols: 4
  rows: 4
  data: [{T}]
rate_hz: 20
resolution: [188, 120]
camera_model: pinhole
intrinsics: [{K}] #fu, fv, cu, cv
distortion_model: radial-tangential
distortion_coefficients: [{D}]
"""
CAM0 = dict(
    T="0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975, 0.999557249008, 0.0149672133247, "
    "0.025715529948, -0.064676986768, -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949, 0, 0, 0, 1",
    K="114.6635, 114.324, 91.80375, 62.09375",
    D="-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05",
)
CAM1 = dict(
    T="0.0125552670891, -0.999755099723, 0.0182237714554, -0.0198435579556, 0.999598781151, 0.0130119051815, "
    "0.0251588363115, 0.0453689425024, -0.0253898008918, 0.0179005838253, 0.999517347078, 0.00786212447038, 0, 0, 0, 1",
    K="114.39675, 114.0335, 94.99975, 63.8095",
    D="-0.28368365, 0.07451284, -0.00010473, -3.55590700e-05",
)
IMU_YAML = "%YAML:1.0\nsensor_type: imu\nT_BS:\n  cols: 4\n  rows: 4\n  data: [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]\n"
T0 = 1403715273262142976


def make_euroc(root: Path, n: int = 3, cam1_offset_ns: int = 0) -> Path:
    """A fake ASL sequence with n random stereo pairs at 20 Hz and 200 Hz IMU; returns the sequence folder."""
    rng = np.random.default_rng(3)
    for cam, values, offset in (("cam0", CAM0, 0), ("cam1", CAM1, cam1_offset_ns)):
        folder = root / "mav0" / cam
        stamps = [T0 + i * 50_000_000 + offset for i in range(n)]
        for s in stamps:
            write_png(folder / "data" / f"{s}.png", rng.integers(0, 255, size=(120, 188), dtype=np.uint8))
        (folder / "data.csv").write_text("#timestamp [ns],filename\n" + "".join(f"{s},{s}.png\n" for s in stamps))
        (folder / "sensor.yaml").write_text(CAM_YAML.format(**values))
    imu = root / "mav0" / "imu0"
    imu.mkdir(parents=True)
    (imu / "sensor.yaml").write_text(IMU_YAML)
    (imu / "data.csv").write_text("#timestamp [ns],wx,wy,wz,ax,ay,az\n" + "".join(
        f"{T0 + i * 5_000_000},0.1,0.2,0.3,9.8,0,{i}\n" for i in range(40)))  # fmt: skip
    return root


def _orb_vertical_offset_px(left: np.ndarray, right: np.ndarray) -> float:
    """Median |v_left - v_right| (px) over cross-checked ORB matches."""
    orb = cv2.ORB_create(1000)
    kl, dl = orb.detectAndCompute(left, None)
    kr, dr = orb.detectAndCompute(right, None)
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(dl, dr)
    assert len(matches) > 100
    return float(np.median([abs(kl[m.queryIdx].pt[1] - kr[m.trainIdx].pt[1]) for m in matches]))


@pytest.fixture(scope="module")
def micro_source(euroc_micro: Path) -> EurocSource:
    return EurocSource(euroc_micro)


@pytest.mark.dataset
def test_micro_clip_pairs_95_frames_and_warns_about_4_missing(euroc_micro: Path, caplog):
    with caplog.at_level(logging.WARNING, logger="zenslam.service.sources.euroc"):
        source = EurocSource(euroc_micro)
    assert len(source) == 95 and source.name == "euroc/V1_01_easy_micro" and source.sensor == "stereo"
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1
    assert str(euroc_micro / "mav0") in warnings[0]
    assert "dropped 4 rows whose image file is missing (cam0 0, cam1 4)" in warnings[0]
    stamps = source.stamps_ns()
    assert stamps[0] == T0 and np.all(np.diff(stamps) > 0)


@pytest.mark.dataset
def test_micro_clip_rectified_calibration(micro_source: EurocSource):
    cal = micro_source.calibration
    assert (cal.width, cal.height) == (752, 480)
    assert 0.105 <= cal.baseline_m <= 0.115
    assert 400.0 < cal.fx < 470.0 and cal.fx == cal.fy  # stereoRectify gives one focal length to both axes
    assert 0 < cal.cx < 752 and 0 < cal.cy < 480


@pytest.mark.dataset
def test_micro_clip_rectification_aligns_rows(micro_source: EurocSource, euroc_micro: Path):
    frame = next(iter(micro_source))
    assert frame.left.shape == (480, 752) and frame.right.shape == (480, 752) and frame.left.dtype == np.uint8
    after = _orb_vertical_offset_px(frame.left, frame.right)
    raw = [euroc_micro / "mav0" / cam / "data" / f"{frame.stamp_ns}.png" for cam in ("cam0", "cam1")]
    before = _orb_vertical_offset_px(read_grey(raw[0]), read_grey(raw[1]))
    assert after < 1.0
    assert before > 5.0  # measured 12.1 px on the raw pair


@pytest.mark.dataset
def test_micro_clip_imu_at_200_hz(micro_source: EurocSource):
    imu = micro_source.imu()
    assert imu is not None and len(imu.stamps_ns) > 1000
    assert imu.gyro_rad_s.shape == imu.accel_m_s2.shape == (len(imu.stamps_ns), 3)
    assert np.median(np.diff(imu.stamps_ns)) == pytest.approx(5_000_000, abs=1_000)
    # Standing still: gravity's magnitude, within the ADIS16448's bias.
    assert np.linalg.norm(imu.accel_m_s2[:100].mean(axis=0)) == pytest.approx(9.81, abs=0.2)
    R = imu.T_cam_imu[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
    # The camera sits ~7 cm from the IMU, rotated ~90 degrees about the optical axis.
    assert 0.05 < np.linalg.norm(imu.T_cam_imu[:3, 3]) < 0.1


@pytest.mark.dataset
def test_micro_clip_ground_truth_is_the_rectified_left_camera(micro_source: EurocSource, euroc_micro: Path):
    gt = micro_source.ground_truth()
    assert gt is not None and len(gt) == 74
    assert set(gt.stamps_ns.tolist()) <= set(micro_source.stamps_ns().tolist())
    raw = np.loadtxt(euroc_micro / "groundtruth_cam0.csv", delimiter=",", comments="#")
    # Rectification is a pure rotation of cam0: positions are the file's, orientations differ by < 2 degrees.
    np.testing.assert_allclose(gt.positions, raw[:, 1:4], atol=1e-9)
    T_body_cam0 = read_asl_camera(euroc_micro / "mav0" / "cam0" / "sensor.yaml").T_body_cam
    T_cam0_rect = invert_T(T_body_cam0) @ micro_source.T_body_cam
    angle = np.linalg.norm(so3_log(T_cam0_rect[:3, :3]))
    assert 1e-4 < angle < np.deg2rad(2.0)
    # Over the clip the drone barely moves (README: 1.5 cm).
    assert np.linalg.norm(gt.positions[-1] - gt.positions[0]) < 0.05


def test_fake_sequence_reads_with_imu(tmp_path: Path):
    source = EurocSource(make_euroc(tmp_path))
    assert len(source) == 3
    frames = list(source)
    assert [f.stamp_ns for f in frames] == [T0, T0 + 50_000_000, T0 + 100_000_000]
    assert all(f.left.shape == (120, 188) and f.right.shape == (120, 188) for f in frames)
    imu = source.imu()
    assert len(imu.stamps_ns) == 40 and imu.accel_m_s2[7, 2] == 7.0
    # T_cam_imu places the IMU in the rectified camera: its inverse is the camera pose in the body (= IMU) frame.
    np.testing.assert_allclose(invert_T(imu.T_cam_imu), source.T_body_cam, atol=1e-12)
    assert source.ground_truth() is None


def test_stereo_pairs_within_tolerance_and_drops_beyond(tmp_path: Path, caplog):
    root = make_euroc(tmp_path / "near", cam1_offset_ns=200)
    assert len(EurocSource(root)) == 3
    root = make_euroc(tmp_path / "far", cam1_offset_ns=2_000_000)
    with pytest.raises(DatasetError, match=r"no stereo pair left \(3 cam0 rows, 3 cam1 rows"):
        EurocSource(root)
    assert len(EurocSource(root, EurocConfig(stereo_max_gap_ns=3_000_000))) == 3


def test_missing_right_image_is_dropped_at_index_time(tmp_path: Path, caplog):
    root = make_euroc(tmp_path, n=4)
    (root / "mav0" / "cam1" / "data" / f"{T0 + 50_000_000}.png").unlink()
    with caplog.at_level(logging.WARNING):
        source = EurocSource(root)
    assert source.stamps_ns().tolist() == [T0, T0 + 100_000_000, T0 + 150_000_000]
    assert "dropped 1 rows whose image file is missing (cam0 0, cam1 1) and 1 rows without a partner" in caplog.text
    assert len(list(source)) == 3


def test_body_ground_truth_becomes_the_rectified_left_camera(tmp_path: Path):
    root = make_euroc(tmp_path)
    gt_dir = root / "mav0" / "state_groundtruth_estimate0"
    gt_dir.mkdir()
    (gt_dir / "data.csv").write_text(
        "#timestamp,p_x,p_y,p_z,q_w,q_x,q_y,q_z,v_x,v_y,v_z,bw_x,bw_y,bw_z,ba_x,ba_y,ba_z\n"
        f"{T0},1,2,3,1,0,0,0,0,0,0,0,0,0,0,0,0\n{T0 + 7},1,2,3,0,0,0,1,0,0,0,0,0,0,0,0,0\n"
    )
    source = EurocSource(root)
    gt = source.ground_truth()
    expected = source.T_body_cam.copy()
    expected[:3, 3] += [1, 2, 3]
    np.testing.assert_allclose(gt.T_world_cam[0], expected, atol=1e-12)
    np.testing.assert_array_equal(gt.stamps_ns, [T0, T0 + 7])
    # The second body pose is turned 180 degrees about z.
    np.testing.assert_allclose(gt.T_world_cam[1][:3, :3], np.diag([-1, -1, 1]) @ expected[:3, :3], atol=1e-12)


def test_missing_mav0(tmp_path: Path):
    with pytest.raises(DatasetError, match=r"seq has no mav0/ folder"):
        EurocSource(tmp_path / "seq")


def test_missing_sensor_yaml(tmp_path: Path):
    root = make_euroc(tmp_path)
    (root / "mav0" / "cam1" / "sensor.yaml").unlink()
    with pytest.raises(CalibrationError, match=r"cam1/sensor\.yaml does not exist"):
        EurocSource(root)


def test_missing_image_folder(tmp_path: Path):
    root = make_euroc(tmp_path)
    for p in (root / "mav0" / "cam0" / "data").iterdir():
        p.unlink()
    (root / "mav0" / "cam0" / "data").rmdir()
    with pytest.raises(DatasetError, match=r"cam0/data does not exist"):
        EurocSource(root)


@pytest.mark.parametrize(
    "old, new, message",
    [
        ("intrinsics: [114.6635, 114.324, 91.80375, 62.09375] #fu, fv, cu, cv\n", "", r"lacks 'intrinsics'"),
        ("114.6635, 114.324,", "-114.6635, 114.324,", r"fu=-114\.6635, fv=114\.324 must be positive"),
        ("1.76187114e-05]", "]", r"'distortion_coefficients' has 3 values .* expected 4 or 5"),
        ("distortion_model: radial-tangential", "distortion_model: equidistant", r"equidistant.*radial-tangential"),
        ("0.00981073058949, 0, 0, 0, 1", "0.00981073058949, 0, 0, 0", r"'data' has 15 values"),
        ("0.0148655429818, -0.9998", "0.5, -0.9998", r"T_BS is not a rigid transform"),
    ],
)
def test_invalid_sensor_yaml_names_file_and_problem(tmp_path: Path, old: str, new: str, message: str):
    root = make_euroc(tmp_path)
    path = root / "mav0" / "cam0" / "sensor.yaml"
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new))
    with pytest.raises(CalibrationError, match=r"cam0/sensor\.yaml.*" + message):
        EurocSource(root)


def test_camera_stamps_not_increasing(tmp_path: Path):
    root = make_euroc(tmp_path)
    csv = root / "mav0" / "cam1" / "data.csv"
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join([lines[0], lines[2], lines[1], lines[3]]) + "\n")
    with pytest.raises(TimestampError, match=r"cam1/data\.csv must strictly increase: line 3"):
        EurocSource(root)


def test_corrupt_image_fails_when_iteration_reaches_it(tmp_path: Path):
    root = make_euroc(tmp_path)
    bad = root / "mav0" / "cam1" / "data" / f"{T0 + 50_000_000}.png"
    bad.write_bytes(b"\x00garbage")
    frames = iter(EurocSource(root))
    next(frames)
    with pytest.raises(ImageReadError, match=rf"{bad.name} could not be decoded"):
        next(frames)


def test_image_size_differing_from_sensor_yaml(tmp_path: Path):
    root = make_euroc(tmp_path)
    write_png(root / "mav0" / "cam0" / "data" / f"{T0}.png", np.zeros((480, 752), np.uint8))
    with pytest.raises(ImageReadError, match=rf"{T0}\.png is 752x480 pixels but the calibration expects 188x120"):
        next(iter(EurocSource(root)))


def test_imu_yaml_missing_is_a_calibration_error(tmp_path: Path):
    root = make_euroc(tmp_path)
    (root / "mav0" / "imu0" / "sensor.yaml").unlink()
    with pytest.raises(CalibrationError, match=r"imu0/sensor\.yaml does not exist"):
        EurocSource(root).imu()
