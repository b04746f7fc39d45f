"""Benchmark the keyframe database: loop and relocalisation queries at 1,000 keyframes.

Keyframes are real bags of words: the default vocabulary's transform of the ORB descriptors of
synthetic renders (the corridor and the room scenes, every few frames, with several seeds), so the
inverted index has the word statistics of real images. Each query is a keyframe of a second
render of the same scenes (another seed of the photometric noise) against the whole database;
the covisibility graph links each keyframe to its 10 neighbours along its sequence, so the group
accumulation does its real work. Times are thread CPU time, median and minimum over the queries.

Run: ``.venv/bin/python benchmarks/place_recognition.py [--keyframes 1000] [--queries 50]``
(writes benchmarks/results/place_recognition.json).
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from zenslam.backend.covisibility import CovisibilityGraph
from zenslam.backend.keyframe_database import KeyframeDatabase
from zenslam.frontend.orb_extractor import OrbExtractor
from zenslam.service.sources.synthetic import SyntheticSource, scene_config
from zenslam.vocabulary import load_vocabulary

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "place_recognition.json"
SCENES = ("corridor", "loop", "figure_eight")


def descriptors_of(n_keyframes: int, seed: int) -> list[np.ndarray]:
    """ORB descriptors of ``n_keyframes`` left images spread over the scenes."""
    extractor = OrbExtractor()
    per_scene = -(-n_keyframes // len(SCENES))
    out: list[np.ndarray] = []
    for name in SCENES:
        source = SyntheticSource(scene_config(name, seed=seed))
        for i in np.linspace(0, len(source) - 1, per_scene).astype(int).tolist():
            features, _ = extractor.extract(source.frame(i).left)
            out.append(np.asarray(features.descriptors))
    return out[:n_keyframes]


def cpu_ms(function) -> tuple[float, object]:
    start = time.thread_time()
    value = function()
    return (time.thread_time() - start) * 1e3, value


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--keyframes", type=int, default=1000)
    parser.add_argument("--queries", type=int, default=50)
    args = parser.parse_args()
    vocabulary = load_vocabulary(None)
    database, graph = KeyframeDatabase(), CovisibilityGraph(15)
    transform_ms = []
    for kf_id, d in enumerate(descriptors_of(args.keyframes, seed=1)):
        ms, (bow, _) = cpu_ms(lambda d=d: vocabulary.transform(d))
        transform_ms.append(ms)
        database.add(kf_id, bow)
        graph.add_keyframe(kf_id)
        for other in range(max(0, kf_id - 10), kf_id):
            graph.change_weight(kf_id, other, 100 - 8 * (kf_id - other))
    queries = descriptors_of(args.queries, seed=2)
    loop_ms, reloc_ms, found = [], [], []
    for d in queries:
        bow, _ = vocabulary.transform(d)
        ms, candidates = cpu_ms(lambda: database.relocalisation_candidates(bow, graph, vocabulary.score))
        reloc_ms.append(ms)
        found.append(len(candidates))
        ms, _ = cpu_ms(lambda: database.loop_candidates(-1, bow, 0.01, graph, vocabulary.score))
        loop_ms.append(ms)
    figures = {
        "keyframes": len(database),
        "queries": len(queries),
        "transform_ms": {"median": statistics.median(transform_ms), "min": min(transform_ms)},
        "relocalisation_query_ms": {"median": statistics.median(reloc_ms), "min": min(reloc_ms), "max": max(reloc_ms)},
        "loop_query_ms": {"median": statistics.median(loop_ms), "min": min(loop_ms), "max": max(loop_ms)},
        "candidates_per_query_median": statistics.median(found),
        "machine": platform.processor() or platform.machine(),
    }
    print(json.dumps(figures, indent=2))
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(figures, indent=2) + "\n")


if __name__ == "__main__":
    main()
