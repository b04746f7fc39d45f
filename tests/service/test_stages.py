"""One arrangement of the stages for ``zenslam run`` and ``zenslam stage``: their modules and what each waits for."""

from __future__ import annotations

import pytest

from zenslam.errors import ConfigError
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
