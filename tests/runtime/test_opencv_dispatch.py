"""The frontend runs OpenCV's own dispatch (cpu_kernels.OPENCV_DISPATCH_FREE_STAGES): every OpenCV call it
makes gives the same bits on the SSE3 baseline path as on the path OpenCV picks for this CPU."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from pathlib import Path

import pytest

from zenslam.runtime import cpu_kernels
from zenslam.runtime.supervisor import stage_environment
from zenslam.service.stages import STAGE_MODULES

# A child's view: digests of what the frontend asks of OpenCV, on textured images and (when present)
# KITTI and EuRoC frames: whole ORB extractions (pyramid, FAST, borders, the descriptor kernel),
# brute-force Hamming distances, EPnP poses (relocalisation's hypotheses), and the dispatch in force.
_CHILD = """
import hashlib, json, sys
from pathlib import Path
import cv2
import numpy as np
from zenslam.frontend.orb_extractor import OrbConfig, OrbExtractor
from zenslam.frontend import pnp_ransac
root = Path(sys.argv[1])
rng = np.random.default_rng(11)
images = [cv2.GaussianBlur(rng.integers(0, 256, (480, 640), dtype=np.uint8), (0, 0), s) for s in (0.8, 1.5)]
for folder in ("kitti_odometry/sequences/06/image_0", "kitti_odometry/sequences/06/image_1", "euroc/V1_01_easy_micro/mav0/cam0/data", "euroc/V1_01_easy_micro/mav0/cam1/data"):
    images += [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted((root / folder).glob("*.png"))[::10][:4]]
extractor = OrbExtractor(OrbConfig(threads=1))
features = hashlib.sha256()
descriptors = []
for image in images:
    f, _ = extractor.extract(image)
    for name in ("px", "level", "angle_deg", "response", "descriptors"):
        features.update(getattr(f, name).tobytes())
    descriptors.append(f.descriptors)
distances = hashlib.sha256()
for a, b in zip(descriptors, descriptors[1:]):
    for result in cv2.batchDistance(a, b, cv2.CV_32S, normType=cv2.NORM_HAMMING, K=2):  # as feature_matcher asks
        distances.update(result.tobytes())
K = np.array([[707.0, 0.0, 601.9], [0.0, 707.0, 183.1], [0.0, 0.0, 1.0]])
poses = hashlib.sha256()
for i in range(600):
    n = 4 if i % 2 else int(rng.integers(10, 200))
    p_world = rng.uniform([-10.0, -3.0, 3.0], [10.0, 3.0, 40.0], (n, 3))
    px = (p_world @ K.T)[:, :2] / p_world[:, 2:3] + rng.normal(0.0, 1.0, (n, 2))
    T = pnp_ransac._epnp(p_world, px, K)
    poses.update(b"none" if T is None else T.tobytes())
print(json.dumps({
    "images": len(images),
    "features": features.hexdigest(), "distances": distances.hexdigest(), "poses": poses.hexdigest(),
    "dispatched": [f for f in cv2.getCPUFeaturesLine().split() if f.startswith("*") and not f.endswith("?")],
}))
"""

_DATA = Path(os.environ.get("ZENSLAM_DATA") or Path(__file__).resolve().parents[2].parent / "shared" / "data")


def _child(env: dict[str, str]) -> dict:
    result = subprocess.run([sys.executable, "-c", _CHILD, str(_DATA)], env=env, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    return json.loads(result.stdout)


@pytest.mark.slow(20)
def test_the_frontends_opencv_calls_give_the_same_bits_on_the_baseline_path():
    """With every other pin in force, as the frontend runs (numpy's, OpenBLAS's and libm's choices change
    results of their own)."""
    machine = {k: v for k, v in os.environ.items() if k not in cpu_kernels.kernel_pins({})}
    own = _child(cpu_kernels.with_pinned_kernels(machine, opencv=False))
    baseline = _child(cpu_kernels.with_pinned_kernels(machine))
    assert own["dispatched"] and not baseline["dispatched"]  # OpenCV's own choice, and the pinned baseline
    targets = cpu_kernels.opencv_dispatch_targets()
    if not targets:
        pytest.skip("this OpenCV build dispatches to no CPU feature beyond its baseline: nothing to compare")
    assert own["images"] == baseline["images"] >= 2
    for key in ("features", "distances", "poses"):
        assert own[key] == baseline[key], key


@pytest.mark.skipif(platform.machine().lower() not in cpu_kernels.X86_64_MACHINES, reason="the pins name x86-64 code paths")
def test_only_the_frontend_runs_opencvs_own_dispatch():
    if not cpu_kernels.opencv_dispatch_targets():
        pytest.skip("this OpenCV build dispatches to no CPU feature beyond its baseline")
    for role, module in STAGE_MODULES.items():
        env = stage_environment({}, module)
        assert ("OPENCV_CPU_DISABLE" in env) == (role != "frontend"), role
    assert stage_environment({"OPENCV_CPU_DISABLE": "AVX2"}, STAGE_MODULES["frontend"])["OPENCV_CPU_DISABLE"] == "AVX2"
