"""Source spec strings: good ones open the right reader, bad ones say what is accepted."""

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
