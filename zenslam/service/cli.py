"""The ``zenslam`` command line: the only place that configures logging."""

from __future__ import annotations

import argparse
import logging
import sys

from tqdm.contrib.logging import logging_redirect_tqdm

from zenslam import __version__
from zenslam.errors import ZenslamError


def build_parser() -> argparse.ArgumentParser:
    from zenslam.service.commands import register_all

    parser = argparse.ArgumentParser(prog="zenslam", description="Visual SLAM service (ORB-SLAM on a GTSAM back end).")
    parser.add_argument("--version", action="version", version=f"zenslam {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    register_all(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one subcommand. A Ctrl-C is held from the start (the commands' imports take seconds): a
    command registered with ``stop_flag=True`` gets it as ``args.stop`` and stops in its own way
    (``zenslam run`` still writes what was tracked); any other is interrupted with one line."""
    from zenslam.runtime.stop import EXIT_INTERRUPTED, StopFlag

    stop = StopFlag(quiet=True).install()
    log = logging.getLogger("zenslam")
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, format="%(levelname)s %(name)s: %(message)s")
        if args.command is None:
            parser.print_help()
            return 0
        if getattr(args, "stop_flag", False):
            args.stop = stop
        else:
            stop.uninstall()
            if stop():
                log.warning("interrupted before %s started", args.command)
                return EXIT_INTERRUPTED
        # Log lines go through tqdm.write: printed above a progress bar (zenslam run's) instead of through it.
        with logging_redirect_tqdm():
            return int(args.handler(args) or 0)
    except ZenslamError as exc:
        log.error("%s", exc)
        return 2
    except KeyboardInterrupt:
        log.warning("interrupted")
        return EXIT_INTERRUPTED
    finally:
        stop.uninstall()


if __name__ == "__main__":
    sys.exit(main())
