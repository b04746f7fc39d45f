"""Benchmark loading a saved map (``zenslam run --map``): seconds to read a 1,000-keyframe map into the backend.

The map is built synthetically at the sizes of a real run's map, then written with ``save_map``:
``--keyframes`` keyframes (default 1,000) of ``--keypoints`` keypoints each (default 1,500, the
ORB extractor's 2,000 less the ones dropped at the borders), half of them observing a point; each
point is observed by 4 keyframes in a row (so ~190,000 points, ~750,000 observations),
covisibility between keyframes sharing points, a spanning tree along the path, bags of words of
600 words and direct indexes of 100 nodes per keyframe, 200 culled keyframes. Timed: ``load_map``
(read, check, rebuild keyframes, points, graphs and the keyframe database) into an empty backend
map, ``--repeat`` times, and the same for a real map given with ``--map FILE``.

Run: ``.venv/bin/python benchmarks/map_load.py [--keyframes 1000] [--map FILE] [--repeat 3]``
(writes benchmarks/results/map_load.json).
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from zenslam.backend.map import BackendMap
from zenslam.backend.map_arrays import map_from_arrays
from zenslam.backend.map_file import load_map, save_map
from zenslam.backend.place_recognition import PlaceRecognition
from zenslam.camera import PinholeCalibration
from zenslam.schemas.map_update import BACKEND_POINT_ID_BASE
from zenslam.vocabulary import load_vocabulary

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "map_load.json"
CAL = PinholeCalibration(718.856, 718.856, 607.19, 185.22, 1241, 376, 0.537)
SPAN = 4  # keyframes observing each point, consecutive


def _offsets(lengths: np.ndarray) -> np.ndarray:
    return np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)


def synthetic_arrays(n_kf: int, n_kp: int, n_words: int, seed: int = 0) -> dict[str, np.ndarray]:
    """The arrays of a saved map of ``n_kf`` keyframes (see the module doc)."""
    rng = np.random.default_rng(seed)
    observed = n_kp // 2
    per_kf_new = observed // SPAN
    n_points = per_kf_new * (n_kf + SPAN - 1)
    n = n_kf * n_kp
    map_point_ids = np.full((n_kf, n_kp), -1, dtype=np.int64)
    obs_kf, obs_kp = [[] for _ in range(n_points)], [[] for _ in range(n_points)]
    for k in range(n_kf):
        points = np.concatenate([np.arange(per_kf_new) + per_kf_new * (k + j) for j in range(SPAN)])
        keypoints = rng.permutation(n_kp)[: len(points)]
        map_point_ids[k, keypoints] = BACKEND_POINT_ID_BASE + points
        for p, kp in zip(points.tolist(), keypoints.tolist()):
            obs_kf[p].append(k)
            obs_kp[p].append(kp)
    poses = np.tile(np.eye(4), (n_kf, 1, 1))
    poses[:, 0, 3] = 0.5 * np.arange(n_kf)
    n_culled = n_kf // 5
    words = [np.sort(rng.choice(n_words, 600, replace=False)) for _ in range(n_kf)]
    groups = [np.array_split(rng.permutation(n_kp), 100) for _ in range(n_kf)]
    shared = per_kf_new * np.arange(SPAN - 1, 0, -1)
    return {
        "keyframe_ids": np.arange(n_kf, dtype=np.int64),
        "keyframe_stamps_ns": np.arange(n_kf, dtype=np.int64) * 100_000_000,
        "keyframe_serials": np.arange(n_kf, dtype=np.int64),
        "keyframe_T_world_cam": poses,
        "keyframe_keypoint_offsets": _offsets(np.full(n_kf, n_kp)),
        "keyframe_scale_offsets": _offsets(np.full(n_kf, 8)),
        "keyframe_scale_factors": np.tile(1.2 ** np.arange(8), n_kf),
        "keypoints_px": rng.uniform(0, 370, (n, 2)),
        "keypoint_levels": rng.integers(0, 8, n).astype(np.int64),
        "keypoint_angles_deg": rng.uniform(0, 360, n),
        "keypoint_right_u": rng.uniform(0, 370, n),
        "keypoint_depth_m": rng.uniform(1, 30, n),
        "keypoint_descriptors": rng.integers(0, 256, (n, 32), dtype=np.uint8),
        "keypoint_map_point_ids": map_point_ids.reshape(-1),
        "point_ids": BACKEND_POINT_ID_BASE + np.arange(n_points, dtype=np.int64),
        "point_p_world": rng.uniform(-20, 20, (n_points, 3)),
        "point_first_keyframe_ids": np.array([o[0] if o else 0 for o in obs_kf], dtype=np.int64),
        "point_created_serials": np.array([o[0] if o else 0 for o in obs_kf], dtype=np.int64),
        "point_descriptors": rng.integers(0, 256, (n_points, 32), dtype=np.uint8),
        "point_normals": np.tile([0.0, 0.0, 1.0], (n_points, 1)),
        "point_min_distance_m": np.full(n_points, 1.0),
        "point_max_distance_m": np.full(n_points, 40.0),
        "point_n_visible": np.full(n_points, 8, dtype=np.int64),
        "point_n_found": np.full(n_points, 6, dtype=np.int64),
        "point_observation_offsets": _offsets(np.array([len(o) for o in obs_kf])),
        "observation_keyframe_ids": np.array([k for o in obs_kf for k in o], dtype=np.int64),
        "observation_keypoints": np.array([kp for o in obs_kp for kp in o], dtype=np.int64),
        "covisibility_weights": np.array(
            [(a, a + d, int(shared[d - 1])) for a in range(n_kf) for d in range(1, SPAN) if a + d < n_kf], dtype=np.int64
        ).reshape(-1, 3),
        "spanning_tree_parents": np.arange(-1, n_kf - 1, dtype=np.int64),
        "loop_edges": np.array([[0, n_kf - 1]], dtype=np.int64),
        "culled_keyframe_ids": n_kf + np.arange(n_culled, dtype=np.int64),
        "culled_stamps_ns": np.arange(n_culled, dtype=np.int64),
        "culled_parent_ids": rng.integers(0, n_kf, n_culled).astype(np.int64),
        "culled_T_parent_cam": np.tile(np.eye(4), (n_culled, 1, 1)),
        "fused_point_ids": np.zeros((0, 2), dtype=np.int64),
        "bow_offsets": _offsets(np.array([len(w) for w in words])),
        "bow_word_ids": np.concatenate(words).astype(np.int64),
        "bow_weights": np.full(600 * n_kf, 1.0 / 600),
        "feature_vector_offsets": _offsets(np.full(n_kf, 100)),
        "feature_vector_node_ids": np.tile(np.arange(100, dtype=np.int64), n_kf),
        "feature_vector_group_offsets": _offsets(np.array([len(g) for gs in groups for g in gs])),
        "feature_vector_keypoints": np.concatenate([np.sort(g) for gs in groups for g in gs]).astype(np.int64),
    }


def time_load(path: Path, vocabulary, repeat: int) -> dict:
    seconds, bmap = [], None
    for _ in range(repeat):
        bmap, places = BackendMap(), PlaceRecognition(vocabulary)
        started = time.perf_counter()
        load_map(path, bmap, places)
        seconds.append(time.perf_counter() - started)
    return {
        "file": str(path), "file_mb": path.stat().st_size / 1e6, "keyframes": len(bmap.keyframes),
        "points": len(bmap.points), "observations": sum(len(p.observations) for p in bmap.points.values()),
        "load_s": {"median": statistics.median(seconds), "min": min(seconds), "max": max(seconds), "runs": seconds},
    }  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--keyframes", type=int, default=1000)
    parser.add_argument("--keypoints", type=int, default=1500)
    parser.add_argument("--map", type=Path, default=None, help="also time this saved map (e.g. a run's --save-map)")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    vocabulary = load_vocabulary(None)
    results: dict = {"machine": platform.processor() or platform.machine(), "python": platform.python_version()}
    with tempfile.TemporaryDirectory() as folder:
        started = time.perf_counter()
        bmap, places = BackendMap(), PlaceRecognition(vocabulary)
        map_from_arrays(
            synthetic_arrays(args.keyframes, args.keypoints, vocabulary.n_words), bmap, places, CAL, "stereo",
            args.keyframes, BACKEND_POINT_ID_BASE + 10**7,
        )  # fmt: skip
        path = Path(folder) / "synthetic.zmap"
        save_started = time.perf_counter()
        save_map(path, bmap, places)
        results["synthetic"] = {
            "build_s": save_started - started, "save_s": time.perf_counter() - save_started,
            **time_load(path, vocabulary, args.repeat),
        }  # fmt: skip
    if args.map is not None:
        results["given"] = time_load(args.map, vocabulary, args.repeat)
    for name in ("synthetic", "given"):
        if name in results:
            r = results[name]
            print(
                f"{name}: {r['keyframes']} keyframes, {r['points']} points, {r['observations']} observations, "
                f"{r['file_mb']:.0f} MB: load {r['load_s']['median']:.2f} s median of {len(r['load_s']['runs'])} "
                f"(min {r['load_s']['min']:.2f}, max {r['load_s']['max']:.2f})"
            )
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
