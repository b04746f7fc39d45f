"""Source spec strings: good ones open the right reader, bad ones say what is accepted."""

import numpy as np
import pytest

from zenslam.errors import SourceSpecError
from zenslam.service.sources import open_source


@pytest.mark.parametrize(
    "spec, fragment",
    [
        ("bogus:/data", "unknown source 'bogus:/data'"),
        ("kitti:", "needs a path after 'kitti:'"),
        ("synthetic:moon", "unknown synthetic scene 'moon'"),
        ("synthetic:loop/lidar", "unknown synthetic sensor 'lidar'"),
    ],
)
def test_bad_specs_name_the_problem(spec, fragment):
    with pytest.raises(SourceSpecError, match=fragment):
        open_source(spec)


def test_synthetic_default_is_the_stereo_loop():
    source = open_source("synthetic")
    assert source.sensor == "stereo"
    assert "loop" in source.name


def test_synthetic_sensor_suffix():
    assert open_source("synthetic:still/rgbd").sensor == "rgbd"


def test_a_synthetic_scene_takes_more_laps_of_its_own_length():
    one = open_source("synthetic:figure_eight")
    many = open_source("synthetic:figure_eight/rgbd,laps=5")
    assert many.config.laps == 5 and many.sensor == "rgbd"
    lap_s = one.config.duration_s / one.config.laps
    assert many.config.duration_s == pytest.approx(5 * lap_s)
    assert len(many) == 5 * (len(one) - 1) // one.config.laps + 1


def test_a_synthetic_scene_takes_another_seed():
    """``seed=N`` draws other textures and noise on the same path (a check of luck against system)."""
    default, other = open_source("synthetic:loop"), open_source("synthetic:loop,laps=2,seed=3")
    assert (default.config.seed, other.config.seed, other.config.laps) == (0, 3, 2)
    assert np.array_equal(default.ground_truth().T_world_cam[1], other.ground_truth().T_world_cam[1])
    assert not np.array_equal(default.frame(1).left, other.frame(1).left)


@pytest.mark.parametrize(
    ("spec", "problem"),
    [
        ("synthetic:loop,laps=0", "laps=N"), ("synthetic:loop,speed=2", "laps=N"), ("synthetic:loop,seed=-1", "seed=N"),
        ("synthetic:still,laps=2", "has no laps"),
    ],
)
def test_bad_synthetic_options_are_named(spec, problem):
    with pytest.raises(SourceSpecError, match=problem):
        open_source(spec)
