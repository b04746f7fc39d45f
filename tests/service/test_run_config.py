"""Run configuration: YAML sections round-trip strictly; ORB-SLAM2/3 settings files give calibration and ORB values."""

from __future__ import annotations

import textwrap

import pytest

from zenslam.backend.local_mapping import LocalMappingConfig
from zenslam.camera import PinholeCalibration
from zenslam.errors import CalibrationError, ConfigError
from zenslam.map_rules_config import MapRulesConfig
from zenslam.runtime.bus import BusConfig
from zenslam.service.run_config import (
    BackendConfig,
    RunConfig,
    SourceConfig,
    apply_orbslam_settings,
    fit_calibration_to_images,
    load_run_config,
    read_orbslam_settings,
    run_config_to_yaml,
    with_map_rules,
)
from zenslam.service.recorder_config import RecorderConfig

# ORB-SLAM3's own format (File.version 1.0), with the values of its KITTI 04-12 example.
ORBSLAM3_KITTI = """\
%YAML:1.0
File.version: "1.0"
Camera.type: "Rectified"
Camera1.fx: 707.0912
Camera1.fy: 707.0912
Camera1.cx: 601.8873
Camera1.cy: 183.1104
Camera.width: 1226
Camera.height: 370
Camera.fps: 10
Stereo.b: 0.53715
Camera.RGB: 1
Stereo.ThDepth: 40.0
ORBextractor.nFeatures: 2000
ORBextractor.scaleFactor: 1.2
ORBextractor.nLevels: 8
ORBextractor.iniThFAST: 12
ORBextractor.minThFAST: 7
Viewer.PointSize:2
"""

# ORB-SLAM2's format with a stereo rectification (the EuRoC example's LEFT.P / RIGHT.P).
ORBSLAM2_EUROC = """\
%YAML:1.0
Camera.fx: 435.2046959714599
Camera.fy: 435.2046959714599
Camera.cx: 367.4517211914062
Camera.cy: 252.2008514404297
Camera.k1: 0.0
Camera.k2: 0.0
Camera.p1: 0.0
Camera.p2: 0.0
Camera.width: 752
Camera.height: 480
Camera.fps: 20.0
Camera.bf: 47.90639384423901
ThDepth: 35
LEFT.D: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data:[-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0]
LEFT.P:  !!opencv-matrix
   rows: 3
   cols: 4
   dt: d
   data: [435.2046959714599, 0, 367.4517211914062, 0,  0, 435.2046959714599, 252.2008514404297, 0,  0, 0, 1, 0]
RIGHT.P:  !!opencv-matrix
   rows: 3
   cols: 4
   dt: d
   data: [435.2046959714599, 0, 367.4517211914062, -47.90639384423901, 0, 435.2046959714599, 252.2008514404297, 0, 0, 0, 1, 0]
ORBextractor.nFeatures: 1200
"""

# ORB-SLAM3's and ORB-SLAM2's stock KITTI04-12.yaml: both state 1241x376, the images of 04-12 are 1226x370.
ORBSLAM3_KITTI_04_12 = ORBSLAM3_KITTI.replace("Camera.width: 1226", "Camera.width: 1241").replace(
    "Camera.height: 370", "Camera.height: 376"
)
ORBSLAM2_KITTI_04_12 = """\
%YAML:1.0
Camera.type: "PinHole"
Camera.fx: 707.0912
Camera.fy: 707.0912
Camera.cx: 601.8873
Camera.cy: 183.1104
Camera.k1: 0.0
Camera.k2: 0.0
Camera.p1: 0.0
Camera.p2: 0.0
Camera.bFishEye: 0
Camera.width: 1241
Camera.height: 376
Camera.fps: 10.0
Camera.bf: 379.8145
Camera.RGB: 1
ThDepth: 40.0
ORBextractor.nFeatures: 2000
"""

RGBD_DISTORTED = """\
%YAML:1.0
Camera.fx: 517.3
Camera.fy: 516.5
Camera.cx: 318.6
Camera.cy: 255.3
Camera.k1: 0.2624
Camera.k2: -0.9531
Camera.width: 640
Camera.height: 480
Camera.bf: 40.0
DepthMapFactor: 5000.0
"""


def test_defaults_round_trip_through_yaml(tmp_path):
    path = tmp_path / "config.yaml"
    path.write_text(run_config_to_yaml(RunConfig()))
    assert load_run_config(path) == RunConfig()
    assert load_run_config(None) == RunConfig()


def test_a_full_config_round_trips(tmp_path):
    calibration = PinholeCalibration(400.0, 401.0, 320.0, 240.0, 640, 480, 0.1)
    config = RunConfig(
        bus=BusConfig(listen=("tcp/127.0.0.1:7447",), connect=("tcp/127.0.0.1:7448",)),
        source=SourceConfig(spec="synthetic:still/rgbd", max_frames=5, calibration=calibration),
    )
    path = tmp_path / "config.yaml"
    path.write_text(run_config_to_yaml(config))
    assert load_run_config(path) == config


def test_sections_take_partial_mappings(tmp_path):
    path = tmp_path / "config.yaml"
    path.write_text("source:\n  rate: 2.0\nfrontend:\n  orb:\n    n_features: 500\n")
    config = load_run_config(path)
    assert config.source.rate == 2.0 and config.frontend.orb.n_features == 500
    assert config.bus == BusConfig()


def test_unknown_keys_are_named(tmp_path):
    path = tmp_path / "config.yaml"
    path.write_text("source:\n  speed: 2.0\nbakend: {}\n")
    with pytest.raises(ConfigError) as info:
        load_run_config(path)
    assert "'bakend'" in str(info.value) and "'speed'" in str(info.value)


def test_source_values_are_checked():
    with pytest.raises(ConfigError, match="source.rate=-1"):
        SourceConfig(rate=-1.0)
    with pytest.raises(ConfigError, match="max_frames=0"):
        SourceConfig(max_frames=0)


def test_orbslam3_settings(tmp_path):
    path = tmp_path / "KITTI06.yaml"
    path.write_text(ORBSLAM3_KITTI)
    settings = read_orbslam_settings(path)
    assert settings.calibration == PinholeCalibration(707.0912, 707.0912, 601.8873, 183.1104, 1226, 370, 0.53715)
    assert settings.fps == 10.0 and settings.th_depth == 40.0
    assert settings.orb == {"n_features": 2000, "scale_factor": 1.2, "n_levels": 8, "ini_fast_threshold": 12, "min_fast_threshold": 7}
    config = apply_orbslam_settings(RunConfig(), settings)
    assert config.source.calibration == settings.calibration
    assert config.frontend.orb.n_features == 2000 and config.frontend.orb.ini_fast_threshold == 12
    assert config.frontend.keyframe.close_depth_baselines == 40.0
    assert config.frontend.keyframe.max_frames == 10


def test_orbslam2_settings_with_stereo_rectification(tmp_path):
    path = tmp_path / "EuRoC.yaml"
    path.write_text(ORBSLAM2_EUROC)
    settings = read_orbslam_settings(path)
    cal = settings.calibration
    assert (cal.fx, cal.cx, cal.cy, cal.width, cal.height) == (435.2046959714599, 367.4517211914062, 252.2008514404297, 752, 480)
    assert cal.baseline_m == pytest.approx(47.90639384423901 / 435.2046959714599, rel=1e-12)  # 0.110 m
    assert settings.th_depth == 35.0 and settings.orb == {"n_features": 1200}


def test_distorted_camera_without_rectification_is_refused(tmp_path):
    path = tmp_path / "TUM1.yaml"
    path.write_text(RGBD_DISTORTED)
    with pytest.raises(CalibrationError, match=r"TUM1.yaml: distortion \{'k1': 0.2624, 'k2': -0.9531\}"):
        read_orbslam_settings(path)


def test_settings_without_intrinsics_say_what_is_missing(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("%YAML:1.0\nCamera.width: 640\nCamera.height: 480\nCamera.fx: 500.0\n")
    with pytest.raises(CalibrationError, match="missing Camera.fy"):
        read_orbslam_settings(path)


def test_missing_settings_file(tmp_path):
    with pytest.raises(ConfigError, match="nope.yaml does not exist"):
        read_orbslam_settings(tmp_path / "nope.yaml")


def test_yaml_is_readable_by_people():
    text = run_config_to_yaml(RunConfig())
    assert text.index("bus:") < text.index("source:") < text.index("frontend:")
    assert textwrap.dedent(text) == text


def test_backend_and_recorder_nice_are_niceness_increments():
    # Where they yield the CPU to tracking (the recorder in pipelined and live runs, the backend in
    # live runs), recording yields most.
    assert 0 < BackendConfig().nice < RecorderConfig().nice <= 19
    assert BackendConfig(nice=0).nice == 0 and RecorderConfig(nice=19).nice == 19
    for bad in (-1, 20):
        with pytest.raises(ConfigError, match=f"backend.nice={bad}"):
            BackendConfig(nice=bad)
        with pytest.raises(ConfigError, match=f"recorder.nice={bad}"):
            RecorderConfig(nice=bad)


def test_pipelining_settings_are_checked(tmp_path):
    assert SourceConfig().frames_in_flight == 2 and RunConfig().mode == "lockstep"
    with pytest.raises(ConfigError, match="frames_in_flight=0"):
        SourceConfig(frames_in_flight=0)
    path = tmp_path / "config.yaml"
    path.write_text("mode: sometimes\nrecorder:\n  chunk_compression: gzip\n")
    with pytest.raises(ConfigError) as info:
        load_run_config(path)
    assert "mode" in str(info.value) and "sometimes" in str(info.value) and "chunk_compression" in str(info.value)


@pytest.mark.parametrize(
    ("lockstep", "waits", "mode"),
    [("true", "true", "lockstep"), ("true", "false", "pipelined"), ("false", "true", "live")],
)
def test_files_of_an_earlier_zenslam_are_read_with_their_run_mode(tmp_path, caplog, lockstep, waits, mode):
    path = tmp_path / "config.yaml"
    path.write_text(
        f"source:\n  lockstep: {lockstep}\n  start_timeout_s: 5.0\n"
        f"backend:\n  wait_for_map_updates: {waits}\n  map_update_queue: 7\n"
    )
    config = load_run_config(path)
    assert (config.mode, config.bus.start_timeout_s, config.frontend.map_update_queue) == (mode, 5.0, 7)
    assert "earlier zenslam" in caplog.text and "source.lockstep" in caplog.text


@pytest.mark.parametrize(("option", "mode"), [(None, "lockstep"), ("--lockstep", "lockstep"), ("--pipelined", "pipelined"), ("--live", "live")])
def test_the_run_modes_from_the_command_line(option, mode):
    import argparse

    from zenslam.service.commands import run as run_command

    parser = argparse.ArgumentParser()
    run_command.register(parser.add_subparsers())
    args = parser.parse_args(["run", "synthetic", *([option] if option else [])])
    config = run_command.resolve_config(args)
    assert config.mode == mode


@pytest.mark.parametrize("text", [ORBSLAM3_KITTI_04_12, ORBSLAM2_KITTI_04_12], ids=["orbslam3", "orbslam2"])
def test_a_slightly_different_stated_size_is_a_warning(tmp_path, caplog, text):
    path = tmp_path / "KITTI04-12.yaml"
    path.write_text(text)
    config = apply_orbslam_settings(RunConfig(), read_orbslam_settings(path))
    assert (config.source.calibration.width, config.source.calibration.height) == (1241, 376)
    with caplog.at_level("WARNING", logger="zenslam.camera"):
        fitted = fit_calibration_to_images(config, 1226, 370).source.calibration
    assert (fitted.width, fitted.height) == (1226, 370)
    assert (fitted.fx, fitted.fy, fitted.cx, fitted.cy) == (707.0912, 707.0912, 601.8873, 183.1104)
    assert fitted.baseline_m == pytest.approx(0.53715, rel=1e-4)
    assert "1241x376" in caplog.text and "1226x370" in caplog.text


@pytest.mark.parametrize("text", [ORBSLAM3_KITTI_04_12, ORBSLAM2_KITTI_04_12], ids=["orbslam3", "orbslam2"])
def test_a_gross_size_mismatch_is_refused(tmp_path, text):
    path = tmp_path / "KITTI04-12.yaml"
    path.write_text(text)
    config = apply_orbslam_settings(RunConfig(), read_orbslam_settings(path))
    with pytest.raises(CalibrationError, match=r"for 1241x376 images but the source's are 613x185: .*more than 10%"):
        fit_calibration_to_images(config, 613, 185)  # half the size
    with pytest.raises(CalibrationError, match=r"for 1241x376 images but the source's are 1226x180: .*principal point"):
        fit_calibration_to_images(config, 1226, 180)  # cy = 183.1 lies below the images


def test_a_principal_point_outside_the_images_is_refused():
    calibration = PinholeCalibration(700.0, 700.0, 1235.0, 183.0, 1241, 376, 0.5)
    with pytest.raises(CalibrationError, match=r"principal point \(1235, 183\) lies outside the 1226x370 images"):
        calibration.fitted_to(1226, 370)
    assert calibration.fitted_to(1241, 376) is calibration
    assert fit_calibration_to_images(RunConfig(), 1226, 370) == RunConfig()  # no override: nothing to fit


def test_strict_and_no_faults_from_the_command_line(tmp_path):
    import argparse

    from zenslam.service.commands import run as run_command

    path = tmp_path / "config.yaml"
    path.write_text("source:\n  faults:\n    - {kind: drop, first_frame: 3, last_frame: 4}\n")
    parser = argparse.ArgumentParser()
    run_command.register(parser.add_subparsers())
    plain = run_command.resolve_config(parser.parse_args(["run", "--config", str(path)]))
    assert plain.source.strict is False and [f.kind for f in plain.source.faults] == ["drop"]
    options = run_command.resolve_config(parser.parse_args(["run", "--config", str(path), "--strict", "--no-faults"]))
    assert options.source.strict is True and options.source.faults == ()


def test_the_map_section_sets_the_covisibility_threshold_of_both_stages(tmp_path):
    path = tmp_path / "config.yaml"
    path.write_text("map:\n  min_covisibility_weight: 20\n")
    config = load_run_config(path)
    expected = MapRulesConfig(min_covisibility_weight=20)
    assert config.map == config.frontend.tracking.local_map.map_rules == config.backend.local_mapping.map_rules == expected
    path.write_text(run_config_to_yaml(config))
    assert load_run_config(path) == config  # the resolved file, copies included, reads back
    assert with_map_rules(RunConfig(), expected) == config
    with pytest.raises(ConfigError, match=r"map.min_covisibility_weight=10 must be within 15..30"):
        MapRulesConfig(min_covisibility_weight=10)


def test_a_stage_copy_of_the_map_section_cannot_differ_from_it(tmp_path):
    path = tmp_path / "config.yaml"
    path.write_text(
        "map:\n  min_covisibility_weight: 20\n"
        "backend:\n  local_mapping:\n    map_rules:\n      min_covisibility_weight: 25\n"
    )
    with pytest.raises(ConfigError, match=r"backend.local_mapping.map_rules=.*differs from map"):
        load_run_config(path)
    backend = BackendConfig(local_mapping=LocalMappingConfig(map_rules=MapRulesConfig(min_covisibility_weight=25)))
    with pytest.raises(ConfigError, match=r"backend.local_mapping.map_rules=.*differs from map"):
        RunConfig(backend=backend)


@pytest.mark.parametrize(
    "earlier",
    [
        "frontend:\n  tracking:\n    local_map:\n      min_covisibility_weight: 22\n",
        "backend:\n  local_mapping:\n    min_covisibility_weight: 22\n",
        "frontend:\n  tracking:\n    local_map:\n      min_covisibility_weight: 22\n"
        "backend:\n  local_mapping:\n    min_covisibility_weight: 22\n",
    ],
)
def test_the_earlier_per_stage_covisibility_thresholds_move_to_the_map_section(tmp_path, caplog, earlier):
    path = tmp_path / "config.yaml"
    path.write_text(earlier)
    config = load_run_config(path)
    assert config.map.min_covisibility_weight == 22
    assert config.frontend.tracking.local_map.map_rules == config.backend.local_mapping.map_rules == config.map
    for old in ("frontend.tracking.local_map", "backend.local_mapping"):
        if old.split(".")[0] in earlier:
            assert f"{old}.min_covisibility_weight -> map.min_covisibility_weight" in caplog.text


@pytest.mark.parametrize(
    "earlier",
    [
        "frontend:\n  tracking:\n    local_map:\n      min_covisibility_weight: 20\n"
        "backend:\n  local_mapping:\n    min_covisibility_weight: 25\n",
        "map:\n  min_covisibility_weight: 20\nbackend:\n  local_mapping:\n    min_covisibility_weight: 25\n",
    ],
)
def test_earlier_covisibility_thresholds_that_disagree_are_refused(tmp_path, earlier):
    path = tmp_path / "config.yaml"
    path.write_text(earlier)
    with pytest.raises(ConfigError) as info:
        load_run_config(path)
    assert "=20" in str(info.value) and "backend.local_mapping.min_covisibility_weight=25" in str(info.value)
    assert "map.min_covisibility_weight alone" in str(info.value)


def test_the_frontend_recent_point_culling_keys_are_dropped(tmp_path, caplog):
    path = tmp_path / "config.yaml"
    path.write_text(
        "frontend:\n  tracking:\n    local_map:\n      best_covisible: 12\n      cull_recent_points: false\n"
        "      cull_min_found_ratio: 0.5\n      cull_min_keyframe_observations: 3\n      cull_window_keyframes: 4\n"
    )
    config = load_run_config(path)
    assert config.frontend.tracking.local_map.best_covisible == 12
    for key in ("cull_recent_points", "cull_min_found_ratio", "cull_min_keyframe_observations", "cull_window_keyframes"):
        assert f"frontend.tracking.local_map.{key}" in caplog.text
    assert "the backend culls them (backend.point_culling)" in caplog.text


def test_a_config_written_before_the_map_section_reads_through_the_upgrade(caplog):
    from pathlib import Path

    golden = Path(__file__).parent / "data" / "config_before_map_section.yaml"
    text = golden.read_text()
    config = load_run_config(golden)
    assert config.map == MapRulesConfig() and config.backend.local_mapping.map_rules == config.map
    assert "map.min_covisibility_weight" in caplog.text and "backend.point_culling" in caplog.text
    assert golden.read_text() == text  # read, never rewritten


def test_a_written_config_with_its_map_section_edited_loads_with_the_new_rules(tmp_path):
    """The run's config.yaml holds the stages' copies of ``map``; editing ``map`` alone in a copy of it works."""
    path = tmp_path / "config.yaml"
    path.write_text(run_config_to_yaml(RunConfig()).replace("min_covisibility_weight: 15", "min_covisibility_weight: 20", 1))
    config = load_run_config(path)
    assert config.map.min_covisibility_weight == 20
    assert config.frontend.tracking.local_map.map_rules.min_covisibility_weight == 20
    assert config.backend.local_mapping.map_rules.min_covisibility_weight == 20
