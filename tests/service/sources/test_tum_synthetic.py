"""A TUM RGB-D fixture written from synthetic renders reads back exactly (depth to the format's 0.2 mm)."""

import itertools

import numpy as np

from zenslam.service.cli import main
from zenslam.service.sources import open_source
from zenslam.service.sources.tum import TumSource


def test_synthetic_renders_round_trip_through_tum_layout(tmp_path):
    assert main(["generate", "synthetic:loop", str(tmp_path / "seq"), "--frames", "4"]) == 0
    rendered = list(itertools.islice(open_source("synthetic:loop/rgbd"), 4))
    source = TumSource(tmp_path / "seq")
    read = list(source)

    assert source.sensor == "rgbd"
    assert len(read) == 4
    truth = open_source("synthetic:loop/rgbd")
    assert source.calibration == truth.calibration
    for original, back in zip(rendered, read):
        assert back.stamp_ns == original.stamp_ns  # synthetic stamps are whole microseconds
        np.testing.assert_array_equal(back.left, original.left)
        valid = original.depth_m > 0
        np.testing.assert_array_equal(back.depth_m > 0, valid)
        assert np.max(np.abs(back.depth_m[valid] - original.depth_m[valid])) <= 0.5 / 5000 + 1e-6
    gt_back = source.ground_truth()
    gt = truth.ground_truth()
    np.testing.assert_array_equal(gt_back.stamps_ns, gt.stamps_ns)
    np.testing.assert_allclose(gt_back.T_world_cam, gt.T_world_cam, atol=1e-6)


def test_generate_refuses_a_dataset(tmp_path, caplog):
    assert main(["generate", "kitti:/data", str(tmp_path / "x")]) == 2
    assert "built-in scenes only" in caplog.text
