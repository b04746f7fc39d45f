"""``zenslam eval EST GT``: ATE and RPE of a trajectory file against ground truth, with metrics.json and a plot."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from zenslam.service.evaluation.loops import loops_section
from zenslam.service.evaluation.metrics import EvaluationConfig, evaluate
from zenslam.service.evaluation.plot import PLANES, save_evaluation_plot
from zenslam.service.evaluation.report import METRICS_FILENAME, format_summary, write_metrics
from zenslam.service.evaluation.trajectory_io import TRAJECTORY_FORMATS, detect_format, read_trajectory

logger = logging.getLogger(__name__)

PLOT_FILENAME = "trajectory_top.png"


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "eval",
        help="ATE/RPE of an estimated trajectory against ground truth",
        description=(
            "Compare an estimated trajectory (EST) with ground truth (GT): associate poses by stamp "
            "(by frame index when both are KITTI files without times), align, and report ATE and RPE. "
            f"Writes {METRICS_FILENAME} and {PLOT_FILENAME} to the output folder."
        ),
    )
    parser.add_argument("estimate", type=Path, metavar="EST", help="estimated trajectory file (TUM, KITTI or EuRoC)")
    parser.add_argument("ground_truth", type=Path, metavar="GT", help="ground-truth trajectory file")
    parser.add_argument(
        "--align", choices=("se3", "sim3", "none"), default="se3",
        help="alignment before the ATE: se3 (stereo/RGB-D, default), sim3 (monocular: scale too) or none",
    )
    parser.add_argument("--format-est", choices=TRAJECTORY_FORMATS, default=None, help="format of EST (default: detected)")
    parser.add_argument("--format-gt", choices=TRAJECTORY_FORMATS, default=None, help="format of GT (default: detected)")
    parser.add_argument("--times-est", type=Path, default=None, help="KITTI times.txt (seconds) stamping a KITTI EST")
    parser.add_argument("--times-gt", type=Path, default=None, help="KITTI times.txt (seconds) stamping a KITTI GT")
    parser.add_argument(
        "--max-time-diff-ms", type=float, default=10.0,
        help="largest stamp difference of an associated pose pair, milliseconds (default 10)",
    )
    parser.add_argument(
        "--plane", choices=PLANES, default="auto",
        help="world axes of the top-view plot (default auto: the ground plane of the ground-truth cameras, held "
        "upright; else the two axes along which the ground truth varies most)",
    )
    parser.add_argument("--output", type=Path, default=None, help="output folder (default: the folder of EST)")
    delta = parser.add_mutually_exclusive_group()
    delta.add_argument("--delta-m", type=float, default=None, help="RPE pair spacing in metres travelled")
    delta.add_argument("--rpe-delta-frames", type=int, default=None, help="RPE pair spacing in frames (default 1)")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Read both files, evaluate, write metrics.json and the plot, print the figures."""
    fmt_est = detect_format(args.estimate, args.format_est)
    fmt_gt = detect_format(args.ground_truth, args.format_gt)
    estimate = read_trajectory(args.estimate, fmt_est, times_path=args.times_est)
    ground_truth = read_trajectory(args.ground_truth, fmt_gt, times_path=args.times_gt)
    by_index = fmt_est == fmt_gt == "kitti" and args.times_est is None and args.times_gt is None
    if by_index:
        logger.info("both trajectories are KITTI files without times: associating by frame index")
    if args.delta_m is not None:
        rpe_delta, rpe_unit = args.delta_m, "m"
    else:
        rpe_delta, rpe_unit = (args.rpe_delta_frames if args.rpe_delta_frames is not None else 1), "frames"
    config = EvaluationConfig(
        alignment=args.align,
        association="index" if by_index else "time",
        max_time_diff_ns=round(args.max_time_diff_ms * 1e6),
        rpe_delta=float(rpe_delta),
        rpe_delta_unit=rpe_unit,
    )
    evaluation = evaluate(estimate, ground_truth, config)
    output = args.output if args.output is not None else args.estimate.resolve().parent
    metrics_path = write_metrics(output / METRICS_FILENAME, evaluation, loops=loops_section(evaluation))
    plot_path = save_evaluation_plot(output / PLOT_FILENAME, evaluation, plane=args.plane)
    print(f"estimate      {args.estimate} ({fmt_est})")
    print(f"ground truth  {args.ground_truth} ({fmt_gt})")
    print(format_summary(evaluation))
    print(f"wrote {metrics_path} and {plot_path}")
    return 0
