"""Replay as a regression test: the committed golden recording, and a fresh KITTI run, replay identically.

The golden (recordings/golden/synthetic_loop: 101 lockstep frames of the synthetic loop scene, two
5 Hz laps of a short lap at 192x144, with a loop closed on the second lap and a global BA) guards
behaviour: any change in what the frontend or backend publish fails here. When a change is
intended, regenerate it with ``python scripts/regenerate_golden.py`` and commit it with the change.
It was made on another machine: the stage processes pin their math kernels
(zenslam.runtime.cpu_kernels), so it replays bit for bit whatever kernels the machine, or the
environment of the replay command, would pick.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import pytest

from zenslam.runtime import cpu_kernels
from zenslam.schemas import codec
from zenslam.schemas.map_update import MapUpdate
from zenslam.service import backend_replay, replay
from zenslam.service.evaluation.loop_acceptance import loop_error
from zenslam.service.sources.mcap_source import McapSource

pytestmark = pytest.mark.integration

REPO_ROOT = Path(__file__).resolve().parents[2]
GOLDEN = REPO_ROOT / "recordings" / "golden" / "synthetic_loop" / "run.mcap"
REGENERATE = "if the change is intended, run `python scripts/regenerate_golden.py` and commit the new golden with it"
MAX_GOLDEN_BYTES = 20_000_000  # most of it: the map updates of 50 keyframes, a loop correction and a global BA


# The replay command's own kernel choice: the machine's (no kernel variables set), or another one
# forced on it (Nehalem's OpenBLAS kernels run on any CPU numpy runs on).
KERNEL_CHOICES = {"machine": {}, "forced": {"OPENBLAS_CORETYPE": "Nehalem"}}


def _zenslam(*args: str, cwd: Path, kernels: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "zenslam.service.cli", *args]
    env = None
    if kernels is not None:
        pinned = set(cpu_kernels.kernel_pins({})) - {"GLIBC_TUNABLES"}
        env = {**{k: v for k, v in os.environ.items() if k not in pinned}, **kernels}
    return subprocess.run(command, capture_output=True, text=True, timeout=900, cwd=cwd, env=env)


def _verdict(result: subprocess.CompletedProcess) -> str:
    """The line after the run's own summary: "identical" or "first difference: ..."."""
    lines = result.stdout.splitlines()
    return next((line for line in lines if line == "identical" or line.startswith("first difference")), "")


def test_the_golden_is_a_small_lockstep_recording():
    assert GOLDEN.is_file(), f"{GOLDEN} is missing; run `python scripts/regenerate_golden.py`"
    assert GOLDEN.stat().st_size < MAX_GOLDEN_BYTES
    config = replay.recorded_run_config(GOLDEN)
    assert config.mode == "lockstep"
    assert len(McapSource(GOLDEN)) == 101
    streams = replay.read_topics(GOLDEN, replay.COMPARED_TOPICS)
    assert len(streams[replay.POSE_TOPIC]) == 101 and len(streams[replay.KEYFRAME_TOPIC]) >= 1 + 3  # keyframes and the end


def test_the_golden_closes_a_true_loop_and_corrects_the_map():
    """The replays below cover loop closing: the golden holds an accepted loop, right by its ground
    truth, and the correction it published."""
    streams = replay.read_topics(GOLDEN, (replay.LOOP_TOPIC, replay.MAP_UPDATE_TOPIC))
    loops = [codec.decode_loop(m.data) for m in streams[replay.LOOP_TOPIC]]
    accepted = [loop for loop in loops if loop.accepted]
    assert accepted, f"no accepted loop among {len(loops)} verified candidates; {REGENERATE}"
    truth = McapSource(GOLDEN).ground_truth()
    for loop in accepted:
        translation_m, rotation_deg = loop_error(loop, truth)
        assert translation_m < 0.05 and rotation_deg < 1.0, (loop.keyframe_id, loop.loop_keyframe_id, translation_m, rotation_deg)
    updates = [codec.decode_map_update(m.data) for m in streams[replay.MAP_UPDATE_TOPIC]]
    corrections = [u for u in updates if isinstance(u, MapUpdate) and u.kind == "correction"]
    assert len(corrections) >= len(accepted)
    assert sum(u.corrections_following for u in updates if isinstance(u, MapUpdate)) == len(corrections)


@pytest.mark.parametrize("kernels", KERNEL_CHOICES.values(), ids=KERNEL_CHOICES)
def test_golden_replays_identically_through_the_whole_pipeline(tmp_path, kernels):
    result = _zenslam(
        "replay", str(GOLDEN), "--output", str(tmp_path), "--run-id", "golden-replay", "--no-progress", cwd=tmp_path, kernels=kernels
    )
    assert result.returncode == 0 and _verdict(result) == "identical", (
        f"{_verdict(result) or result.stderr[-3000:]}\n{result.stdout[-2000:]}\n{REGENERATE}"
    )
    assert (tmp_path / "golden-replay" / "run.mcap").is_file()


# The forced kernels through the backend alone: CI runs it after the README's command (the whole
# pipeline's replay under forced kernels, in that command, covers the backend's outputs too).
@pytest.mark.parametrize(
    "kernels", [pytest.param(KERNEL_CHOICES["machine"], id="machine"), pytest.param(KERNEL_CHOICES["forced"], id="forced", marks=pytest.mark.extended)]
)
def test_golden_replays_identically_through_the_backend_alone(tmp_path, kernels):
    result = _zenslam("replay", str(GOLDEN), "--stage", "backend", cwd=tmp_path, kernels=kernels)
    assert result.returncode == 0 and _verdict(result) == "identical", (
        f"{_verdict(result) or result.stderr[-3000:]}\n{result.stdout[-2000:]}\n{REGENERATE}"
    )
    counts = next(line for line in result.stdout.splitlines() if line.startswith(f"  {replay.MAP_UPDATE_TOPIC}: "))
    recorded, replayed = (int(word) for word in counts.split() if word.isdigit())
    assert recorded == replayed >= 1 + 3


@pytest.fixture
def kitti_recording(kitti_lockstep_run: Path) -> Path:
    """A fresh lockstep run of the KITTI 06 clip (conftest.py; rerun off: replay compares the MCAP only)."""
    return kitti_lockstep_run / "run.mcap"


@pytest.mark.slow(50)  # with the recording it replays
@pytest.mark.dataset
def test_a_kitti_run_replays_identically_through_the_whole_pipeline(kitti_recording, tmp_path):
    result = _zenslam("replay", str(kitti_recording), "--output", str(tmp_path), "--run-id", "again", "--no-progress", cwd=tmp_path)
    assert result.returncode == 0 and _verdict(result) == "identical", result.stdout[-2000:] + result.stderr[-3000:]
    assert "  /frontend/pose: 51 recorded, 51 replayed" in result.stdout


@pytest.mark.extended  # CI runs it after the README's command; the whole-pipeline replay above covers the backend
@pytest.mark.dataset
def test_a_kitti_run_replays_identically_through_the_backend_alone(kitti_recording, tmp_path):
    result = _zenslam("replay", str(kitti_recording), "--stage", "backend", cwd=tmp_path)
    assert result.returncode == 0 and _verdict(result) == "identical", result.stdout[-2000:] + result.stderr[-3000:]


def test_a_behaviour_change_in_the_backend_is_caught():
    """The guard works: one robust local-BA iteration fewer changes the map updates, and the report says where."""
    backend = replay.recorded_run_config(GOLDEN).backend
    local_ba = backend.local_ba
    changed = dataclasses.replace(backend, local_ba=dataclasses.replace(local_ba, robust_iterations=local_ba.robust_iterations - 1))
    comparison = backend_replay.replay_backend(GOLDEN, changed)
    assert not comparison.equivalent
    assert comparison.difference.topic == replay.MAP_UPDATE_TOPIC and comparison.difference.field
