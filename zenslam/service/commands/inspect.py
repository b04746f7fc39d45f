"""``zenslam inspect SOURCE``: frame count, rate, resolution, calibration and ground truth of a source."""

from __future__ import annotations

import argparse

import numpy as np

from zenslam.service.sources import Source, open_source


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "inspect",
        help="summarise a dataset or scene before running on it",
        description="Print frame count, rate, resolution, calibration and ground truth of SOURCE.",
    )
    parser.add_argument("source", help="kitti:<root>/sequences/NN | euroc:<folder> | tum:<folder> | synthetic[:<scene>]")
    parser.add_argument(
        "--check-images", type=int, default=1, metavar="N", help="decode the first N frames to check they load (default 1)"
    )
    parser.set_defaults(handler=run)


def describe(source: Source, check_images: int = 1) -> list[str]:
    """Human-readable summary lines of a source; decodes the first ``check_images`` frames."""
    stamps = source.stamps_ns()
    lines = [f"source:      {source.name}", f"sensor:      {source.sensor}", f"frames:      {len(source)}"]
    if len(stamps) > 1:
        duration_s = (stamps[-1] - stamps[0]) * 1e-9
        rate = (len(stamps) - 1) / duration_s if duration_s > 0 else float("nan")
        lines.append(f"duration:    {duration_s:.2f} s at {rate:.2f} Hz")
    cal = source.calibration
    lines.append(f"resolution:  {cal.width}x{cal.height}")
    lines.append(f"calibration: {cal.summary()}")
    gt = source.ground_truth()
    if gt is None:
        lines.append("ground truth: none")
    else:
        lines.append(f"ground truth: {len(gt)} poses, path length {gt.path_length_m():.3f} m")
    imu = source.imu()
    lines.append("imu:         none" if imu is None else f"imu:         {len(imu.stamps_ns)} samples")
    for i, frame in enumerate(source):
        if i >= check_images:
            break
        parts = [f"left {frame.left.shape[1]}x{frame.left.shape[0]} mean {float(np.mean(frame.left)):.1f}"]
        if frame.right is not None:
            parts.append("right ok")
        if frame.depth_m is not None:
            valid = frame.depth_m > 0
            parts.append(f"depth valid {valid.mean() * 100:.0f}%")
        lines.append(f"frame {frame.index}:     " + ", ".join(parts))
    return lines


def run(args: argparse.Namespace) -> int:
    source = open_source(args.source)
    for line in describe(source, args.check_images):
        print(line)
    return 0
