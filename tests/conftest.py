"""Shared fixtures: where the benchmark clips live, skipping with a reason when they are absent; and how the
tests are spread over pytest-xdist workers.

Rules for tests (pyproject runs ``-n auto --dist loadgroup``, one worker per core):
- A test that takes more than ~10 s of CPU carries ``@pytest.mark.slow(seconds)``: roughly how many
  CPU seconds it and the processes it starts use, fixtures it brings included (not its wall time on
  a busy machine: the numbers only order the tests against each other). Slow tests start first,
  longest first.
- Tests that use a module-scoped fixture of their module, or a session-scoped fixture of a
  conftest.py below this one, run on one worker, so that the fixture runs once: make an expensive
  run that several tests check such a fixture, not a copy per test (a run that tests in several
  modules check goes in the folder's conftest.py, as tests/integration/conftest.py does).
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


def _shared_fixtures(item: pytest.Item, root_baseid: str) -> tuple[list[str], bool]:
    """(the session-scoped fixtures of a conftest.py below this one that ``item`` uses, whether it uses a
    module-scoped fixture of its module)."""
    fixture_info = getattr(item, "_fixtureinfo", None)
    if fixture_info is None:
        return [], False
    fixtures = [defs[-1] for defs in fixture_info.name2fixturedefs.values() if defs]
    shared = sorted(f"{f.baseid}::{f.argname}" for f in fixtures if f.scope == "session" and f.baseid not in ("", root_baseid))
    return shared, any(f.scope == "module" for f in fixtures)


def _group_tests_that_share_fixtures(items: list[pytest.Item], root_baseid: str) -> None:
    """Mark the tests that share an expensive fixture with one xdist group, so that it runs once: tests
    that use session-scoped fixtures of a conftest.py below this one, linked through the fixtures they
    use (a test using two joins their groups); else the tests of a module that use a module-scoped
    fixture of it."""
    uses = {id(item): _shared_fixtures(item, root_baseid) for item in items}
    parent: dict[str, str] = {}

    def root(name: str) -> str:
        while parent.setdefault(name, name) != name:
            name = parent[name]
        return name

    for shared, _ in uses.values():
        for a, b in zip(shared, shared[1:]):
            first, second = sorted((root(a), root(b)))
            parent[second] = first
    for item in items:
        shared, module_fixture = uses[id(item)]
        if shared:
            item.add_marker(pytest.mark.xdist_group(root(shared[0])))
        elif module_fixture:
            item.add_marker(pytest.mark.xdist_group(item.nodeid.split("::")[0]))


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
    _group_tests_that_share_fixtures(items, root_baseid)
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


def pytest_configure(config: pytest.Config) -> None:
    """Compile (or load) the frontend's numba kernels once, in the controlling process, before any
    worker starts: on a fresh clone the compile takes tens of seconds, and two workers' stage
    processes compiling the same kernels at once would spend that time inside their start timeouts."""
    if hasattr(config, "workerinput"):
        return  # a pytest-xdist worker: the controller has filled the cache
    from zenslam.frontend.kernel_warm_up import warm_up_kernels

    warm_up_kernels()
