"""Compiled kernels: the same bits from numba's generic x86-64 build as from the machine's own, and a second start loads them from the cache."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from pathlib import Path

import pytest


# A child's view: a digest of the ORB features of a textured image and (when present) two KITTI frames
# (FAST corners, quadtree, orientation, descriptors: every kernel of the extractor), of the stereo
# matches of the textured image with itself shifted and of the KITTI pair, of a local BA (the
# backend's Schur kernels) on a synthetic stereo window with outliers, of local mapping's searches
# (triangulation's pairs, fusion's matches) on synthetic scenes, of the shipped vocabulary's descent
# and of representative descriptors and viewing directions; the CPU numba compiled for, and how
# many of those kernels it compiled or loaded from the cache.
_CHILD = """
import hashlib, json, sys
from pathlib import Path
import cv2
import numpy as np
from numba.core import config
from zenslam.camera import PinholeCalibration
from zenslam.frontend import orb_descriptor, orb_fast, orb_orientation, orb_quadtree, stereo_kernel
from zenslam.frontend.orb_extractor import OrbConfig, OrbExtractor
from zenslam.frontend.stereo_matcher import match_stereo
rng = np.random.default_rng(5)
images = [cv2.GaussianBlur(rng.integers(0, 256, (370, 1226), dtype=np.uint8), (0, 0), 1.5)]
folder = Path(sys.argv[1]) / "kitti_odometry" / "sequences" / "06"
images += [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted(folder.glob("image_[01]/000010.png"))]
extractor = OrbExtractor(OrbConfig(threads=2))
digest = hashlib.sha256()
extracted = []
for image in images:
    features, pyramid = extractor.extract(image)
    extracted.append((features, pyramid))
    for name in ("px", "level", "angle_deg", "response", "descriptors"):
        digest.update(getattr(features, name).tobytes())
calibration = PinholeCalibration(707.0912, 707.0912, 601.8873, 183.1104, 1226, 370, baseline_m=0.5372)
pairs = [(extracted[0], extractor.extract(np.roll(images[0], -9, axis=1)))] + [tuple(extracted[1:])] * (len(images) == 3)
for (left, left_pyramid), (right, right_pyramid) in pairs:
    matches = match_stereo(left, right, left_pyramid, right_pyramid, calibration)
    for name in ("right_u", "depth_m", "right_index", "sad"):
        digest.update(getattr(matches, name).tobytes())
kernels = [orb_quadtree._morton_codes, orb_quadtree._distribute, orb_orientation._centroid_moments, orb_descriptor._descriptors]
kernels += [orb_fast._fast_in_cells]  # it calls orb_fast._strengths and _suppressed, compiled into it
sys.path.insert(0, sys.argv[2])  # tests/backend: its synthetic local BA window
from test_local_ba import make_window
from zenslam.backend import ba_normal_equations, schur_complement
from zenslam.backend.ba_problem import LocalBAConfig
from zenslam.backend.schur_ba import SchurBundleAdjuster
window, _, _, _ = make_window(12, n_keyframes=7, outlier_fraction=0.05)
ba = SchurBundleAdjuster(LocalBAConfig()).optimize(window)
for array in (ba.T_world_cam, ba.p_world, ba.inlier_obs):
    digest.update(np.ascontiguousarray(array).tobytes())
kernels += [ba_normal_equations._project, ba_normal_equations._blocks, schur_complement._reduced_system, schur_complement._back_substitute]
kernels += [stereo_kernel.best_descriptor_matches, stereo_kernel.refine_level_by_sad, stereo_kernel.keep_matches]
import test_mapping_search as searches  # local mapping's searches, on its synthetic scenes
from zenslam.backend import epipolar_search, fusion_search
for kind in searches.SCENES:
    for found in (searches.pair_searches(kind, 0)[0], searches.fusion_searches(kind, 0)[0]):
        for array in found:
            digest.update(np.ascontiguousarray(array).tobytes())
kernels += [epipolar_search.node_pair_candidates, fusion_search.best_in_windows]
from zenslam.vocabulary import load_vocabulary
from zenslam.vocabulary.descent import descend
words = np.random.default_rng(3).integers(0, 256, (500, 32), dtype=np.uint8).view(np.uint64)
for array in load_vocabulary(None)._descend(words, 2):
    digest.update(array.tobytes())
kernels += [descend]
from zenslam.map_point_rules import representative_descriptors
from zenslam.representative_descriptor import representative_offsets
groups = np.random.default_rng(4).integers(0, 256, (200, 9, 32), dtype=np.uint8)
digest.update(representative_descriptors(groups, np.arange(200) % 9 + 1).tobytes())
kernels += [representative_offsets]
from zenslam.map_point_rules import mean_viewing_directions
from zenslam.viewing_direction import mean_rays
rays = np.random.default_rng(6).normal(0, 10, (200, 6, 3))
digest.update(mean_viewing_directions(rays[:, 0], rays[:, 1:], np.arange(200) % 5 + 1).tobytes())
kernels += [mean_rays]
print(json.dumps({
    "digest": digest.hexdigest(),
    "images": len(images),
    "stereo_pairs": len(pairs),
    "cpu": config.CPU_NAME or "host",
    "misses": sum(sum(k.stats.cache_misses.values()) for k in kernels),
    "hits": sum(sum(k.stats.cache_hits.values()) for k in kernels),
    "scipy_linalg_loaded": "scipy.linalg" in sys.modules,
}))
"""


# The clips' root as tests/conftest.py names it (a plain import of that conftest is ambiguous:
# pytest puts every tests folder with a conftest.py on the path). Without the clips the child
# compares the textured image only.
_DATA = Path(os.environ.get("ZENSLAM_DATA") or Path(__file__).resolve().parents[1].parent / "shared" / "data")


def _child(**env: str) -> dict:
    environment = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")} | env
    command = [sys.executable, "-c", _CHILD, str(_DATA), str(Path(__file__).parent / "backend")]
    result = subprocess.run(command, env=environment, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    return json.loads(result.stdout)


@pytest.mark.slow(34)
@pytest.mark.skipif(platform.machine().lower() not in ("x86_64", "amd64"), reason="the generic target named is x86-64's")
def test_generic_x86_64_build_gives_the_same_features_as_the_machines_own(tmp_path: Path) -> None:
    own = _child(NUMBA_CACHE_DIR=str(tmp_path))
    generic = _child(NUMBA_CACHE_DIR=str(tmp_path), NUMBA_CPU_NAME="generic")
    assert (own["cpu"], generic["cpu"]) == ("host", "generic")
    assert own["stereo_pairs"] >= 1
    assert generic["digest"] == own["digest"]


@pytest.mark.slow(22)
def test_a_second_start_loads_the_kernels_from_the_cache(tmp_path: Path) -> None:
    first = _child(NUMBA_CACHE_DIR=str(tmp_path))
    second = _child(NUMBA_CACHE_DIR=str(tmp_path))
    assert first["misses"] > 0 and first["hits"] == 0  # an empty cache: compiled, then written
    assert second["misses"] == 0 and second["hits"] == first["misses"]
    assert second["digest"] == first["digest"]
    assert not first["scipy_linalg_loaded"] and not second["scipy_linalg_loaded"]  # compiled.py keeps numba off it


def test_scipy_linalg_still_imports_after_the_kernels_module():
    """compiled.py hides scipy's BLAS from numba only while numba's numpy support loads: a process
    that loads kernels can still use scipy.linalg afterwards."""
    code = "import zenslam.compiled, scipy.linalg, numba.np.arraymath as a\nprint(scipy.linalg.solve([[2.0]], [1.0])[0], a._HAVE_BLAS)"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["0.5", "False"]


def test_only_the_processes_that_extract_or_search_load_numba():
    """numba costs a process ~60 MB: the supervising run, the backend, the recorder and a source
    import the configs (OrbConfig among them) without it."""
    modules = ["zenslam.service.commands.run", "zenslam.service.run_config", "zenslam.backend.node",
               "zenslam.service.recorder", "zenslam.service.sources", "zenslam.frontend.config"]  # fmt: skip
    code = f"import sys\nfor m in {modules!r}: __import__(m)\nprint('numba' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "False"
