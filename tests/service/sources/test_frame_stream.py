"""The source process's frame stream: bad frames (unreadable, corrupt, stamps out of order, dropped) become SkippedFrame."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from zenslam.errors import DatasetError, FrameReadError, TimestampError
from zenslam.schemas.sensor_data import SensorFrame
from zenslam.service.sources.faults import FaultInjector, FrameFault
from zenslam.service.sources.frame_stream import SkippedFrame, frame_stream, stamp_problem
from zenslam.service.sources.images import write_png
from zenslam.service.sources.kitti import KittiSource


class _Stamps:
    """A source whose frames carry the given stamps."""

    name = "stamps"

    def __init__(self, stamps: list[int]):
        self.stamps = stamps

    def __len__(self) -> int:
        return len(self.stamps)

    def frame(self, index: int) -> SensorFrame:
        return SensorFrame(index, self.stamps[index], np.zeros((4, 6), np.uint8))


def make_kitti(root: Path, n: int) -> Path:
    """A fake KITTI sequence <root>/sequences/07 of n random 20x32 stereo pairs at 10 Hz."""
    seq = root / "sequences" / "07"
    rng = np.random.default_rng(7)
    for folder in ("image_0", "image_1"):
        for i in range(n):
            write_png(seq / folder / f"{i:06d}.png", rng.integers(0, 255, size=(20, 32), dtype=np.uint8))
    (seq / "calib.txt").write_text("P0: 700 0 16 0 0 700 10 0 0 0 1 0\nP1: 700 0 16 -350 0 700 10 0 0 0 1 0\n")
    (seq / "times.txt").write_text("".join(f"{0.1 * i:e}\n" for i in range(n)))
    return seq


def _summary(items) -> list[str | int]:
    return [item.index if isinstance(item, SensorFrame) else f"{item.index}:{item.reason}" for item in items]


def test_stamp_problem_tells_a_repeat_from_a_step_back():
    assert stamp_problem(5, 101, 4, 100) is None
    repeat = stamp_problem(5, 100, 4, 100)
    assert repeat.reason == "stamp_repeat" and isinstance(repeat.error, TimestampError)
    assert "frame 5: stamp 100 ns repeats the stamp of frame 4 (100 ns)" in str(repeat.error)
    back = stamp_problem(5, 98_000_000, 3, 100_000_000)
    assert back.reason == "stamp_backwards"
    assert "frame 5: stamp 98000000 ns is 2.000 ms before the stamp of frame 3" in str(back.error)


def test_stamps_are_checked_against_the_last_frame_passed_on():
    # 3 repeats 2; 4 goes back before 2; 5 is after 2 but before the skipped 4's stamp: it passes.
    items = list(frame_stream(_Stamps([10, 20, 30, 30, 25, 35, 40])))
    assert _summary(items) == [0, 1, 2, "3:stamp_repeat", "4:stamp_backwards", 5, 6]


def test_real_dataset_stamps_pass_untouched():
    assert _summary(frame_stream(_Stamps([0, 1, 2, 3]))) == [0, 1, 2, 3]


def test_injected_faults_become_skips_with_their_reasons():
    injector = FaultInjector((FrameFault("drop", 1, 1), FrameFault("corrupt", 3, 3), FrameFault("stamp_repeat", 5, 6),
                              FrameFault("stamp_backwards", 8, 8), FrameFault("black", 9, 9)))  # fmt: skip
    items = list(frame_stream(_Stamps(list(range(0, 110, 10))), injector))
    assert _summary(items) == [0, "1:drop", 2, "3:corrupt", 4, "5:stamp_repeat", "6:stamp_repeat", 7,
                               "8:stamp_backwards", 9, 10]  # fmt: skip
    drop = items[1]
    assert "frame 1: dropped by source.faults {kind: drop, first_frame: 1, last_frame: 1}" in str(drop.error)
    assert not items[9].left.any()  # black is sent


def test_a_corrupt_file_is_skipped_and_the_frames_after_it_are_read(tmp_path: Path):
    seq = make_kitti(tmp_path, n=5)
    bad = seq / "image_1" / "000002.png"
    bad.write_bytes(bad.read_bytes()[:40])  # truncated
    source = KittiSource(seq)
    (seq / "image_0" / "000003.png").unlink()  # gone while the source plays
    items = list(frame_stream(source))
    assert _summary(items) == [0, 1, "2:corrupt", "3:missing", 4]
    corrupt = items[2].error
    assert isinstance(corrupt, FrameReadError) and corrupt.frame_index == 2 and corrupt.path == str(bad)
    assert str(corrupt).startswith(f"frame 2: image {bad} could not be decoded")


def test_reader_frames_are_random_access_and_bounded(tmp_path: Path):
    source = KittiSource(make_kitti(tmp_path, n=3))
    assert source.frame(2).index == 2 and source.frame(0).index == 0
    with pytest.raises(DatasetError, match=r"kitti/07 has no frame 3: it has 3 frames, numbered 0 to 2"):
        source.frame(3)
    with pytest.raises(DatasetError, match="has no frame -1"):
        source.frame(-1)
