"""The README's commands are true: CI runs its test command, its main command works on a fresh clone, and its
tour and the guide's vocabulary commands run line by line."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from test_docs import command_lines, run_line, scratch_checkout

REPO_ROOT = Path(__file__).resolve().parents[1]


def readme_command(name: str) -> str:
    """The README's own shell block named ``name`` (the two commands must be the README's, not the guide's)."""
    text = (REPO_ROOT / "README.md").read_text()
    match = re.search(rf"<!-- readme-command: {name} -->\s*```sh\n(.+?)\n```", text, re.S)
    assert match, f"README has no command marked {name!r}"
    return match.group(1).strip()


def test_readme_opens_with_the_main_and_test_commands():
    text = (REPO_ROOT / "README.md").read_text()
    first_blocks = re.findall(r"```sh\n(.+?)\n```", text, re.S)[:2]
    assert first_blocks == [readme_command("main"), readme_command("test")]
    assert "zenslam run" in readme_command("main")
    assert "pytest" in readme_command("test")
    assert readme_command("tour").startswith("zenslam inspect")  # the tour stays on the front page


def test_ci_runs_exactly_the_readme_test_command():
    """.ci/run extracts the marked block from the README; check its extraction gives the same line."""
    script = (REPO_ROOT / ".ci" / "run").read_text()
    awk = re.search(r"test_command=\$\(awk '(.+?)' README.md\)", script)
    assert awk, ".ci/run no longer extracts the README's test command"
    out = subprocess.run(["awk", awk.group(1), "README.md"], cwd=REPO_ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == readme_command("test")


@pytest.mark.slow(160)  # a fresh venv, pip install and the whole synthetic loop
@pytest.mark.skipif(shutil.which("git") is None, reason="git is needed to make a fresh clone")
def test_main_command_on_a_fresh_clone(tmp_path: Path):
    """A new user's first command: clone, install into a new venv, run SLAM on the synthetic scene."""
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO_ROOT, capture_output=True, text=True)
    if head.returncode != 0:
        pytest.skip("not inside a git checkout with commits; nothing to clone")
    clone = tmp_path / "zenslam"
    subprocess.run(["git", "clone", "--quiet", str(REPO_ROOT), str(clone)], check=True)
    result = subprocess.run(
        ["bash", "-c", readme_command("main")], cwd=clone, capture_output=True, text=True, timeout=1800,
        env={"PATH": f"{Path(sys.executable).parent}:/usr/local/bin:/usr/bin:/bin", "HOME": str(Path.home())},
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert re.search(r"ATE", result.stdout), result.stdout[-3000:]
    runs = list((clone / "recordings").glob("*/metrics.json"))
    assert len(runs) == 1, f"expected one run folder with metrics.json, found {runs}"


@pytest.mark.extended  # the longest test (the KITTI clip run three ways, replayed, exported, ...): CI runs it
@pytest.mark.slow(70)
def test_tour_commands_run_in_order(tmp_path: Path, data_root: Path, kitti_root: Path):
    """Every line of the README's tour (it uses the KITTI clip), run from a checkout whose ../shared/data is the real one."""
    checkout = scratch_checkout(tmp_path, data_root)
    for line in command_lines("tour"):
        result = run_line(line, checkout)
        if line.startswith("zenslam run "):
            assert "ATE RMSE" in result.stdout, result.stdout[-2000:]
        if line.startswith("zenslam replay"):
            assert "identical" in result.stdout
    assert (checkout / "recordings" / "kitti06" / "eval" / "metrics.json").is_file()
    assert (checkout / "recordings" / "kitti06" / "export" / "points.ply").is_file()
    assert (checkout / "recordings" / "loop_tum" / "metrics.json").is_file()


@pytest.mark.slow(30)  # ORB on 40 frames and a k=10, L=5 tree
def test_vocab_commands_run_in_order(tmp_path: Path, data_root: Path):
    """Every line of the guide's vocabulary commands (docs/vocabulary.md), run from a checkout whose ../shared/data is
    the real one."""
    if not (data_root / "euroc" / "V1_01_easy_revisits").is_dir() or not (data_root / "kitti_odometry").is_dir():
        pytest.skip(f"the EuRoC revisits and KITTI clips are not both in {data_root}")
    checkout = scratch_checkout(tmp_path, data_root)
    for line in command_lines("vocab"):
        result = run_line(line, checkout)
        if line.startswith("zenslam vocab score"):
            assert re.search(r"^score: 0\.\d{4}$", result.stdout, re.MULTILINE), result.stdout
        if line.startswith("zenslam vocab info"):
            assert re.search(r"^k: +10$", result.stdout, re.MULTILINE), result.stdout
            assert re.search(r"^L: +5$", result.stdout, re.MULTILINE), result.stdout
    assert (checkout / "recordings" / "vocab" / "small.txt.gz").is_file()
