"""``zenslam publish synthetic`` and ``zenslam run zenoh:...`` side by side, as two separate commands.

The publisher listens on a free loopback port and the run connects to it (``--listen``/``--connect``;
by default both use tcp/127.0.0.1:7447). The publisher plays at 0.3 times the recorded rate, so
tracking keeps up on a busy machine; the run ends when the publisher's
liveliness token goes, and is scored against the scene's ground truth given with ``--ground-truth``.
"""

from __future__ import annotations

import json
import subprocess
import sys
from importlib import metadata

import pytest

from zenslam.runtime import bus

pytestmark = pytest.mark.integration

FRAMES = 20


@pytest.mark.slow(10)
@pytest.mark.parametrize("fmt", ["foxglove", "ros2"])
def test_every_published_frame_is_tracked(tmp_path, fmt):
    endpoint = bus.free_tcp_endpoint()
    zenslam = [sys.executable, "-m", "zenslam.service.cli"]
    if fmt == "ros2":  # a ROS 2 camera driver on rmw_zenoh, read by the ros2: source
        target, spec = ["--ros2", "/it"], "ros2:/it"
    else:
        target, spec = ["--key", f"cam/it-{fmt}", "--format", fmt], f"zenoh:cam/it-{fmt}"
    publish = [*zenslam, "publish", "synthetic", *target, "--max-frames", str(FRAMES), "--rate", "0.3", "--listen", endpoint]
    run = [*zenslam, "run", spec, "--connect", endpoint, "--ground-truth", "synthetic", "--output", str(tmp_path),
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
    # Every frame published is accounted for: tracked, or dropped (counted) because tracking was busy,
    # which on a loaded machine can happen to a frame that arrives while the first one is tracked.
    assert metrics["skipped_frames"]["total"] == 0
    assert metrics["frames"] + metrics["dropped_frames"]["total"] == FRAMES
    assert metrics["tracked_ok"] == metrics["frames"] >= FRAMES - 2
    assert metrics["run"]["completed"] and metrics["run"]["mode"] == "pipelined"
    assert metrics["run"]["environment"]["libraries"]["gtsam"] == metadata.version("gtsam")
    assert metrics["ate"]["rmse_m"] < 0.02  # the synthetic loop's frames, scored against its ground truth
