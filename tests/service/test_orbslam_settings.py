"""ORB-SLAM settings files that cannot be read: a ConfigError naming the file (or the key) and what to do."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from zenslam.errors import ConfigError
from zenslam.service.run_config import read_orbslam_settings

GOOD = """\
%YAML:1.0
Camera.fx: 500.0
Camera.fy: 500.0
Camera.cx: 320.0
Camera.cy: 240.0
Camera.width: 640
Camera.height: 480
Camera.bf: 50.0
"""

WHAT_TO_DO = r"pass an ORB-SLAM2/3 settings file \(OpenCV YAML, starting with %YAML:1\.0\) to --orbslam-settings"


@pytest.mark.parametrize(
    "text, problem",
    [
        ("this is: [not an opencv yaml\n", r"is not an OpenCV YAML file \(line 1: Missing , between the elements\)"),
        ("plain words, no mapping\n", r"is not an OpenCV YAML file \(line 1: .*\)"),
        ("%YAML:1.0\nCamera.fx: [500.0, 1\n", r"is not an OpenCV YAML file \(line 2: .*\)"),
        ("", r"is empty"),
    ],
    ids=["unclosed-list", "not-a-mapping", "broken-on-line-2", "empty"],
)
def test_a_file_that_is_not_opencv_yaml_is_named(tmp_path: Path, text: str, problem: str):
    path = tmp_path / "settings.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=r"ORB-SLAM settings file .*settings\.yaml " + problem + "; " + WHAT_TO_DO):
        read_orbslam_settings(path)


def test_a_binary_file_is_named(tmp_path: Path):
    path = tmp_path / "settings.bin"
    path.write_bytes(b"\x00\x01\x02 not text")
    with pytest.raises(ConfigError, match=r"settings\.bin is not an OpenCV YAML file; " + WHAT_TO_DO):
        read_orbslam_settings(path)


def test_a_missing_file_or_a_folder_is_named(tmp_path: Path):
    with pytest.raises(ConfigError, match=r"nope\.yaml does not exist; " + WHAT_TO_DO):
        read_orbslam_settings(tmp_path / "nope.yaml")
    with pytest.raises(ConfigError, match=r"is not a file; " + WHAT_TO_DO):
        read_orbslam_settings(tmp_path)


@pytest.mark.parametrize(
    "line, problem",
    [
        ("Camera.fx: five hundred", r"Camera\.fx is 'five hundred'; it must be a number"),
        ("Camera.width: [640, 480]", r"Camera\.width is a list; give a number or an !!opencv-matrix"),
        ("LEFT.P: {rows: 3}", r"LEFT\.P is a mapping but not an !!opencv-matrix"),
        ("ORBextractor.nFeatures: many", r"ORBextractor\.nFeatures is 'many'; it must be a number"),
    ],
    ids=["string-focal", "list-width", "map-not-matrix", "string-orb"],
)
def test_a_value_of_the_wrong_kind_names_its_key(tmp_path: Path, line: str, problem: str):
    key = line.partition(":")[0]
    kept = [row for row in GOOD.splitlines() if not row.startswith(key + ":")]
    path = tmp_path / "settings.yaml"
    path.write_text("\n".join([*kept, line]) + "\n")
    with pytest.raises(ConfigError, match=r"settings\.yaml: " + problem):
        read_orbslam_settings(path)


def test_a_good_file_still_reads(tmp_path: Path):
    path = tmp_path / "settings.yaml"
    path.write_text(GOOD)
    calibration = read_orbslam_settings(path).calibration
    assert (calibration.fx, calibration.width, calibration.baseline_m) == (500.0, 640, pytest.approx(0.1))


def test_run_with_a_bad_settings_file_exits_with_one_line_and_no_traceback(tmp_path: Path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("this is: [not an opencv yaml\n")
    command = [sys.executable, "-m", "zenslam.service.cli", "run", "--orbslam-settings", str(bad),
               "--output", str(tmp_path / "out"), "--no-progress"]
    result = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert result.returncode == 2, result.stderr  # the CLI's exit code for a ZenslamError such as ConfigError
    assert "Traceback" not in result.stderr and "SystemError" not in result.stderr, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ERROR zenslam: ORB-SLAM settings file ") and str(bad) in lines[0]
    assert not (tmp_path / "out").exists()  # refused before any process started or any output was written
