"""``zenslam publish synthetic`` and ``zenslam run zenoh:...`` side by side, as two separate commands.

The publisher listens on a free loopback port and the run connects to it (``--listen``/``--connect``;
by default both use tcp/127.0.0.1:7447). The publisher plays at a tenth of the recorded rate, so
tracking keeps up on a busy machine and every frame is tracked; the run ends when the publisher's
liveliness token goes, and is scored against the scene's ground truth given with ``--ground-truth``.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from zenslam.runtime import bus

pytestmark = pytest.mark.integration

FRAMES = 20


@pytest.mark.slow(25)
@pytest.mark.parametrize("fmt", ["foxglove"])
def test_every_published_frame_is_tracked(tmp_path, fmt):
    endpoint = bus.free_tcp_endpoint()
    key = f"cam/it-{fmt}"
    zenslam = [sys.executable, "-m", "zenslam.service.cli"]
    publish = [*zenslam, "publish", "synthetic", "--key", key, "--max-frames", str(FRAMES), "--rate", "0.1",
               "--format", fmt, "--listen", endpoint]  # fmt: skip
    run = [*zenslam, "run", f"zenoh:{key}", "--connect", endpoint, "--ground-truth", "synthetic", "--output", str(tmp_path),
           "--run-id", "bus", "--no-progress"]  # fmt: skip
    publisher = subprocess.Popen(publish, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        result = subprocess.run(run, capture_output=True, text=True, timeout=600)
        published, published_err = publisher.communicate(timeout=60)
    finally:
        publisher.kill()
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-3000:]
    assert publisher.returncode == 0, published_err[-3000:]
    assert f"published {FRAMES} frames" in published
    metrics = json.loads((tmp_path / "bus" / "metrics.json").read_text())
    assert metrics["frames"] == FRAMES and metrics["tracked_ok"] == FRAMES
    assert metrics["dropped_frames"]["total"] == 0 and metrics["skipped_frames"]["total"] == 0
    assert metrics["run"]["completed"] and metrics["run"]["mode"] == "pipelined"
    assert metrics["ate"]["rmse_m"] < 0.02  # the synthetic loop's frames, scored against its ground truth
