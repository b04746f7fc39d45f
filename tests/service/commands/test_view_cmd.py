"""``zenslam view`` finds a run's .rrd files, starts the viewer on them, and prints the command when it cannot."""

from __future__ import annotations

import argparse
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from zenslam.errors import ConfigError
from zenslam.service.commands import view


def _parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="zenslam")
    view.register(parser.add_subparsers(dest="command"))
    return parser.parse_args(["view", *argv])


@pytest.fixture
def run_dir(tmp_path) -> Path:
    run = tmp_path / "run-1"
    run.mkdir()
    for stage in ("source", "frontend", "backend"):
        (run / f"{stage}.rrd").write_bytes(b"rrd")
    (run / "config.yaml").write_text("{}\n")
    return run


@pytest.fixture
def headless(monkeypatch):
    for name in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(view.sys, "platform", "linux")

    def no_spawn(*args, **kwargs):
        raise AssertionError("no viewer may be spawned without a display")

    monkeypatch.setattr(subprocess, "call", no_spawn)


def _fake_viewer(tmp_path: Path, exit_code: int) -> tuple[Path, Path]:
    """An executable that records its arguments, one per line, and exits with ``exit_code``."""
    argv_file = tmp_path / "viewer_argv.txt"
    script = tmp_path / "fake_rerun"
    script.write_text(
        f"#!{sys.executable}\nimport sys\nopen({str(argv_file)!r}, 'w').write('\\n'.join(sys.argv[1:]))\nsys.exit({exit_code})\n"
    )
    script.chmod(script.stat().st_mode | stat.S_IXUSR)
    return script, argv_file


def test_a_run_folder_gives_its_rrd_files_sorted(run_dir):
    assert [p.name for p in view.rrd_files(run_dir)] == ["backend.rrd", "frontend.rrd", "source.rrd"]
    assert view.rrd_files(run_dir / "frontend.rrd") == [run_dir / "frontend.rrd"]


@pytest.mark.parametrize("name", ["nowhere", "config.yaml", "empty"])
def test_bad_targets_name_the_path(run_dir, name):
    (run_dir / "empty").mkdir()
    with pytest.raises(ConfigError, match=str(run_dir / name)):
        view.rrd_files(run_dir / name)


def test_display_detection():
    assert not view.has_display({}, "linux")
    assert view.has_display({"DISPLAY": ":0"}, "linux")
    assert view.has_display({"WAYLAND_DISPLAY": "wayland-0"}, "linux")
    assert view.has_display({}, "darwin")


def test_headless_prints_the_command_to_run_elsewhere(run_dir, headless, capsys):
    assert view.view(_parse([str(run_dir)])) == view.EXIT_NO_DISPLAY
    out = capsys.readouterr().out
    expected = "rerun " + " ".join(str((run_dir / f"{s}.rrd").resolve()) for s in ("backend", "frontend", "source"))
    assert expected in out
    assert f"zenslam view --web {run_dir}" in out


def test_print_command_exits_0_without_starting_a_viewer(run_dir, headless, capsys):
    assert view.view(_parse([str(run_dir), "--print-command", "--viewer", "/opt/rerun"])) == 0
    assert capsys.readouterr().out.strip() == "/opt/rerun " + " ".join(
        str((run_dir / f"{s}.rrd").resolve()) for s in ("backend", "frontend", "source")
    )


def test_with_a_display_the_viewer_gets_every_file(run_dir, tmp_path, monkeypatch):
    monkeypatch.setenv("DISPLAY", ":99")
    viewer, argv_file = _fake_viewer(tmp_path, 0)
    assert view.view(_parse([str(run_dir), "--viewer", str(viewer)])) == 0
    assert argv_file.read_text().splitlines() == [str((run_dir / f"{s}.rrd").resolve()) for s in ("backend", "frontend", "source")]


def test_a_failing_viewer_is_reported_with_the_command(run_dir, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("DISPLAY", ":99")
    viewer, _ = _fake_viewer(tmp_path, 1)
    assert view.view(_parse([str(run_dir / "backend.rrd"), "--viewer", str(viewer)])) == view.EXIT_VIEWER_FAILED
    assert f"{viewer} {(run_dir / 'backend.rrd').resolve()}" in capsys.readouterr().out


def test_a_missing_viewer_is_reported(run_dir, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("DISPLAY", ":99")
    assert view.view(_parse([str(run_dir), "--viewer", str(tmp_path / "no-rerun")])) == view.EXIT_VIEWER_FAILED
    assert "cannot start the viewer" in capsys.readouterr().out


def test_the_default_viewer_is_the_installed_rerun():
    executable = view.viewer_executable()
    assert Path(executable).name == "rerun"


def test_the_web_viewer_listens_on_this_machine_only_unless_asked(run_dir, headless, capsys):
    files = " ".join(str((run_dir / f"{s}.rrd").resolve()) for s in ("backend", "frontend", "source"))
    assert view.view(_parse([str(run_dir), "--web", "--print-command", "--viewer", "/opt/rerun"])) == 0
    assert capsys.readouterr().out.strip() == f"/opt/rerun --web-viewer --bind 127.0.0.1 {files}"
    assert view.view(_parse([str(run_dir), "--web", "--bind", "0.0.0.0", "--print-command", "--viewer", "/opt/rerun"])) == 0
    assert capsys.readouterr().out.strip() == f"/opt/rerun --web-viewer --bind 0.0.0.0 {files}"
    with pytest.raises(ConfigError, match="--bind 'everywhere' is not an IP address"):
        view.view(_parse([str(run_dir), "--web", "--bind", "everywhere", "--print-command"]))


def test_the_web_viewer_is_started_bound_to_loopback(run_dir, tmp_path, headless, monkeypatch):
    viewer, argv_file = _fake_viewer(tmp_path, 0)
    monkeypatch.setattr(subprocess, "call", lambda command: subprocess.run(command).returncode)  # headless forbids spawning
    assert view.view(_parse([str(run_dir), "--web", "--viewer", str(viewer)])) == 0
    assert argv_file.read_text().splitlines()[:3] == ["--web-viewer", "--bind", "127.0.0.1"]


def test_the_command_line_does_not_load_rerun_until_a_command_needs_it():
    # Every subcommand's module is imported to build the parser; `zenslam run`'s hub must not hold rerun.
    code = "import sys; from zenslam.service import cli; cli.build_parser(); print('rerun' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "False"
