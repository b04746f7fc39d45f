"""Shared fixtures: where the benchmark clips live, skipping with a reason when they are absent."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]


def shared_data_root() -> Path:
    """``$ZENSLAM_DATA`` if set, else ``../shared/data`` beside the checkout."""
    env = os.environ.get("ZENSLAM_DATA")
    return Path(env) if env else REPO_ROOT.parent / "shared" / "data"


@pytest.fixture(scope="session")
def data_root() -> Path:
    root = shared_data_root()
    if not root.is_dir():
        pytest.skip(f"benchmark clips not found at {root}; set ZENSLAM_DATA or place them at ../shared/data")
    return root


@pytest.fixture(scope="session")
def kitti_root(data_root: Path) -> Path:
    path = data_root / "kitti_odometry"
    if not path.is_dir():
        pytest.skip(f"KITTI clip not found at {path}")
    return path


@pytest.fixture(scope="session")
def euroc_micro(data_root: Path) -> Path:
    path = data_root / "euroc" / "V1_01_easy_micro"
    if not path.is_dir():
        pytest.skip(f"EuRoC clip not found at {path}")
    return path
