"""The default vocabulary shipped in the package, and the issue's measure on the EuRoC revisits clip."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from zenslam.frontend.config import FrontendConfig
from zenslam.frontend.orb_extractor import OrbExtractor
from zenslam.service.sources.images import read_grey
from zenslam.vocabulary import default_vocabulary_path, load_vocabulary
from zenslam.vocabulary.files import DEFAULT_VOCABULARY


@pytest.fixture(scope="module")
def vocabulary():
    return load_vocabulary(None)


def test_default_vocabulary_is_shipped_small_and_documented(vocabulary):
    path = default_vocabulary_path()
    assert path.stat().st_size <= 15e6
    assert (vocabulary.branching, vocabulary.depth) == (10, 5)
    assert 50_000 < vocabulary.n_words <= 10**5
    assert "synthetic:figure_eight (seed 7)" in vocabulary.metadata["corpus"]
    assert vocabulary.metadata["command"].startswith("zenslam vocab train ")
    assert (path.parent / "README.md").is_file()


@pytest.mark.dataset
def test_euroc_revisits_rank_the_revisited_place_first(vocabulary, data_root: Path):
    """Frame 0 revisits the place of frame 1 (98 s later), frame 3 that of frame 2: each scores best among the four."""
    folder = data_root / "euroc" / "V1_01_easy_revisits"
    if not folder.is_dir():
        pytest.skip(f"EuRoC revisits clip not found at {folder}")
    extractor = OrbExtractor(FrontendConfig().orb)
    bows = [vocabulary.transform(extractor.extract(read_grey(folder / f"left_img_{i}.png"))[0].descriptors)[0]
            for i in range(4)]
    scores = np.array([[vocabulary.score(a, b) for b in bows] for a in bows])
    for query, revisit in ((0, 1), (2, 3)):
        others = [i for i in range(4) if i != query]
        assert max(others, key=lambda i: scores[query, i]) == revisit, scores


def test_the_wheel_ships_the_default_vocabulary():
    """pyproject's package data names the default vocabulary (``pip wheel .`` then holds it)."""
    import fnmatch
    import tomllib

    repo = Path(__file__).resolve().parents[2]
    patterns = tomllib.loads((repo / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["zenslam.vocabulary"]
    assert any(fnmatch.fnmatch(f"data/{DEFAULT_VOCABULARY}", pattern) for pattern in patterns)
    assert (repo / "zenslam" / "vocabulary" / "data" / DEFAULT_VOCABULARY).is_file()
