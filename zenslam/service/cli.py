"""The ``zenslam`` command line: the only place that configures logging."""

from __future__ import annotations

import argparse
import logging
import sys

from tqdm.contrib.logging import logging_redirect_tqdm

from zenslam import __version__
from zenslam.errors import ZenslamError
from zenslam.service.commands import register_all


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="zenslam", description="Visual SLAM service (ORB-SLAM on a GTSAM back end).")
    parser.add_argument("--version", action="version", version=f"zenslam {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    register_all(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    if args.command is None:
        parser.print_help()
        return 0
    try:
        # Log lines go through tqdm.write: printed above a progress bar (zenslam run's) instead of through it.
        with logging_redirect_tqdm():
            return int(args.handler(args) or 0)
    except ZenslamError as exc:
        logging.getLogger("zenslam").error("%s", exc)
        return 2


if __name__ == "__main__":
    sys.exit(main())
