"""``zenslam vocab train|score|info``: train a bag-of-words vocabulary, score two images, describe a vocabulary file."""

from __future__ import annotations

import argparse
import logging
import shlex
import time
from pathlib import Path

from tqdm import tqdm

from zenslam import __version__
from zenslam.errors import VocabularyError

logger = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "vocab",
        help="train a bag-of-words vocabulary, score two images, or describe a vocabulary file",
        description="Bag-of-words vocabularies of ORB words (DBoW2 trees: TF-IDF weights, L1 score). Files are "
        "zenslam's .npz or DBoW2 text (.txt, .txt.gz: what ORB-SLAM2/3 load as ORBvoc.txt), told apart by content.",
    )
    commands = parser.add_subparsers(dest="vocab_command", metavar="{train,score,info}", required=True)

    train = commands.add_parser(
        "train",
        help="train a vocabulary from sources' frames",
        description="Extract ORB features (the frontend's default settings) from every image of the sources' frames "
        "(left and right of a stereo frame) and train a vocabulary tree on them; each image is one document for the "
        "idf weights. Written as DBoW2 text when OUTPUT ends in .txt or .txt.gz, else as zenslam's .npz.",
    )
    train.add_argument("sources", nargs="+", metavar="SOURCE",
                       help="kitti:<root>/sequences/NN | euroc:<folder> | tum:<folder> | synthetic[:<scene>[/<sensor>][,laps=N][,seed=N]] "
                       "| mcap:<run.mcap>")
    train.add_argument("--output", type=Path, required=True, help="vocabulary file to write (.npz, .txt or .txt.gz)")
    train.add_argument("--branching", type=int, default=10, metavar="K", help="children per node (default 10)")
    train.add_argument("--depth", type=int, default=5, metavar="L", help="levels below the root (default 5)")
    train.add_argument("--max-frames-per-source", type=int, default=None, metavar="N",
                       help="use N frames of each source, spread evenly over it (default: every frame)")
    train.add_argument("--synthetic-seeds", default=None, metavar="SEEDS",
                       help="render each synthetic scene with these texture seeds, e.g. 0-7 or 1,4,9 (default: its own seed)")
    train.add_argument("--seed", type=int, default=0, help="seed of the k-means++ draws (default 0)")
    train.add_argument("--max-iterations", type=int, default=None, metavar="N",
                       help="assignment passes per node before its clusters are kept as they are (default 30)")
    train.set_defaults(handler=run_train)

    score = commands.add_parser(
        "score",
        help="print the similarity of two images",
        description="The L1 score (0: nothing in common, 1: the same words) of two grey or colour image files' ORB "
        "bags of words.",
    )
    score.add_argument("image_a", type=Path, metavar="IMAGE_A")
    score.add_argument("image_b", type=Path, metavar="IMAGE_B")
    score.add_argument("--vocabulary", type=Path, default=None, metavar="FILE", help="vocabulary file (default: the one shipped)")
    score.set_defaults(handler=run_score)

    info = commands.add_parser("info", help="describe a vocabulary file",
                               description="k, L, words, nodes, weighting, scoring, file size and training notes.")
    info.add_argument("file", type=Path, nargs="?", default=None, metavar="FILE", help="vocabulary file (default: the one shipped)")
    info.set_defaults(handler=run_info)


def run_train(args: argparse.Namespace) -> int:
    from zenslam.service.vocabulary_corpus import collect_descriptors, frame_indices, open_training_sources, parse_seeds
    from zenslam.vocabulary import save_vocabulary
    from zenslam.vocabulary.training import TrainingConfig, train_vocabulary

    overrides = {} if args.max_iterations is None else {"max_iterations": args.max_iterations}
    config = TrainingConfig(branching=args.branching, depth=args.depth, seed=args.seed, **overrides)
    if not args.output.name.lower().endswith((".npz", ".txt", ".txt.gz")):
        raise VocabularyError(f"--output {args.output}: end the name in .npz (zenslam) or .txt / .txt.gz (DBoW2 text)")
    seeds = parse_seeds(args.synthetic_seeds) if args.synthetic_seeds else None
    sources = open_training_sources(args.sources, seeds)
    start = time.perf_counter()
    total = sum(len(frame_indices(len(s), args.max_frames_per_source)) for s in sources)
    with tqdm(total=total, desc="extracting ORB", unit="frame") as bar:
        images, parts = collect_descriptors(sources, args.max_frames_per_source, on_frame=lambda: bar.update())
    extracted = time.perf_counter()
    with tqdm(total=config.depth, desc="clustering", unit="level") as bar:
        vocabulary = train_vocabulary(
            images, config, on_level=lambda *_: bar.update(),
            metadata={
                "corpus": "\n".join(part.describe() for part in parts),
                "command": _train_command(args, config),
                "training": f"k={config.branching} L={config.depth} seed={config.seed} "
                f"max_iterations={config.max_iterations}; zenslam {__version__}",
            },
        )
    args.output.parent.mkdir(parents=True, exist_ok=True)
    path = save_vocabulary(vocabulary, args.output)
    descriptors = sum(d.shape[0] for d in images)
    for part in parts:
        print(part.describe())
    print(
        f"wrote {path}: {vocabulary.n_words} words, {vocabulary.n_nodes} nodes (k={vocabulary.branching}, "
        f"L={vocabulary.depth}), {path.stat().st_size / 1e6:.1f} MB, from {len(images)} images / {descriptors} "
        f"descriptors; extraction {extracted - start:.0f} s, clustering {time.perf_counter() - extracted:.0f} s"
    )
    return 0


def _train_command(args: argparse.Namespace, config) -> str:
    """The command line that trains this vocabulary again (every setting spelled out)."""
    words = ["zenslam", "vocab", "train", *args.sources]
    if args.synthetic_seeds:
        words += ["--synthetic-seeds", args.synthetic_seeds]
    if args.max_frames_per_source is not None:
        words += ["--max-frames-per-source", str(args.max_frames_per_source)]
    words += ["--branching", str(config.branching), "--depth", str(config.depth), "--seed", str(config.seed),
              "--max-iterations", str(config.max_iterations), "--output", str(args.output)]
    return shlex.join(words)


def run_score(args: argparse.Namespace) -> int:
    from zenslam.frontend.config import FrontendConfig
    from zenslam.frontend.orb_extractor import OrbExtractor
    from zenslam.service.sources.images import read_grey
    from zenslam.vocabulary import load_vocabulary

    vocabulary = load_vocabulary(args.vocabulary)
    extractor = OrbExtractor(FrontendConfig().orb)
    bows = []
    print(f"vocabulary: {vocabulary.source} ({vocabulary.n_words} words, k={vocabulary.branching}, L={vocabulary.depth})")
    for path in (args.image_a, args.image_b):
        features, _ = extractor.extract(read_grey(path))
        bow, _ = vocabulary.transform(features.descriptors)
        bows.append(bow)
        print(f"{path}: {len(features)} features, {len(bow)} words")
    print(f"score: {vocabulary.score(bows[0], bows[1]):.4f}")
    return 0


def run_info(args: argparse.Namespace) -> int:
    from zenslam.vocabulary import load_vocabulary
    from zenslam.vocabulary.files import default_vocabulary_path

    path = args.file if args.file is not None else default_vocabulary_path()
    start = time.perf_counter()
    vocabulary = load_vocabulary(path)
    load_s = time.perf_counter() - start
    print(f"file:       {path}")
    print(f"size:       {path.stat().st_size / 1e6:.2f} MB (loaded in {load_s:.2f} s)")
    print(f"k:          {vocabulary.branching}")
    print(f"L:          {vocabulary.depth}")
    print(f"words:      {vocabulary.n_words} ({(vocabulary.word_weights == 0).sum()} stopped: weight 0)")
    print(f"nodes:      {vocabulary.n_nodes} (root included)")
    print(f"weighting:  {vocabulary.weighting}")
    print(f"scoring:    {vocabulary.scoring}")
    for key in ("training", "command", "corpus"):
        value = vocabulary.metadata.get(key)
        if value:
            lines = value.splitlines()
            print(f"{key + ':':<11} {lines[0]}")
            for line in lines[1:]:
                print(f"{'':<11} {line}")
    return 0
