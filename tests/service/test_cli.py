"""The zenslam command line: log lines printed while a progress bar is shown do not break it."""

from __future__ import annotations

import subprocess
import sys

# A command that logs while its progress bar is half done, run through zenslam's own main().
_DEMO = """
import logging, sys
from tqdm import tqdm
from zenslam.service import cli, commands

def register(subparsers):
    subparsers.add_parser("demo").set_defaults(handler=handler)

def handler(args):
    bar = tqdm(total=2, desc="tracking", unit="frame", file=sys.stderr, mininterval=0)
    bar.update(1)
    logging.getLogger("zenslam.demo").warning("halfway there")
    bar.update(1)
    bar.close()
    return 0

commands.register_all = register  # build_parser imports it when called
sys.exit(cli.main(["demo"]))
"""


def test_log_lines_print_above_the_progress_bar():
    result = subprocess.run([sys.executable, "-c", _DEMO], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    # What a terminal shows: each line's text after its last carriage return (the bar redraws in place).
    shown = [line.rsplit("\r", 1)[-1] for line in result.stderr.split("\n")]
    assert "WARNING zenslam.demo: halfway there" in shown, result.stderr
    assert any(line.startswith("tracking: 100%") for line in shown), result.stderr
