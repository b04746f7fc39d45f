"""``zenslam recover BROKEN.mcap [-o FIXED.mcap]``: an indexed copy of a recording whose writer was killed."""

from __future__ import annotations

import argparse
from pathlib import Path

from zenslam.service import mcap_io


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "recover",
        help="make a readable, indexed MCAP from a recording whose writer was killed",
        description="Copy every finished chunk and message of BROKEN.mcap (a killed recorder loses only its open "
        "chunk) into FIXED.mcap with a fresh summary and index, and report what was kept.",
    )
    parser.add_argument("broken", type=Path, help="the damaged recording, e.g. recordings/<run-id>/run.mcap")
    parser.add_argument("-o", "--output", type=Path, default=None, help="the recovered file (default: BROKEN.recovered.mcap)")
    parser.set_defaults(handler=run)


def default_output(broken: Path) -> Path:
    """``run.mcap`` -> ``run.recovered.mcap`` beside it."""
    return broken.with_name(f"{broken.stem}.recovered{broken.suffix or '.mcap'}")


def report_lines(report: mcap_io.RecoveryReport, fixed: Path) -> list[str]:
    """What a recovery kept, for people."""
    lines = [
        f"recovered {report.total} messages on {report.channels} channels ({report.schemas} schemas, "
        f"{report.attachments} attachments, {report.metadata} metadata) -> {fixed}"
    ]
    for topic in sorted(report.messages):
        lines.append(f"  {topic}: {report.messages[topic]}")
    if report.complete:
        lines.append("the input was complete: nothing was lost")
    else:
        lines.append(f"the input ended early ({report.stop_reason or 'truncated'}): its unfinished tail is lost")
    return lines


def run(args: argparse.Namespace) -> int:
    output = args.output or default_output(args.broken)
    report = mcap_io.recover(args.broken, output)
    for line in report_lines(report, output):
        print(line)
    return 0
