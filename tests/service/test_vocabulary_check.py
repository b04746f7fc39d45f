"""A run's vocabulary files are read before any stage starts: a missing or corrupt one ends ``zenslam run``
at once, with an error naming the setting and the file, and no process started."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from zenslam.errors import VocabularyError
from zenslam.runtime.supervisor import Supervisor
from zenslam.service.cli import main
from zenslam.service.run_config import load_run_config
from zenslam.service.vocabulary_check import check_vocabularies, vocabulary_settings
from zenslam.vocabulary import default_vocabulary_path


def _config(tmp_path: Path, sections: dict) -> Path:
    path = tmp_path / "run.yaml"
    path.write_text(yaml.safe_dump(sections))
    return path


@pytest.fixture
def truncated(tmp_path: Path) -> Path:
    """The shipped vocabulary cut short, as an interrupted download leaves it."""
    path = tmp_path / "truncated.npz"
    path.write_bytes(default_vocabulary_path().read_bytes()[:4096])
    return path


def test_the_shipped_vocabulary_is_not_read_again_and_a_named_one_is(tmp_path: Path):
    assert vocabulary_settings(load_run_config(None)) == {}
    named = str(default_vocabulary_path())
    config = load_run_config(_config(tmp_path, {"backend": {"vocabulary": named}, "frontend": {"vocabulary": named}}))
    assert vocabulary_settings(config) == {"backend.vocabulary": named, "frontend.vocabulary": named}
    check_vocabularies(config)  # a good file passes


def test_the_frontends_vocabulary_is_checked_only_when_it_relocalises(tmp_path: Path):
    sections = {"frontend": {"vocabulary": str(tmp_path / "none.npz"), "tracking": {"relocalisation": {"enabled": False}}}}
    config = load_run_config(_config(tmp_path, sections))
    assert vocabulary_settings(config) == {}
    check_vocabularies(config)


@pytest.mark.parametrize("setting", ["backend", "frontend"])
def test_a_missing_file_names_the_setting_and_the_file(tmp_path: Path, setting: str):
    missing = tmp_path / "ORBvoc.txt"
    config = load_run_config(_config(tmp_path, {setting: {"vocabulary": str(missing)}}))
    with pytest.raises(VocabularyError, match=rf"^{setting}\.vocabulary: vocabulary {missing} does not exist"):
        check_vocabularies(config)


def test_a_corrupt_file_names_the_setting_the_file_and_what_to_do(tmp_path: Path, truncated: Path):
    config = load_run_config(_config(tmp_path, {"backend": {"vocabulary": str(truncated)}}))
    with pytest.raises(VocabularyError, match=rf"^backend\.vocabulary: vocabulary {truncated}: .*truncated or corrupt; get a complete copy"):
        check_vocabularies(config)


def test_zenslam_run_with_a_bad_vocabulary_fails_before_any_process_starts(tmp_path: Path, truncated: Path, caplog, monkeypatch):
    started: list[object] = []
    monkeypatch.setattr(Supervisor, "start", lambda self, spec: started.append(spec))
    config = _config(tmp_path, {"backend": {"vocabulary": str(truncated)}})
    output = tmp_path / "recordings"
    code = main(["run", "synthetic", "--config", str(config), "--output", str(output), "--max-frames", "3", "--no-progress"])
    assert code == 2  # as for any other configuration error
    assert f"backend.vocabulary: vocabulary {truncated}" in caplog.text and "get a complete copy" in caplog.text
    assert started == [] and not output.exists()  # no stage started, no run folder made
