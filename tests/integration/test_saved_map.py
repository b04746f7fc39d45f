"""Saved maps end to end: ``zenslam run --save-map``, then runs that start from the map (localisation mode and
mapping on), and the runs a map refuses at start-up. The first two runs are the guide's commands
(on fewer frames), and its snippet (docs/maps.md) reads the map."""

from __future__ import annotations

import json
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from zenslam.backend.config import BackendConfig
from zenslam.backend.map_file import read_header
from zenslam.runtime.rerun_config import RerunConfig
from zenslam.service.run_config import RecorderConfig, RunConfig, run_config_to_yaml
from zenslam.vocabulary import load_vocabulary, save_vocabulary

pytestmark = pytest.mark.integration

MAP_FRAMES = 30  # frames of the synthetic loop mapped
LOCALISE_FRAMES = 15  # frames tracked in the map
REPO_ROOT = Path(__file__).resolve().parents[2]


def _readme_maps() -> tuple[list[list[str]], str]:
    """The guide's saved-map commands (each a ``zenslam run`` argument list) and its Python snippet (docs/maps.md)."""
    text = (REPO_ROOT / "docs" / "maps.md").read_text()
    commands = re.search(r"<!-- docs-command: maps -->\s*```sh\n(.+?)\n```", text, re.S)
    snippet = re.search(r"To read one\nelsewhere:\n\n```python\n(.+?)\n```", text, re.S)
    assert commands and snippet, "docs/maps.md lost its saved-map commands or snippet"
    lines = [shlex.split(line) for line in commands.group(1).splitlines()]
    assert all(line[:2] == ["zenslam", "run"] for line in lines)
    return [line[2:] for line in lines], snippet.group(1)


def _run(tmp: Path, run_id: str, *options: str, source: str = "synthetic", ok: bool = True) -> subprocess.CompletedProcess:
    config = tmp / "config.yaml"
    if not config.exists():  # rerun and the recorder off: the runs are checked by their metrics and maps
        config.write_text(run_config_to_yaml(RunConfig(rerun=RerunConfig(enabled=False), recorder=RecorderConfig(enabled=False))))
    command = [sys.executable, "-m", "zenslam.service.cli", "run", *([source] if source else []), "--lockstep",
               "--config", str(config), "--output", str(tmp), "--run-id", run_id, "--no-progress", *options]  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, timeout=600, cwd=tmp)
    if ok:
        assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-3000:]
    return result


def _metrics(tmp: Path, run_id: str) -> dict:
    return json.loads((tmp / run_id / "metrics.json").read_text())


def _poses(path: Path) -> list[str]:
    return [line for line in path.read_text().splitlines() if line and not line.startswith("#")]


@pytest.fixture(scope="module")
def saved_map(tmp_path_factory) -> tuple[Path, Path]:
    tmp = tmp_path_factory.mktemp("saved-map")
    (save, _), _ = _readme_maps()
    _run(tmp, "mapping", *save, "--max-frames", str(MAP_FRAMES), source="")
    return tmp, tmp / "recordings" / "loop.zmap"


@pytest.mark.slow(25)
def test_a_localisation_run_relocalises_at_once_and_adds_nothing(saved_map, monkeypatch):
    tmp, path = saved_map
    header = read_header(path)
    mapping = _metrics(tmp, "mapping")
    assert header.counts["keyframes"] >= 2 and header.counts["keyframes"] <= mapping["keyframes"]["sent"]
    _, snippet = _readme_maps()
    _run(tmp, "localising", "--max-frames", str(LOCALISE_FRAMES), "--map", str(path), "--localization", source="synthetic:loop")
    metrics = _metrics(tmp, "localising")
    assert metrics["keyframes"] == {"sent": 0, "processed": 0}
    assert metrics["relocalisation"]["count"] >= 1
    assert metrics["lost_frames"] <= 2 and metrics["tracked_ok"] == LOCALISE_FRAMES - metrics["lost_frames"]
    assert metrics["ate"]["rmse_m"] < 0.02
    assert _poses(tmp / "localising" / "keyframes.tum") == []  # the map's keyframes are not this run's
    config = (tmp / "localising" / "config.yaml").read_text()
    assert "localization: true" in config and "start_in_map: true" in config
    assert f"keyframe_id_start: {header.next_keyframe_id}" in config
    names: dict = {}
    monkeypatch.chdir(tmp)
    exec(compile(snippet, "docs/maps.md", "exec"), names)  # noqa: S102 - the guide's own snippet, run where it says
    assert names["header"]["format"] == "zenslam-map" and names["poses"].shape == (header.counts["keyframes"], 4, 4)
    assert names["points"].shape == (header.counts["points"], 3)

def test_the_readme_localisation_command_adds_no_keyframe(saved_map):
    """The guide's second command, on a few frames: the figure-eight starts where this short map of
    the loop's first 1.5 s does not reach (the full loop's map does, benchmarks/saved_maps.md), so it may
    stay lost; it never makes a keyframe."""
    tmp, _ = saved_map
    (_, localise), _ = _readme_maps()
    _run(tmp, "readme-localising", *localise, "--max-frames", "4", source="")
    metrics = _metrics(tmp, "readme-localising")
    assert metrics["frames"] == 4 and metrics["keyframes"] == {"sent": 0, "processed": 0}
    assert metrics["initializing_frames"] == 0  # no new map is started: lost until it relocalises


@pytest.mark.slow(25)
def test_a_mapping_run_continues_the_map_with_ids_of_its_own(saved_map):
    tmp, path = saved_map
    header = read_header(path)
    _run(tmp, "continuing", "--max-frames", str(LOCALISE_FRAMES), "--map", str(path), "--save-map", "longer.zmap")
    metrics = _metrics(tmp, "continuing")
    assert metrics["relocalisation"]["count"] >= 1 and metrics["lost_frames"] <= 2
    assert metrics["keyframes"]["processed"] == metrics["keyframes"]["sent"]
    longer = read_header(tmp / "longer.zmap")
    assert longer.next_keyframe_id == header.next_keyframe_id + metrics["keyframes"]["sent"]
    assert longer.counts["keyframes"] >= header.counts["keyframes"] - 2  # old keyframes stay (a few may be culled)
    assert longer.next_frontend_point_id >= header.next_frontend_point_id
    assert longer.vocabulary_id == header.vocabulary_id and longer.calibration == header.calibration


def test_a_map_is_refused_by_another_camera_and_another_vocabulary(saved_map):
    tmp, path = saved_map
    header = read_header(path)
    result = _run(tmp, "other-camera", "--max-frames", "3", "--map", str(path), "--sensor", "rgbd", ok=False)
    assert result.returncode == 2
    assert "made with a stereo camera" in result.stderr and "this run's is a rgbd camera" in result.stderr
    vocabulary = load_vocabulary(None)
    other = save_vocabulary(vocabulary.with_weights(vocabulary.word_weights * 2.0), tmp / "other.npz")
    config = tmp / "other-vocabulary.yaml"
    config.write_text(run_config_to_yaml(RunConfig(backend=BackendConfig(vocabulary=str(other)))))
    command = [sys.executable, "-m", "zenslam.service.cli", "run", "synthetic", "--config", str(config), "--max-frames", "3",
               "--output", str(tmp), "--run-id", "other-vocabulary", "--no-progress", "--map", str(path)]  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, timeout=300, cwd=tmp)
    assert result.returncode == 2
    assert header.vocabulary_id in result.stderr and load_vocabulary(other).content_id in result.stderr
    assert not (tmp / "other-vocabulary" / "metrics.json").exists()  # refused before any stage started
