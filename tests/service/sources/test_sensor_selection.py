"""Playing a source as another sensor: stereo/RGB-D datasets as mono, refusals naming what a source gives."""

import numpy as np
import pytest

from zenslam.errors import ConfigError, SourceSpecError
from zenslam.service.sources import open_source
from zenslam.service.sources.config import SourceConfig
from zenslam.service.sources.sensor_selection import as_sensor


def test_kitti_as_mono_gives_left_images_without_baseline(kitti_root):
    stereo = open_source(f"kitti:{kitti_root}/sequences/06")
    mono = open_source(f"kitti:{kitti_root}/sequences/06", "mono")
    assert mono.sensor == "mono"
    assert mono.calibration.baseline_m is None
    assert (mono.calibration.fx, mono.calibration.width) == (stereo.calibration.fx, stereo.calibration.width)
    frame, own = mono.frame(3), stereo.frame(3)
    assert frame.right is None and frame.depth_m is None
    np.testing.assert_array_equal(frame.left, own.left)
    assert frame.stamp_ns == own.stamp_ns
    assert len(mono) == len(stereo)
    np.testing.assert_array_equal(mono.stamps_ns(), stereo.stamps_ns())
    assert mono.ground_truth() is not None
    assert [f.index for f in mono][:3] == [0, 1, 2]


def test_kitti_cannot_be_rgbd(kitti_root):
    with pytest.raises(SourceSpecError, match=r"stereo source and cannot be played as rgbd: choose --sensor stereo or mono"):
        open_source(f"kitti:{kitti_root}/sequences/06", "rgbd")


def test_own_sensor_is_the_source_itself():
    source = open_source("synthetic:still")
    assert as_sensor(source, "stereo") is source


def test_rgbd_scene_as_mono_drops_depth():
    mono = as_sensor(open_source("synthetic:still/rgbd"), "mono")
    frame = mono.frame(0)
    assert frame.depth_m is None and frame.left.shape == (mono.calibration.height, mono.calibration.width)
    with pytest.raises(SourceSpecError, match="rgbd source and cannot be played as stereo"):
        as_sensor(open_source("synthetic:still/rgbd"), "stereo")


def test_synthetic_scene_renders_the_chosen_sensor():
    assert open_source("synthetic:still/stereo", "rgbd").sensor == "rgbd"
    mono = open_source("synthetic:still", "mono")
    assert mono.sensor == "mono" and mono.calibration.baseline_m is None


def test_config_refuses_an_unknown_sensor():
    with pytest.raises(ConfigError, match="source.sensor='lidar'"):
        SourceConfig(sensor="lidar")  # type: ignore[arg-type]
