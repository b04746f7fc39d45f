"""A corrupt image mid-stream on the real KITTI clip: ``zenslam run`` skips that frame and tracks the rest;
``--strict`` stops at it instead, naming it.

The clip is copied to a temporary folder as symlinks to the shared files, except the left image of
frame 10, which is a truncated copy (half its bytes, as an interrupted download leaves it).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.dataset, pytest.mark.integration]

BAD_FRAME = 10
CLIP_FRAMES = 51
# Relative: skipping one frame of 51 must not change the accuracy by more than 15%. Any one frame
# missing moves this clip's ATE by -6% to +22% (frames 5, 10, 20, 30 or 40 dropped;
# benchmarks/late_map_updates.md), the tracking's chaos rather than the skip's handling: frame 10 happens to
# be within 10% at the default settings, but any change to tracking or mapping draws again.
ATE_TOLERANCE = 0.15
# Rerun logging and the recorder are off: these runs are about the source, and they take long enough.
CONFIG = "rerun: {enabled: false}\nrecorder: {enabled: false}\n"


def _link_tree(source: Path, target: Path) -> None:
    """``target`` mirrors ``source``: folders made, every file a symlink to the original."""
    for path in source.rglob("*"):
        copy = target / path.relative_to(source)
        if path.is_dir():
            copy.mkdir(parents=True, exist_ok=True)
        else:
            copy.parent.mkdir(parents=True, exist_ok=True)
            copy.symlink_to(path)


@pytest.fixture(scope="module")
def bad_clip(kitti_root: Path, tmp_path_factory) -> Path:
    """The KITTI clip with the left image of frame 10 truncated; returns its sequence folder."""
    root = tmp_path_factory.mktemp("kitti_bad_frame")
    _link_tree(kitti_root, root)
    bad = root / "sequences" / "06" / "image_0" / f"{BAD_FRAME:06d}.png"
    data = bad.resolve().read_bytes()
    bad.unlink()
    bad.write_bytes(data[: len(data) // 2])
    return root / "sequences" / "06"


def _run(sequence: Path, output: Path, run_id: str, *options: str) -> subprocess.CompletedProcess:
    config = output / f"{run_id}.yaml"
    config.write_text(CONFIG)
    command = [sys.executable, "-m", "zenslam.service.cli", "run", f"kitti:{sequence}", "--config", str(config),
               "--output", str(output), "--run-id", run_id, "--no-progress", *options]  # fmt: skip
    return subprocess.run(command, capture_output=True, text=True, timeout=1800)


def _metrics(result: subprocess.CompletedProcess, run_dir: Path) -> dict:
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-3000:]
    return json.loads((run_dir / "metrics.json").read_text())


@pytest.mark.slow(20)
def test_a_truncated_frame_is_skipped_and_the_run_keeps_its_accuracy(kitti_lockstep_run: Path, bad_clip: Path, tmp_path: Path):
    bad = _metrics(_run(bad_clip, tmp_path, "bad"), tmp_path / "bad")
    clean = json.loads((kitti_lockstep_run / "metrics.json").read_text())  # the whole clip (conftest.py), lockstep too
    assert bad["run"]["completed"] is True
    assert bad["skipped_frames"] == {"total": 1, "reasons": {"corrupt": 1}}
    assert bad["frames"] == CLIP_FRAMES - 1 and bad["tracked_ok"] == CLIP_FRAMES - 1
    assert clean["skipped_frames"] == {"total": 0, "reasons": {}} and clean["tracked_ok"] == CLIP_FRAMES
    ate_bad, ate_clean = bad["ate"]["rmse_m"], clean["ate"]["rmse_m"]
    assert abs(ate_bad - ate_clean) <= ATE_TOLERANCE * ate_clean, f"ATE {ate_bad:.4f} m with frame 10 skipped, {ate_clean:.4f} m clean"
    warnings = [line for line in (tmp_path / "bad" / "logs" / "source.log").read_text().splitlines() if "skipping frame" in line]
    assert len(warnings) == 1
    assert f"skipping frame {BAD_FRAME}: image {bad_clip / 'image_0' / '000010.png'} could not be decoded" in warnings[0]


def test_strict_fails_at_the_truncated_frame_naming_it(bad_clip: Path, tmp_path: Path):
    result = _run(bad_clip, tmp_path, "strict", "--strict")
    assert result.returncode == 2
    assert f"frame {BAD_FRAME}: image {bad_clip / 'image_0' / '000010.png'} could not be decoded" in result.stderr
    metrics = json.loads((tmp_path / "strict" / "metrics.json").read_text())  # what was tracked is still written
    assert metrics["run"]["completed"] is False
    assert [(f["stage"], f.get("exit_code")) for f in metrics["run"]["failures"]] == [("source", 2)]
    assert metrics["tracked_ok"] == BAD_FRAME
