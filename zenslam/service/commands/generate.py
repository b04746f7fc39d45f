"""``zenslam generate SCENE OUT``: render a built-in synthetic scene to disk in TUM RGB-D layout."""

from __future__ import annotations

import argparse
import itertools
from pathlib import Path

from tqdm import tqdm

from zenslam.errors import SourceSpecError
from zenslam.service.sources import open_source
from zenslam.service.sources.tum import write_tum_rgbd


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "generate",
        help="render a synthetic scene to a TUM RGB-D folder",
        description="Render synthetic[:<scene>] as RGB-D and write it in TUM RGB-D layout "
        "(rgb/, depth/, rgb.txt, depth.txt, groundtruth.txt, calibration.yaml), readable with tum:<OUT>.",
    )
    parser.add_argument("scene", help="synthetic or synthetic:<scene> (loop, figure_eight, still, corridor, corridor_aliased)")
    parser.add_argument("output", type=Path, help="folder to write (created)")
    parser.add_argument("--frames", type=int, default=None, help="write only the first N frames")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    if not args.scene.startswith("synthetic"):
        raise SourceSpecError(f"generate renders built-in scenes only; got {args.scene!r}, use synthetic[:<scene>]")
    scene = args.scene.split("/")[0]
    source = open_source(f"{scene}/rgbd")
    total = len(source) if args.frames is None else min(args.frames, len(source))
    frames = tqdm(itertools.islice(source, total), total=total, desc="rendering", unit="frame")
    written = write_tum_rgbd(args.output, frames, source.ground_truth(), source.calibration)
    print(f"wrote {written} RGB-D frames of {source.name} to {args.output} (read it back with tum:{args.output})")
    return 0
