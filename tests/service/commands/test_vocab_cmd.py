"""``zenslam vocab``: train from a source, describe the file, score two images; errors name the file."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import pytest

from zenslam.service.cli import main
from zenslam.service.sources import open_source


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    output = tmp_path_factory.mktemp("vocab") / "sub" / "loop.txt.gz"
    assert main(["vocab", "train", "synthetic:loop", "--max-frames-per-source", "3", "--depth", "3",
                 "--output", str(output)]) == 0
    return output


def test_train_writes_dbow2_text_that_info_describes(trained: Path, capsys):
    assert trained.is_file()
    assert main(["vocab", "info", str(trained)]) == 0
    out = capsys.readouterr().out
    assert re.search(r"^k: +10$", out, re.MULTILINE) and re.search(r"^L: +3$", out, re.MULTILINE)
    assert re.search(r"^words: +\d+", out, re.MULTILINE) and "tf-idf" in out and "L1-norm" in out


def test_score_of_an_image_with_itself_is_one_and_with_another_less(trained: Path, tmp_path: Path, capsys):
    frame = open_source("synthetic:still").frame(0)
    left, right = tmp_path / "left.png", tmp_path / "right.png"
    cv2.imwrite(str(left), frame.left)
    cv2.imwrite(str(right), frame.right)
    assert main(["vocab", "score", str(left), str(left), "--vocabulary", str(trained)]) == 0
    assert re.search(r"^score: 1\.0000$", capsys.readouterr().out, re.MULTILINE)
    assert main(["vocab", "score", str(left), str(right), "--vocabulary", str(trained)]) == 0
    score = float(re.search(r"^score: (\S+)$", capsys.readouterr().out, re.MULTILINE).group(1))
    assert 0.0 < score < 1.0


def test_a_missing_vocabulary_or_a_wrong_output_name_fails_naming_it(tmp_path: Path, caplog):
    missing = tmp_path / "ORBvoc.txt"
    assert main(["vocab", "info", str(missing)]) == 2
    assert f"vocabulary {missing} does not exist" in caplog.text
    assert main(["vocab", "train", "synthetic:still", "--output", str(tmp_path / "voc.bin")]) == 2
    assert "end the name in .npz" in caplog.text
