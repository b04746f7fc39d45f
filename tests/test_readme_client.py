"""The README's client example is true: its microservice receives every pose of a real ``zenslam run``."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]


def readme_block(marker: str, language: str) -> str:
    """The fenced ``language`` block right after ``<!-- marker -->`` in the README."""
    text = (REPO_ROOT / "README.md").read_text()
    match = re.search(rf"<!-- {re.escape(marker)} -->\s*```{language}\n(.+?)\n```", text, re.S)
    assert match, f"README has no {language} block marked {marker!r}"
    return match.group(1)


@pytest.mark.integration
@pytest.mark.slow(20)  # a 30-frame run and the client
def test_readme_pose_logger_receives_every_pose_of_the_run(tmp_path: Path):
    (tmp_path / "pose_logger.py").write_text(readme_block("readme-python: pose_logger.py", "python") + "\n")
    command = readme_block("readme-command: client", "sh").strip()
    bin_dir = Path(sys.executable).parent
    result = subprocess.run(
        ["bash", "-c", command], cwd=tmp_path, capture_output=True, text=True, timeout=600,
        env={"PATH": f"{bin_dir}:/usr/local/bin:/usr/bin:/bin", "HOME": str(Path.home())},
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    tum = (tmp_path / "recordings" / "demo" / "trajectory.tum").read_text().splitlines()[1:]
    run_stamps_ns = [round(float(line.split()[0]) * 1e9) for line in tum]
    received_ns = [int(line.split()[1]) for line in result.stdout.splitlines() if line.startswith("pose ")]
    assert len(run_stamps_ns) >= 25  # the run tracked its frames (the synthetic loop tracks all 30)
    assert received_ns == run_stamps_ns, "the client did not receive exactly the run's poses, in order"
    assert f"received {len(tum)} poses of 30 frames" in result.stdout
