"""The guide's client example (docs/client.md) is true: its microservice receives every pose of a real ``zenslam run``."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from test_docs import command_env, doc_block, doc_command


@pytest.mark.integration
@pytest.mark.slow(20)  # a 30-frame run and the client
def test_readme_pose_logger_receives_every_pose_of_the_run(tmp_path: Path):
    (tmp_path / "pose_logger.py").write_text(doc_block("python", "pose_logger.py") + "\n")
    command = doc_command("client")
    result = subprocess.run(["bash", "-c", command], cwd=tmp_path, capture_output=True, text=True, timeout=600, env=command_env())
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    tum = (tmp_path / "recordings" / "demo" / "trajectory.tum").read_text().splitlines()[1:]
    run_stamps_ns = [round(float(line.split()[0]) * 1e9) for line in tum]
    received_ns = [int(line.split()[1]) for line in result.stdout.splitlines() if line.startswith("pose ")]
    assert len(run_stamps_ns) >= 25  # the run tracked its frames (the synthetic loop tracks all 30)
    assert received_ns == run_stamps_ns, "the client did not receive exactly the run's poses, in order"
    assert f"received {len(tum)} poses of 30 frames" in result.stdout
