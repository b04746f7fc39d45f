"""Benchmark the bag-of-words vocabulary: load time of the default vocabulary, transform time per image, search_by_bow.

Transform: the default vocabulary's ``transform`` (BowVector + FeatureVector, ORB-SLAM's direct
index level) of 1,200 ORB descriptors, extracted with the frontend's default ORB settings from a
synthetic frame (and from the EuRoC revisit images when the clips are in ../shared/data). Load:
``load_vocabulary(None)`` from the package file. Also ``search_by_bow`` between two views, and
optionally (``--dbow2-text``) the load time of the default vocabulary written as DBoW2 text.
Times are the median and the minimum over ``--repeats`` runs (CPU time of one thread; the machine
is shared, so the minimum is the cleanest figure).

Run: ``.venv/bin/python benchmarks/vocabulary.py [--repeats 200] [--dbow2-text]``
(writes benchmarks/results/vocabulary.json).
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import tempfile
import time
from pathlib import Path

from zenslam.frontend.config import FrontendConfig
from zenslam.frontend.orb_extractor import OrbExtractor
from zenslam.service.sources import open_source
from zenslam.service.sources.images import read_grey
from zenslam.vocabulary import default_vocabulary_path, load_vocabulary, save_vocabulary
from zenslam.vocabulary.bow_matching import search_by_bow

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "vocabulary.json"
REVISITS = REPO.parent / "shared" / "data" / "euroc" / "V1_01_easy_revisits"


def timed(function, repeats: int) -> dict:
    """Median and minimum thread CPU time of ``function()`` in ms."""
    times = []
    for _ in range(repeats):
        start = time.thread_time()
        function()
        times.append((time.thread_time() - start) * 1e3)
    return {"median_ms": round(statistics.median(times), 3), "min_ms": round(min(times), 3), "repeats": repeats}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=200)
    parser.add_argument("--dbow2-text", action="store_true", help="also time loading the default vocabulary as DBoW2 text")
    args = parser.parse_args()

    path = default_vocabulary_path()
    load = timed(lambda: load_vocabulary(None), 5)
    vocabulary = load_vocabulary(None)
    print(f"default vocabulary {path.name}: {path.stat().st_size / 1e6:.2f} MB, {vocabulary.n_words} words, "
          f"{vocabulary.n_nodes} nodes; load {load['median_ms']:.0f} ms (min {load['min_ms']:.0f})")

    extractor = OrbExtractor(FrontendConfig().orb)
    frame = open_source("synthetic:loop").frame(100)
    (left, _), (right, _) = extractor.extract_pair(frame.left, frame.right)
    images = {"synthetic:loop frame 100": left}
    if REVISITS.is_dir():
        images["euroc revisits left_img_0"] = extractor.extract(read_grey(REVISITS / "left_img_0.png"))[0]
    transform = {}
    for name, features in images.items():
        descriptors = features.descriptors[:1200]
        figures = timed(lambda d=descriptors: vocabulary.transform(d), args.repeats)
        transform[name] = {"features": int(descriptors.shape[0]), **figures}
        print(f"transform {name}: {descriptors.shape[0]} features, {figures['median_ms']:.2f} ms median "
              f"(min {figures['min_ms']:.2f})")

    _, fvec_left = vocabulary.transform(left.descriptors)
    _, fvec_right = vocabulary.transform(right.descriptors)
    matching = timed(
        lambda: search_by_bow(fvec_left, left.descriptors, left.angle_deg, fvec_right, right.descriptors,
                              right.angle_deg),
        max(args.repeats // 4, 5),
    )
    matches = len(search_by_bow(fvec_left, left.descriptors, left.angle_deg, fvec_right, right.descriptors,
                                right.angle_deg)[0])
    print(f"search_by_bow stereo pair ({len(left)} x {len(right)} features): {matches} matches, "
          f"{matching['median_ms']:.2f} ms median (min {matching['min_ms']:.2f})")

    text_load = None
    if args.dbow2_text:
        with tempfile.TemporaryDirectory() as folder:
            text = save_vocabulary(vocabulary, Path(folder) / "default.txt")
            text_load = {"bytes": text.stat().st_size, **timed(lambda: load_vocabulary(text), 3)}
        print(f"as DBoW2 text: {text_load['bytes'] / 1e6:.1f} MB, load {text_load['median_ms']:.0f} ms")

    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps({
        "machine": platform.processor() or platform.machine(),
        "vocabulary": {"file": path.name, "bytes": path.stat().st_size, "words": vocabulary.n_words,
                       "nodes": vocabulary.n_nodes, "k": vocabulary.branching, "L": vocabulary.depth},
        "load_default": load,
        "transform": transform,
        "search_by_bow": {"matches": matches, **matching},
        "load_dbow2_text": text_load,
    }, indent=2))
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
