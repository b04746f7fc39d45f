"""Fault injection (source.faults): what each kind does to the frames read, and how entries are validated."""

from __future__ import annotations

import numpy as np
import pytest

from zenslam.errors import ConfigError, FrameReadError
from zenslam.schemas.sensor_data import SensorFrame
from zenslam.config import from_mapping
from zenslam.service.run_config import RunConfig, SourceConfig, load_run_config, run_config_to_yaml
from zenslam.service.sources.faults import FaultInjector, FrameFault, check_faults

PERIOD_NS = 100_000_000


class _Source:
    """A stereo source of n frames with non-zero images, counting the frames actually read."""

    name = "fake"

    def __init__(self, n: int = 8):
        self.n = n
        self.reads: list[int] = []

    def __len__(self) -> int:
        return self.n

    def frame(self, index: int) -> SensorFrame:
        self.reads.append(index)
        image = np.full((4, 6), 100 + index, np.uint8)
        return SensorFrame(index, 1_000_000_000 + index * PERIOD_NS, image, right=image + 1, depth_m=np.ones((4, 6), np.float32))


def _read_all(faults: list[FrameFault], n: int = 8) -> tuple[list[SensorFrame | None | str], _Source]:
    source, injector, out = _Source(n), FaultInjector(tuple(faults)), []
    for index in range(n):
        try:
            out.append(injector.read(source, index))
        except FrameReadError as exc:
            out.append(f"error:{exc.reason}:{exc.frame_index}")
    return out, source


def test_no_fault_passes_frames_through_untouched():
    frames, source = _read_all([])
    assert [f.index for f in frames] == list(range(8))
    assert [f.stamp_ns for f in frames] == [1_000_000_000 + i * PERIOD_NS for i in range(8)]
    assert source.reads == list(range(8))


def test_black_replaces_both_images_and_keeps_depth_and_stamp():
    frames, _ = _read_all([FrameFault("black", 2, 3)])
    for i in (2, 3):
        assert frames[i].left.shape == (4, 6) and frames[i].left.dtype == np.uint8 and not frames[i].left.any()
        assert not frames[i].right.any()
        np.testing.assert_array_equal(frames[i].depth_m, 1.0)
        assert frames[i].stamp_ns == 1_000_000_000 + i * PERIOD_NS
    assert frames[1].left.all() and frames[4].left.all()


def test_drop_never_reads_the_frame():
    frames, source = _read_all([FrameFault("drop", 3, 5)])
    assert [f is None for f in frames] == [False, False, False, True, True, True, False, False]
    assert source.reads == [0, 1, 2, 6, 7]


def test_corrupt_raises_a_frame_read_error_without_reading():
    frames, source = _read_all([FrameFault("corrupt", 4, 4)])
    assert frames[4] == "error:corrupt:4"
    assert 4 not in source.reads and frames[5].index == 5


def test_stamp_repeat_repeats_the_previous_stamp_over_the_whole_range():
    frames, _ = _read_all([FrameFault("stamp_repeat", 2, 4)])
    stamps = [f.stamp_ns for f in frames]
    s1 = 1_000_000_000 + PERIOD_NS
    assert stamps[1:5] == [s1, s1, s1, s1]
    assert stamps[5] == 1_000_000_000 + 5 * PERIOD_NS


def test_stamp_backwards_keeps_going_back_by_the_frame_interval():
    frames, _ = _read_all([FrameFault("stamp_backwards", 3, 4)])
    stamps = [f.stamp_ns for f in frames]
    s2 = 1_000_000_000 + 2 * PERIOD_NS
    assert stamps[3] == s2 - PERIOD_NS and stamps[4] == s2 - 2 * PERIOD_NS
    assert stamps[5] == 1_000_000_000 + 5 * PERIOD_NS


def test_a_stamp_fault_after_a_drop_refers_to_the_last_frame_read():
    frames, _ = _read_all([FrameFault("drop", 2, 2), FrameFault("stamp_repeat", 3, 3)])
    assert frames[2] is None and frames[3].stamp_ns == frames[1].stamp_ns


def test_faults_beyond_the_source_are_reported():
    injector = FaultInjector((FrameFault("drop", 2, 3), FrameFault("black", 8, 20)))
    assert injector.beyond(8) == [FrameFault("black", 8, 20)]
    assert injector.beyond(30) == []


@pytest.mark.parametrize(
    "entry, message",
    [
        ({"kind": "blur", "first_frame": 1, "last_frame": 2}, r"'source\.faults\[0\]\.kind'='blur' must be one of \['black', 'drop'"),
        ({"kind": "drop", "first_frame": 5, "last_frame": 3}, r"\{kind: drop, first_frame: 5, last_frame: 3\}: last_frame 3 is before"),
        ({"kind": "drop", "first_frame": -1, "last_frame": 3}, r"first_frame=-1 must be a frame index >= 0"),
        ({"kind": "stamp_repeat", "first_frame": 0, "last_frame": 2}, r"stamp_repeat fault needs a previous frame's stamp"),
        ({"kind": "drop", "first_frame": 1}, r"missing required key 'source\.faults\[0\]\.last_frame'"),
        ({"kind": "drop", "first_frame": 1, "last_frame": 2, "every": 3}, r"unknown key\(s\) \['every'\]"),
    ],
)
def test_invalid_entries_name_the_entry_and_what_is_allowed(entry, message):
    with pytest.raises(ConfigError, match=message):
        from_mapping(RunConfig, {"source": {"faults": [entry]}})


def test_overlapping_entries_are_named_both():
    faults = (FrameFault("black", 6, 9), FrameFault("drop", 0, 2), FrameFault("drop", 5, 7))
    with pytest.raises(ConfigError, match=r"source\.faults\[2\] \{kind: drop, first_frame: 5, last_frame: 7\} and "
                       r"source\.faults\[0\] \{kind: black, first_frame: 6, last_frame: 9\} both cover frame 6"):
        SourceConfig(faults=faults)


def test_adjacent_entries_are_fine_and_the_config_round_trips(tmp_path):
    faults = (FrameFault("drop", 2, 4), FrameFault("black", 5, 9))
    check_faults(faults)
    config = RunConfig(source=SourceConfig(faults=faults, strict=True))
    path = tmp_path / "config.yaml"
    path.write_text(run_config_to_yaml(config))
    assert load_run_config(path) == config


def test_the_readme_example_is_a_valid_config():
    import re
    from pathlib import Path

    import yaml

    readme = (Path(__file__).resolve().parents[3] / "docs" / "sources.md").read_text()
    block = next(b for b in re.findall(r"```yaml\n(.+?)\n```", readme, re.S) if "faults:" in b)
    config = from_mapping(RunConfig, yaml.safe_load(block))
    assert [f.kind for f in config.source.faults] == ["black", "drop", "corrupt", "stamp_backwards", "stamp_repeat"]
