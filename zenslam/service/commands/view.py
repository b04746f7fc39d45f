"""``zenslam view RUN_DIR_OR_RRD``: open a run's .rrd files (one per stage, one recording) in the rerun viewer.

The viewer is the ``rerun`` executable of the installed rerun-sdk (its version matches the files').
On a machine without a display (no DISPLAY or WAYLAND_DISPLAY on Linux) no viewer can start: the
command prints the exact command to run where there is one (after copying the files), and the
browser alternative, and exits with ``EXIT_NO_DISPLAY``. The web viewer listens on 127.0.0.1 unless
``--bind`` names another address: recordings are not served to the network by default.
"""

from __future__ import annotations

import argparse
import ipaddress
import logging
import os
import shlex
import shutil
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path

from zenslam.errors import ConfigError

logger = logging.getLogger(__name__)

EXIT_NO_DISPLAY = 3  # no viewer could start here; the command to run elsewhere was printed
EXIT_VIEWER_FAILED = 4  # the viewer started but exited with a failure
LOOPBACK = "127.0.0.1"


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "view",
        help="open a run's rerun recordings (.rrd) in the rerun viewer",
        description="Open the .rrd files of a run folder (or one .rrd file) in the rerun viewer, as one recording. "
        f"Without a display, print the command to run elsewhere and exit {EXIT_NO_DISPLAY}.",
    )
    parser.add_argument("target", type=Path, metavar="RUN_DIR_OR_RRD", help="a run folder (recordings/<run-id>) or an .rrd file")
    parser.add_argument("--print-command", action="store_true", help="only print the viewer command (exit 0)")
    parser.add_argument("--web", action="store_true", help="serve the web viewer instead (open the printed URL in a browser)")
    parser.add_argument(
        "--bind", default=LOOPBACK, metavar="ADDRESS",
        help=f"--web: the IP address the web viewer listens on (default {LOOPBACK}: this machine only; "
        "0.0.0.0 serves every network interface)",
    )
    parser.add_argument("--viewer", default=None, help="the rerun executable (default: the one installed with rerun-sdk)")
    parser.set_defaults(handler=view)


def rrd_files(target: str | Path) -> list[Path]:
    """The .rrd files of a run folder (sorted by name), or ``[target]`` for an .rrd file."""
    # Imported here: rerun_log loads rerun (tens of MB), which every other subcommand, ``zenslam run``'s
    # hub among them, would otherwise hold for the sake of this constant.
    from zenslam.runtime.rerun_log import RRD_SUFFIX

    target = Path(target)
    if target.is_file():
        if target.suffix != RRD_SUFFIX:
            raise ConfigError(f"{target} is not an {RRD_SUFFIX} file; give a run folder or a rerun recording")
        return [target]
    if not target.is_dir():
        raise ConfigError(f"{target} does not exist; give a run folder (recordings/<run-id>) or an {RRD_SUFFIX} file")
    files = sorted(target.glob(f"*{RRD_SUFFIX}"))
    if not files:
        raise ConfigError(f"{target} holds no {RRD_SUFFIX} file; was the run made with rerun.enabled false?")
    return files


def viewer_executable() -> str:
    """The ``rerun`` executable next to this Python interpreter (rerun-sdk installs it), else the one on PATH."""
    beside = Path(sys.executable).with_name("rerun")
    if beside.is_file() and os.access(beside, os.X_OK):
        return str(beside)
    return shutil.which("rerun") or "rerun"


def viewer_command(files: list[Path], executable: str = "rerun", web: bool = False, bind: str = LOOPBACK) -> list[str]:
    """The command that opens ``files`` in one viewer (absolute paths, so it can be pasted anywhere); the web
    viewer listens on ``bind`` (an IP address)."""
    try:
        ipaddress.ip_address(bind)
    except ValueError:
        raise ConfigError(f"--bind {bind!r} is not an IP address; give e.g. {LOOPBACK} or 0.0.0.0") from None
    web_options = ["--web-viewer", "--bind", bind] if web else []
    return [executable, *web_options, *(str(Path(f).resolve()) for f in files)]


def has_display(environ: Mapping[str, str], platform: str = sys.platform) -> bool:
    """Whether a native viewer window can open: always on macOS/Windows, with X11 or Wayland on Linux."""
    if not platform.startswith("linux"):
        return True
    return bool(environ.get("DISPLAY") or environ.get("WAYLAND_DISPLAY") or environ.get("WAYLAND_SOCKET"))


def view(args: argparse.Namespace) -> int:
    """Open the viewer on the run's recordings; exit codes: 0, EXIT_NO_DISPLAY, EXIT_VIEWER_FAILED."""
    files = rrd_files(args.target)
    executable = args.viewer or viewer_executable()
    command = viewer_command(files, executable, web=args.web, bind=args.bind)
    text = shlex.join(command)
    if args.print_command:
        print(text)
        return 0
    if not args.web and not has_display(os.environ):
        portable = shlex.join(viewer_command(files, "rerun"))
        print(f"no display here (DISPLAY and WAYLAND_DISPLAY are unset): no viewer window can open.\n"
              f"On a machine with a display and rerun-sdk installed (same version), with the files copied there, run:\n"
              f"  {portable}\n"
              f"or serve the web viewer from here and open its URL in a browser (it listens on {LOOPBACK}: "
              f"forward its ports with ssh -L, or add --bind 0.0.0.0 to serve the network):\n"
              f"  zenslam view --web {shlex.quote(str(args.target))}")  # fmt: skip
        return EXIT_NO_DISPLAY
    logger.info("opening %d recording file(s): %s", len(files), text)
    try:
        code = subprocess.call(command)
    except OSError as exc:
        print(f"cannot start the viewer ({exc}); install rerun-sdk or pass --viewer, then run:\n  {text}")
        return EXIT_VIEWER_FAILED
    except KeyboardInterrupt:
        return 0
    if code != 0:
        print(f"the viewer exited with status {code}; the command was:\n  {text}")
        return EXIT_VIEWER_FAILED
    return 0
