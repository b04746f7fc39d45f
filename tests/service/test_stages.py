"""One arrangement of the stages for ``zenslam run`` and ``zenslam stage``: modules, waits, and what ``zenslam stage`` adds."""

from __future__ import annotations

import pytest

from zenslam.errors import ConfigError
from zenslam.service.commands.stage import stage_argv
from zenslam.service.run_config import RecorderConfig, RunConfig
from zenslam.service.stages import STAGE_MODULES, STAGE_NAMES, stage_args


def _waits(args: tuple[str, ...] | list[str]) -> list[str]:
    return [args[i + 1] for i, arg in enumerate(args) if arg == "--wait-for"]


def test_each_stage_waits_for_the_one_that_paces_it_and_for_the_recorder():
    assert _waits(stage_args("backend", recorder=True)) == ["recorder"]
    assert _waits(stage_args("frontend", recorder=True)) == ["backend", "recorder"]
    assert "--map-updates" in stage_args("frontend", recorder=False)
    assert _waits(stage_args("source", recorder=False)) == ["frontend"]
    assert stage_args("recorder", recorder=True) == ("--follow", "source", "--follow", "frontend", "--follow", "backend")


def test_clients_named_to_wait_for_are_waited_for_by_every_publishing_stage():
    for stage in ("backend", "frontend", "source"):
        assert _waits(stage_args(stage, recorder=True, wait_for=("pose-logger",)))[-2:] == ["recorder", "pose-logger"]


def test_every_stage_has_a_module_and_an_unknown_one_is_refused():
    assert set(STAGE_MODULES) == set(STAGE_NAMES) == {"source", "frontend", "backend", "recorder"}
    with pytest.raises(ConfigError, match="'tracker'"):
        stage_args("tracker", recorder=True)


def test_zenslam_stage_gives_the_run_arrangement_then_the_users_arguments():
    given = ["--session", "field1", "--bus-config", "robot.json5", "--wait-for", "logger"]
    argv = stage_argv("source", given, RunConfig())
    assert argv == [*stage_args("source", recorder=True), "--publish-ground-truth", *given]
    without_recorder = RunConfig(recorder=RecorderConfig(enabled=False))
    assert _waits(stage_argv("frontend", given, without_recorder)) == ["backend", "logger"]


def test_a_recorder_stage_records_into_the_sessions_run_folder_unless_told_otherwise():
    assert stage_argv("recorder", ["--session", "field1"], RunConfig())[-4:] == ["--run-dir", "recordings/field1", "--session", "field1"]
    assert "--run-dir" not in stage_argv("recorder", ["--session", "field1", "--output", "x.mcap"], RunConfig())
