"""One module per ``zenslam`` subcommand, each exposing ``register(subparsers)``.

A registered subcommand sets ``handler`` (a function of the parsed args returning an exit code).
"""

from __future__ import annotations

import argparse
import importlib

# Order is the order shown in ``zenslam --help``.
COMMAND_MODULES = ("run", "stage", "publish", "inspect", "generate", "eval", "view", "recover", "export", "replay", "vocab")


def register_all(subparsers: argparse._SubParsersAction) -> None:
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(f"zenslam.service.commands.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"zenslam.service.commands.{name}":
                continue  # not written yet
            raise
        module.register(subparsers)
