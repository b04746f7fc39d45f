"""Shared fixtures: where the benchmark clips live, skipping with a reason when they are absent; and how the
tests are spread over pytest-xdist workers.

Rules for tests (pyproject runs ``-n auto --dist loadgroup``, one worker per core):
- A test that takes more than ~10 s of CPU carries ``@pytest.mark.slow(seconds)`` (roughly how many,
  fixtures it brings included); slow tests start first, longest first.
- Tests that use a module-scoped fixture of their module, or a session-scoped fixture of a
  conftest.py below this one, run on one worker, so that the fixture runs once: make an expensive
  run that several tests check such a fixture, not a copy per test.
- Integration tests run in parallel with others: each uses its own hub endpoint
  (``bus.free_tcp_endpoint()``), run id and tmp_path, never fixed ports or shared output folders.
"""

from __future__ import annotations

import os
import warnings
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


# ---- scheduling over pytest-xdist workers (pyproject: -n auto --dist loadgroup --no-loadscope-reorder) ----


def _schedule_tier(item: pytest.Item) -> tuple[int, float]:
    """Slow tests first, longest first; then the other integration and dataset tests; then the rest."""
    slow = item.get_closest_marker("slow")
    if slow is not None:
        return 0, -float(slow.args[0])
    if item.get_closest_marker("integration") or item.get_closest_marker("dataset"):
        return 1, 0.0
    return 2, 0.0


def _shared_fixture_group(item: pytest.Item, root_baseid: str) -> str | None:
    """The xdist group of a test that shares an expensive fixture, so that the fixture runs once: the
    session-scoped fixtures of a conftest.py below this one (one group per conftest), else the
    module-scoped fixtures of a test module (one group per module)."""
    fixture_info = getattr(item, "_fixtureinfo", None)
    if fixture_info is None:
        return None
    fixtures = [defs[-1] for defs in fixture_info.name2fixturedefs.values() if defs]
    for fixture in fixtures:
        if fixture.scope == "session" and fixture.baseid not in ("", root_baseid):
            return fixture.baseid
    if any(fixture.scope == "module" for fixture in fixtures):
        return item.nodeid.split("::")[0]
    return None


@pytest.hookimpl(wrapper=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]):
    """Keep the tests that share an expensive fixture on one worker, and order the tests so that the
    longest start first, each on its own worker.

    xdist gives every worker one more unit of work as soon as fewer than three of its tests are
    pending, so the unit queued behind each worker's first slow test waits for it: a quick test
    goes there, not the next slow one.
    """
    try:
        root_baseid = Path(__file__).parent.relative_to(config.rootpath).as_posix()
    except ValueError:  # a rootdir that does not hold this folder: no conftest is below this one
        root_baseid = ""
    for item in items:
        group = _shared_fixture_group(item, root_baseid)
        if group is not None:
            item.add_marker(pytest.mark.xdist_group(group))
    result = yield  # the other hooks run here, xdist's (group names into node ids) among them
    if getattr(config.option, "loadgroup", False):
        ungrouped = [item.nodeid for item in items if item.get_closest_marker("xdist_group") and "@" not in item.nodeid]
        if ungrouped:
            warnings.warn(pytest.PytestWarning(
                f"pytest-xdist did not group {len(ungrouped)} test(s), e.g. {ungrouped[0]}: their shared fixtures "
                "run once per worker; see the pytest version pin in pyproject.toml"
            ))
    items.sort(key=_schedule_tier)  # stable: collection order within a tier
    workers = int(getattr(config, "workerinput", {}).get("workercount", 1))
    slow = [item for item in items if _schedule_tier(item)[0] == 0]
    quick = [item for item in items if _schedule_tier(item)[0] == 2 and not item.get_closest_marker("xdist_group")]
    if workers > 1 and len(slow) >= workers and len(quick) >= workers:
        fillers = {id(item) for item in quick[:workers]}
        rest = [item for item in items if id(item) not in fillers]
        items[:] = rest[:workers] + quick[:workers] + rest[workers:]
    return result
