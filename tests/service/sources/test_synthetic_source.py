"""SyntheticSource as a Source: configuration, presets, stamps, calibration per sensor, ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from zenslam.errors import ConfigError
from zenslam.config import from_mapping, to_mapping
from zenslam.service.sources.synthetic import (
    SCENE_NAMES,
    PhotometricConfig,
    SceneConfig,
    SyntheticSource,
    scene_config,
)
from zenslam.service.sources.synthetic.scene import build_scene


def test_presets_and_defaults() -> None:
    assert set(SCENE_NAMES) == {"loop", "figure_eight", "still", "corridor", "corridor_aliased"}
    loop = scene_config("loop")
    assert loop.texture.default and loop.world == "room"
    assert (loop.width, loop.height, loop.fx, loop.cx, loop.cy) == (640, 480, 460.0, 319.5, 239.5)
    assert (loop.frame_rate_hz, loop.duration_s, loop.baseline_m, loop.imu_rate_hz) == (10.0, 30.0, 0.10, 200.0)
    assert not loop.photometric.enabled
    assert scene_config("figure_eight").laps >= 2
    assert scene_config("still", sensor="rgbd").sensor == "rgbd"


def test_config_round_trips_through_a_mapping_and_rejects_bad_keys() -> None:
    config = scene_config("figure_eight", seed=4, photometric=PhotometricConfig(noise_sigma=2.0))
    assert from_mapping(SceneConfig, to_mapping(config)) == config
    with pytest.raises(ConfigError, match="unknown key"):
        scene_config("loop", colour=True)
    with pytest.raises(ConfigError, match="sensor"):
        scene_config("loop", sensor="lidar")
    with pytest.raises(ConfigError, match="unknown synthetic scene"):
        scene_config("spiral")
    with pytest.raises(ConfigError, match="duration_s"):
        scene_config("loop", duration_s=-1.0)
    with pytest.raises(ConfigError, match="gain_amplitude"):
        scene_config("loop", photometric={"gain_amplitude": 1.5})


@pytest.mark.parametrize("sensor, baseline", [("mono", None), ("stereo", 0.1), ("rgbd", 0.1)])
def test_calibration_and_frame_contents_per_sensor(sensor: str, baseline: float | None) -> None:
    config = scene_config(
        "still", sensor=sensor, duration_s=0.1, width=64, height=48, fx=46.0, fy=46.0, cx=31.5, cy=23.5, texels_per_m=32.0
    )
    source = SyntheticSource(config)
    assert source.name == "synthetic:still" and source.sensor == sensor
    assert source.calibration.baseline_m == baseline
    assert source.calibration.K[0, 0] == 46.0
    frame = next(iter(source))
    assert frame.left.shape == (48, 64) and frame.left.dtype == np.uint8
    assert (frame.right is not None) == (sensor == "stereo")
    assert (frame.depth_m is not None) == (sensor == "rgbd")


def test_stamps_ground_truth_and_length() -> None:
    source = SyntheticSource(scene_config("loop", start_stamp_ns=1_000_000_000))
    stamps = source.stamps_ns()
    assert len(source) == len(stamps) == 301  # 30 s at 10 Hz, both ends included
    assert stamps[0] == 1_000_000_000 and np.all(np.diff(stamps) == 100_000_000)
    gt = source.ground_truth()
    np.testing.assert_array_equal(gt.stamps_ns, stamps)
    np.testing.assert_allclose(gt.T_world_cam[-1], gt.T_world_cam[0], atol=1e-9)
    assert gt.path_length_m() == pytest.approx(12.9, abs=0.5)  # ellipse perimeter ~12.8 m plus height changes
    assert source.imu().stamps_ns[0] == 1_000_000_000
    with pytest.raises(ConfigError, match="out of range"):
        source.frame(301)


def test_a_scene_built_for_other_settings_is_refused() -> None:
    scene = build_scene(seed=1, texels_per_m=16.0, tile_m=4.0)
    with pytest.raises(ConfigError, match="seed=1"):
        SyntheticSource(scene_config("loop", texels_per_m=16.0, tile_m=4.0), scene=scene)
    SyntheticSource(scene_config("loop", seed=1, texels_per_m=16.0, tile_m=4.0), scene=scene)
