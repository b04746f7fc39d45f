"""``zenslam run``'s options: what its help promises matches the configuration it reads."""

from __future__ import annotations

import argparse
import dataclasses
import time

from zenslam.service.commands import run as run_command
from zenslam.service.run_config import RunConfig
from zenslam.service.run_follower import RunFollower
from zenslam.service.run_stages import watch_for_hang


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


class _Log:
    """What the hang watch reads of the run's log: 22 frames tracked, every keyframe answered."""

    ended = backend_ended = False
    frames = range(22)
    corrections_owed = 0  # the last answer's announced corrections have all arrived

    def keyframe_counts(self) -> dict[str, int]:
        return {"sent": 13, "processed": 13}


class _Supervisor:
    def __init__(self) -> None:
        self.killed: list[str] = []

    def kill_hung(self, name: str, silent_s: float) -> None:
        self.killed.append(name)


def _follower(frontend_silent_s: float, answered_s_ago: float) -> RunFollower:
    """A run's follower without a bus: the frontend last heard ``frontend_silent_s`` ago, the backend's
    last map update ``answered_s_ago``; 30 frames sent by the source, so frames wait for the frontend."""
    now = time.monotonic()
    follower = object.__new__(RunFollower)
    follower.heard = {"frontend": now - frontend_silent_s, "backend": now - answered_s_ago}
    follower.answered_at = now - answered_s_ago
    follower.progressed = {"frontend", "backend"}
    follower.start_timeout_s = 30.0
    follower.source_sent = 30
    follower.log = _Log()
    return follower


def test_the_frontends_hang_clock_starts_again_at_the_backends_answer():
    """Lockstep: a frontend silent for 14 s while it waited for a backend that hung and was rebuilt is
    not hung the moment the answer arrives; one silent that long after an answer is."""
    stop, since = (lambda: False), time.monotonic() - 60.0
    waited = _Supervisor()
    watch_for_hang(_follower(frontend_silent_s=14.0, answered_s_ago=0.01), waited, 10.0, since, stop)
    assert waited.killed == []
    stuck = _Supervisor()
    watch_for_hang(_follower(frontend_silent_s=14.0, answered_s_ago=12.0), stuck, 10.0, since, stop)
    assert stuck.killed == ["frontend"]


def test_a_backend_silent_before_the_correction_its_answer_announced_is_the_hung_one():
    """Lockstep with answers before local BA: the frontend waits for the correction of the keyframe
    the backend answered; when neither has been heard for the hang timeout, the backend owes the work."""
    stop, since = (lambda: False), time.monotonic() - 60.0
    follower = _follower(frontend_silent_s=14.0, answered_s_ago=12.0)
    follower.log.corrections_owed = 1
    supervisor = _Supervisor()
    watch_for_hang(follower, supervisor, 10.0, since, stop)
    assert supervisor.killed == ["backend"]
