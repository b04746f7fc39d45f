"""``zenslam stage ROLE``: the arguments it gives a stage started by hand."""

from __future__ import annotations

from zenslam.config import load_yaml
from zenslam.service.commands.stage import _with_resolved_config, stage_argv
from zenslam.service.run_config import RecorderConfig, RunConfig, load_run_config
from zenslam.service.stages import stage_args


def _waits(args: list[str]) -> list[str]:
    return [args[i + 1] for i, arg in enumerate(args) if arg == "--wait-for"]


def test_zenslam_stage_gives_the_run_arrangement_then_the_users_arguments():
    given = ["--session", "field1", "--bus-config", "robot.json5", "--wait-for", "logger"]
    argv = stage_argv("source", given, RunConfig())
    assert argv == [*stage_args("source", recorder=True), "--publish-ground-truth", *given]
    without_recorder = RunConfig(recorder=RecorderConfig(enabled=False))
    assert _waits(stage_argv("frontend", given, without_recorder)) == ["backend", "logger"]


def test_a_recorder_stage_records_into_the_sessions_run_folder_unless_told_otherwise():
    assert stage_argv("recorder", ["--session", "field1"], RunConfig())[-4:] == ["--run-dir", "recordings/field1", "--session", "field1"]
    assert "--run-dir" not in stage_argv("recorder", ["--session", "field1", "--output", "x.mcap"], RunConfig())


def test_a_config_with_earlier_keys_reaches_the_stage_resolved(tmp_path):
    """A stage reads its sections as written: a file naming a key of an earlier version is passed on
    resolved (beside the given file, where the backend keeps its journal); a resolved file as it is."""
    path = tmp_path / "run.yaml"
    path.write_text("backend:\n  local_mapping:\n    min_covisibility_weight: 20\n")
    config = load_run_config(path)
    given = _with_resolved_config(["--session", "s", "--config", str(path)], path, config)
    resolved = tmp_path / "run.resolved.yaml"
    assert given == ["--session", "s", "--config", str(resolved)]
    assert load_yaml(resolved)["map"]["min_covisibility_weight"] == 20
    assert load_run_config(resolved) == config
    assert _with_resolved_config(["--config", str(resolved)], resolved, load_run_config(resolved)) == ["--config", str(resolved)]
