"""The stage skeleton: one start-up for every stage process (command line, stop flag, bus section, exit status)."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from zenslam.errors import ConfigError
from zenslam.runtime import bus, stage
from zenslam.runtime.stage import EXIT_STAGE_ERROR, StageStart, add_wait_for_argument, run_stage


class _Flag:
    """A stop flag that installs no signal handlers in the test process."""

    def __init__(self, parent_pid: int | None = None) -> None:
        self.parent_pid = parent_pid

    def install(self) -> _Flag:
        return self

    def __call__(self) -> bool:
        return False

    def keep_going(self) -> bool:
        return True


@pytest.fixture(autouse=True)
def _no_process_setup(monkeypatch):
    monkeypatch.setattr(stage, "StopFlag", _Flag)
    monkeypatch.setattr(stage, "setup_process_logging", lambda verbose, name: None)


def test_the_stage_gets_its_arguments_its_stop_flag_and_the_bus_section(tmp_path: Path):
    config = tmp_path / "run.yaml"
    config.write_text("bus:\n  start_timeout_s: 7.5\nmode: live\n")
    started: list[StageStart] = []

    def arguments(parser):
        add_wait_for_argument(parser, "the test starts")

    argv = ["--session", "s1", "--config", str(config), "--wait-for", "frontend", "--parent-pid", "42"]
    assert run_stage("backend", "The test stage.\n\nMore.", started.append, argv, arguments) == 0
    (start,) = started
    assert start.name == "backend" and start.args.session == "s1" and start.args.wait_for == ["frontend"]
    assert start.stop.parent_pid == 42
    assert start.bus_config == bus.BusConfig(start_timeout_s=7.5)
    assert start.mode() == "live" and start.section("bus", bus.BusConfig).start_timeout_s == 7.5


def test_a_project_error_is_logged_by_the_stage_and_ends_it_with_the_stage_error_status(caplog):
    def fails(start: StageStart) -> None:
        raise ConfigError("backend.nice=99 must be 0..19")

    with caplog.at_level(logging.ERROR):
        assert run_stage("backend", __doc__, fails, ["--session", "s1"]) == EXIT_STAGE_ERROR
    (record,) = [r for r in caplog.records if "backend.nice=99" in r.getMessage()]
    assert record.name == __name__  # the stage's own logger, as its log lines read


def test_any_other_error_is_a_bug_and_propagates():
    def breaks(start: StageStart) -> None:
        raise KeyError("oops")

    with pytest.raises(KeyError):
        run_stage("recorder", __doc__, breaks, ["--session", "s1"])


def test_the_session_joins_the_bus_with_the_process_endpoints_added(tmp_path: Path, monkeypatch):
    opened: list[bus.BusConfig] = []
    monkeypatch.setattr(bus, "open_session", opened.append)
    zenoh_file = tmp_path / "zenoh.json5"

    def run(start: StageStart) -> None:
        start.open_session(["tcp/10.0.0.2:7447"])

    argv = ["--session", "s1", "--connect", "tcp/127.0.0.1:7447", "--bus-config", str(zenoh_file)]
    assert run_stage("source", __doc__, run, argv) == 0
    assert opened[0].connect == ("tcp/127.0.0.1:7447", "tcp/10.0.0.2:7447")
    assert opened[0].zenoh_config_file == str(zenoh_file)
