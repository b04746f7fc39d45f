"""``zenslam run``'s options: what its help promises matches the configuration it reads."""

from __future__ import annotations

import argparse
import dataclasses

from zenslam.service.commands import run as run_command
from zenslam.service.run_config import RunConfig


def _run_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="zenslam")
    subparsers = parser.add_subparsers(dest="command")
    run_command.register(subparsers)
    return subparsers.choices["run"]


def _option(parser: argparse.ArgumentParser, flag: str) -> argparse.Action:
    return next(action for action in parser._actions if flag in action.option_strings)


def test_config_help_names_every_key_and_section_of_the_run_config():
    help_text = _option(_run_parser(), "--config").help
    defaults = RunConfig()
    fields = [f.name for f in dataclasses.fields(RunConfig)]
    sections = [name for name in fields if dataclasses.is_dataclass(getattr(defaults, name))]
    keys = [name for name in fields if name not in sections]
    assert sections and f"sections {', '.join(sections)} " in help_text
    assert not keys or f"keys {', '.join(keys)} and " in help_text


def test_plane_defaults_to_auto():
    args = _run_parser().parse_args(["synthetic"])
    assert args.plane == "auto"
    assert _run_parser().parse_args(["synthetic", "--plane", "xz"]).plane == "xz"
