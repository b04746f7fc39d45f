"""benchmarks/vs_orbslam3.py's pure parts: the ORB-SLAM2-style settings, the vocabulary in DBoW2 text,
reading ORB-SLAM3's saved trajectory, failure lines and summaries; none of it needs pyorbslam3."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from zenslam.camera import PinholeCalibration
from zenslam.frontend.orb_extractor import OrbConfig
from zenslam.geometry import R_to_quat_wxyz, make_T, so3_exp
from zenslam.service.run_config import read_orbslam_settings
from zenslam.vocabulary import Vocabulary, load_vocabulary, save_vocabulary

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"

# KITTI odometry sequences 04-12 (calib.txt P0, P1): fx = fy, cx, cy, and -P1[0,3] = baseline x fx.
KITTI_04_12 = PinholeCalibration(707.0912, 707.0912, 601.8873, 183.1104, 1226, 370, 379.8145 / 707.0912)
# What ORB-SLAM2's Examples/Stereo/KITTI04-12.yaml holds (its Camera.width/height, 1241x376, are
# sequences 00-02's; the writer takes the images' size from the calibration).
ORB_SLAM2_KITTI_04_12_STEREO = {
    "Camera.fx": 707.0912, "Camera.fy": 707.0912, "Camera.cx": 601.8873, "Camera.cy": 183.1104,
    "Camera.k1": 0.0, "Camera.k2": 0.0, "Camera.p1": 0.0, "Camera.p2": 0.0, "Camera.fps": 10.0,
    "Camera.bf": 379.8145, "Camera.RGB": 1, "ThDepth": 40.0, "ORBextractor.nFeatures": 2000,
    "ORBextractor.scaleFactor": 1.2, "ORBextractor.nLevels": 8, "ORBextractor.iniThFAST": 12,
    "ORBextractor.minThFAST": 7, "Viewer.KeyFrameSize": 0.6, "Viewer.KeyFrameLineWidth": 2,
    "Viewer.GraphLineWidth": 1, "Viewer.PointSize": 2, "Viewer.CameraSize": 0.7, "Viewer.CameraLineWidth": 3,
    "Viewer.ViewpointX": 0, "Viewer.ViewpointY": -100, "Viewer.ViewpointZ": -0.1, "Viewer.ViewpointF": 2000,
}  # fmt: skip
ORB_SLAM2_KITTI_ORB = OrbConfig(n_features=2000, scale_factor=1.2, n_levels=8, ini_fast_threshold=12, min_fast_threshold=7)


@pytest.fixture(scope="module")
def bench():
    """The benchmark script as a module (benchmarks/ on sys.path for its footprint import, as when run)."""
    sys.path.append(str(BENCHMARKS))
    try:
        spec = importlib.util.spec_from_file_location("vs_orbslam3", BENCHMARKS / "vs_orbslam3.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules["vs_orbslam3"] = module  # its dataclasses look their module up there
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(BENCHMARKS))
    return module


def read_settings(path: Path) -> dict[str, object]:
    """Every top-level key of an OpenCV YAML file, read as ORB-SLAM reads it (cv::FileStorage)."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    root = fs.root()
    values = {}
    for key in root.keys():
        node = root.getNode(key)
        values[key] = node.string() if node.isString() else node.real()
    fs.release()
    return values


def test_kitti_settings_hold_what_orb_slam2_kitti04_12_holds(bench, tmp_path: Path):
    path = tmp_path / "kitti.yaml"
    path.write_text(bench.orbslam2_settings_text(KITTI_04_12, "stereo", 10.0, ORB_SLAM2_KITTI_ORB, 40.0))
    assert path.read_text().startswith("%YAML:1.0\n")
    values = read_settings(path)
    for key, expected in ORB_SLAM2_KITTI_04_12_STEREO.items():
        assert values[key] == pytest.approx(expected, rel=1e-9), key
    assert values["Camera.type"] == "PinHole"
    assert (values["Camera.width"], values["Camera.height"]) == (1226, 370)
    # The old format: nothing of ORB-SLAM3's new one (File.version, Camera1.*), which pyorbslam3 0.1.1 fails on.
    assert not [key for key in values if key == "File.version" or key.startswith(("Camera1", "Stereo."))]
    # zenslam's own reader of ORB-SLAM settings gets the calibration back.
    settings = read_orbslam_settings(path)
    assert settings.calibration.K == pytest.approx(KITTI_04_12.K, abs=1e-9)
    assert settings.calibration.baseline_m == pytest.approx(KITTI_04_12.baseline_m, rel=1e-9)
    assert settings.th_depth == 40.0 and settings.orb["n_features"] == 2000 and settings.orb["ini_fast_threshold"] == 12


def test_mono_settings_have_no_stereo_keys_and_rgbd_ones_a_metric_depth_factor(bench, tmp_path: Path):
    mono = tmp_path / "mono.yaml"
    mono.write_text(bench.orbslam2_settings_text(KITTI_04_12, "mono", 10.0, OrbConfig(), 35.0))
    assert not {"Camera.bf", "ThDepth", "DepthMapFactor"} & set(read_settings(mono))
    rgbd = tmp_path / "rgbd.yaml"
    room = PinholeCalibration(460.0, 460.0, 319.5, 239.5, 640, 480, 0.1)
    rgbd.write_text(bench.orbslam2_settings_text(room, "rgbd", 10.0, OrbConfig(), 35.0))
    values = read_settings(rgbd)
    assert values["DepthMapFactor"] == 1.0 and values["Camera.bf"] == pytest.approx(46.0) and values["ThDepth"] == 35.0
    assert values["ORBextractor.nFeatures"] == OrbConfig().n_features


def test_frame_rate_is_the_clips_rate_in_whole_frames_per_second(bench):
    stamps = np.cumsum(np.r_[0, np.random.default_rng(0).uniform(0.0990e9, 0.1049e9, 50)]).astype(np.int64)
    assert bench.frame_rate(stamps) == 10.0
    assert bench.frame_rate(np.arange(5) * 50_000_000) == 20.0


def test_vocabulary_exported_as_dbow2_text_loads_back_equal(bench, tmp_path: Path):
    rng = np.random.default_rng(3)
    parents = [-1, 0, 0, 1, 1, 2, 2]  # k=2, L=2: two inner nodes, four words
    weights = np.r_[0.0, 0.0, 0.0, np.log(rng.uniform(1.0, 40.0, 4))]
    ours = Vocabulary(2, 2, parents, rng.integers(0, 256, (7, 32), dtype=np.uint8), weights)
    npz = save_vocabulary(ours, tmp_path / "ours.npz")
    text = bench.export_vocabulary(tmp_path / "ours.dbow2.txt", npz)
    assert text.read_text().splitlines()[0].split() == ["2", "2", "0", "0"]  # k L, L1 scoring, TF-IDF
    again = load_vocabulary(text)
    for name in ("parents", "descriptors", "weights", "is_leaf"):
        assert np.array_equal(getattr(again, name), getattr(ours, name)), name


def test_orbslam3_trajectory_file_is_read_at_the_frames_stamps_without_repeated_lines(bench, tmp_path: Path):
    stamp0 = 1_403_715_273_262_142_976
    stamps = stamp0 + np.arange(4) * 50_000_000 + np.array([0, 3, 0, 7])  # ns the float seconds could not carry
    rng = np.random.default_rng(5)
    poses = [make_T(so3_exp(rng.normal(0, 0.3, 3)), rng.normal(0, 2, 3)) for _ in stamps]
    lines = []
    for i in (0, 1, 1, 3):  # frame 2 was lost (RECENTLY_LOST): ORB-SLAM3 repeats frame 1's line
        t_s = (stamps[i] - stamp0) * 1e-9
        w, x, y, z = R_to_quat_wxyz(poses[i][:3, :3])
        p = poses[i][:3, 3]
        lines.append(f"{1e9 * t_s:.6f} {p[0]:.9f} {p[1]:.9f} {p[2]:.9f} {x:.9f} {y:.9f} {z:.9f} {w:.9f}")
    path = tmp_path / "f.txt"
    path.write_text("\n".join(lines) + "\n")
    trajectory = bench.read_orbslam3_trajectory(path, stamp0, stamps)
    assert trajectory.stamps_ns.tolist() == [stamps[0], stamps[1], stamps[3]]
    assert np.allclose(trajectory.T_world_cam, [poses[0], poses[1], poses[3]], atol=1e-7)


def test_a_crashed_child_is_named_by_its_signal_and_a_failed_one_by_its_reason(bench):
    crashed = subprocess.CompletedProcess([], -11, "", "")
    assert bench.describe_failure(crashed) == "ORB-SLAM3 crashed (SIGSEGV)"
    failed = subprocess.CompletedProcess([], 3, "", "noise\nvs_orbslam3: pyorbslam3 does not import: OSError: libGL.so.1\n")
    assert bench.describe_failure(failed) == "pyorbslam3 does not import: OSError: libGL.so.1"


def summary_clip(orbslam3_tracked: int) -> dict:
    ok = {"tracked_ok": 51, "frames": 51}
    orb = {"tracked_ok": orbslam3_tracked, "frames": 51}
    return {
        "zenslam": {"rounds": [{"ate_m": 0.03, "wall_s": 20.0, "peak_rss_sum_mb": 900.0, "peak_pss_sum_mb": 600.0, **ok},
                               {"ate_m": 0.05, "wall_s": 30.0, "peak_rss_sum_mb": 1000.0, "peak_pss_sum_mb": 700.0, **ok},
                               {"ate_m": 0.04, "wall_s": 25.0, "peak_rss_sum_mb": 950.0, "peak_pss_sum_mb": 650.0, **ok}]},
        "orbslam3": {"rounds": [{"ate_m": 0.08, "wall_s": 5.0, "peak_rss_mb": 190.0, "peak_pss_mb": 170.0, **orb},
                                {"error": "ORB-SLAM3 crashed (SIGSEGV)"},
                                {"ate_m": 0.06, "wall_s": 7.0, "peak_rss_mb": 180.0, "peak_pss_mb": 160.0, **orb}]},
    }  # fmt: skip


def test_summary_takes_medians_over_the_rounds_that_ran_and_their_ratios(bench):
    clip = summary_clip(orbslam3_tracked=51)
    bench.summarise(clip)
    assert clip["zenslam"]["median"]["ate_m"] == pytest.approx(0.04)
    assert clip["orbslam3"]["median"]["ate_m"] == pytest.approx(0.07)
    ratios = clip["ratio_zenslam_over_orbslam3"]
    assert ratios["ate_m"] == pytest.approx(0.04 / 0.07)
    assert ratios["wall_s"] == pytest.approx(25.0 / 6.0)
    assert ratios["peak_rss_mb"] == pytest.approx(950.0 / 185.0)
    assert ratios["peak_pss_mb"] == pytest.approx(650.0 / 165.0)
    assert ratios["tracking_median_ms"] is None  # neither measured it


def test_no_ate_ratio_where_a_system_tracked_few_of_the_frames(bench):
    clip = summary_clip(orbslam3_tracked=6)
    bench.summarise(clip)
    ratios = clip["ratio_zenslam_over_orbslam3"]
    assert ratios["ate_m"] is None and ratios["ate_final_m"] is None
    assert ratios["wall_s"] == pytest.approx(25.0 / 6.0)


def test_the_script_does_not_import_pyorbslam3(bench):
    assert "pyorbslam3" not in sys.modules


def test_the_table_shows_peak_pss_beside_peak_rss(bench, capsys):
    clip = summary_clip(orbslam3_tracked=51)
    bench.summarise(clip)
    bench.print_table({"clips": {"kitti06_stereo": clip}})
    lines = capsys.readouterr().out.splitlines()
    header = lines[0].split()
    assert "PSS" in header and header.index("PSS") > header.index("RSS")
    zenslam, orbslam3 = (next(line for line in lines if f" {system} " in line) for system in ("zenslam", "orbslam3"))
    assert " 950 " in zenslam and " 650 " in zenslam
    assert " 185 " in orbslam3 and " 165 " in orbslam3
