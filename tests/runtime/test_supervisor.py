"""The supervisor starts real child processes, notices failures with their output, and leaves no orphans."""

from __future__ import annotations

import os
import signal
import textwrap
import time
from pathlib import Path

import pytest

from zenslam.errors import ConfigError, ProcessError
from zenslam.runtime import bus
from zenslam.runtime.stage import StopFlag
from zenslam.runtime.supervisor import MALLOC_TUNABLES, ProcessSpec, SupervisionConfig, Supervisor

# A stage-like child: parses the common arguments, joins the bus, announces itself, waits for a stop.
STAGE_CHILD = """
import argparse, sys, time
from pathlib import Path
from zenslam.runtime import bus
from zenslam.runtime.stage import StopFlag, add_process_arguments, bus_config_with, setup_process_logging
setup_process_logging(False, "dummy")  # the stop flag logs the signal that set it
parser = argparse.ArgumentParser()
add_process_arguments(parser)
parser.add_argument("--name", required=True)
parser.add_argument("--marker", type=Path, required=True)
args = parser.parse_args()
stop = StopFlag(args.parent_pid).install()
with bus.open_session(bus_config_with(bus.BusConfig(), args.connect)) as session:
    with bus.declare_alive(session, args.session, args.name):
        while not stop():
            time.sleep(0.01)
args.marker.write_text("stopped cleanly")
"""

CRASHING_CHILD = """
import sys
print("loading the frontend", flush=True)
print("Traceback: ValueError: calibration is nonsense", file=sys.stderr, flush=True)
sys.exit(3)
"""

# Prints its arguments; fails with status 3 (a crash) at its first start, 2 (its own error) once restarted.
ARGV_CHILD = """
import sys
print("argv:", " ".join(sys.argv[1:]), flush=True)
sys.exit(2 if "--restart" in sys.argv else 3)
"""

# Ignores SIGINT and SIGTERM, and starts a grandchild in its process group that does the same.
STUBBORN_CHILD = """
import signal, subprocess, sys, time
from pathlib import Path
signal.signal(signal.SIGINT, signal.SIG_IGN)
signal.signal(signal.SIGTERM, signal.SIG_IGN)
if "--grandchild" not in sys.argv:
    g = subprocess.Popen([sys.executable, "-m", "stubborn_child", "--grandchild"])
    Path(sys.argv[sys.argv.index("--pidfile") + 1]).write_text(str(g.pid))
while True:
    time.sleep(0.05)
"""

# Told to stop while it is still "importing" (before its StopFlag is installed): the stop waits.
SLOW_START_CHILD = """
import argparse, time
from pathlib import Path
from zenslam.runtime.stage import StopFlag, add_process_arguments
parser = argparse.ArgumentParser()
add_process_arguments(parser)
parser.add_argument("--dir", type=Path, required=True)
args = parser.parse_args()
(args.dir / "importing").write_text("yes")
while not (args.dir / "go").exists():
    time.sleep(0.01)
stop = StopFlag(args.parent_pid).install()
(args.dir / "marker").write_text("stopped" if stop() else "not stopped")
"""

ENV_CHILD = """
import os
print("GLIBC_TUNABLES=" + os.environ.get("GLIBC_TUNABLES", "<unset>"), flush=True)
"""


@pytest.fixture
def modules(tmp_path: Path) -> dict[str, str]:
    """Child modules importable by ``python -m`` through PYTHONPATH."""
    pkg = tmp_path / "children"
    pkg.mkdir()
    for name, text in {"stage_child": STAGE_CHILD, "crashing_child": CRASHING_CHILD, "stubborn_child": STUBBORN_CHILD, "env_child": ENV_CHILD,
                       "slow_start_child": SLOW_START_CHILD, "argv_child": ARGV_CHILD}.items():
        (pkg / f"{name}.py").write_text(textwrap.dedent(text))
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(pkg), env.get("PYTHONPATH", "")])
    return env


def _supervisor(tmp_path: Path, env: dict[str, str], hub: str | None = None) -> Supervisor:
    return Supervisor(tmp_path / "run", "sup-test", tmp_path / "config.yaml", hub, env=env)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_stage_comes_up_on_the_bus_and_stops_cleanly_on_sigint(tmp_path, modules):
    hub = bus.free_tcp_endpoint()
    marker = tmp_path / "marker"
    with bus.open_session(bus.BusConfig(listen=(hub,))) as session:
        with _supervisor(tmp_path, modules, hub) as supervisor:
            supervisor.start(ProcessSpec("dummy", "stage_child", ("--name", "dummy", "--marker", str(marker))))
            supervisor.wait_until_alive(session, ["dummy"], timeout_s=30.0)
            assert supervisor.returncode("dummy") is None
            supervisor.stop(grace_s=60.0)
            assert supervisor.returncode("dummy") == 0
            assert "received SIGINT" in supervisor.log_tail("dummy")  # it stopped within the grace, before any SIGTERM
            assert "SIGTERM" not in supervisor.log_tail("dummy")
        assert marker.read_text() == "stopped cleanly"
        assert bus.alive_processes(session, "sup-test") == set()


def test_a_stop_sent_while_a_stage_imports_waits_for_its_stop_flag(tmp_path, modules):
    """Stages start with SIGINT blocked: no KeyboardInterrupt in an import, the flag is set once installed."""
    with _supervisor(tmp_path, modules) as supervisor:
        supervisor.start(ProcessSpec("slow", "slow_start_child", ("--dir", str(tmp_path))))
        deadline = time.monotonic() + 30.0
        while not (tmp_path / "importing").exists():
            assert time.monotonic() < deadline and supervisor.returncode("slow") is None, supervisor.log_tail("slow")
            time.sleep(0.01)
        supervisor.request_stop(["slow"])
        (tmp_path / "go").write_text("")
        assert supervisor.wait_exit(timeout_s=30.0) == {"slow": 0}, supervisor.log_tail("slow")
    assert (tmp_path / "marker").read_text() == "stopped"
    assert "Traceback" not in (tmp_path / "run" / "logs" / "slow.log").read_text()


def test_a_crash_is_reported_with_the_tail_of_its_output(tmp_path, modules):
    with _supervisor(tmp_path, modules) as supervisor:
        supervisor.start(ProcessSpec("frontend", "crashing_child"))
        supervisor.wait_exit(timeout_s=30.0)
        with pytest.raises(ProcessError, match=r"(?s)frontend exited with status 3.*calibration is nonsense"):
            supervisor.check()
        assert "loading the frontend" in supervisor.log_tail("frontend")  # stdout is kept too
    assert (tmp_path / "run" / "logs" / "frontend.log").is_file()


def test_waiting_for_a_child_that_crashes_fails_fast(tmp_path, modules):
    with bus.open_session(bus.BusConfig()) as session, _supervisor(tmp_path, modules) as supervisor:
        supervisor.start(ProcessSpec("frontend", "crashing_child"))
        started = time.monotonic()
        with pytest.raises(ProcessError, match="status 3"):
            supervisor.wait_until_alive(session, ["frontend"], timeout_s=300.0)
        # The crash ends the wait, not the timeout: a generous deadline, far below the 300 s.
        assert time.monotonic() - started < 150.0


def test_stubborn_children_and_their_children_are_killed(tmp_path, modules):
    pidfile = tmp_path / "grandchild.pid"
    with _supervisor(tmp_path, modules) as supervisor:
        supervisor.start(ProcessSpec("stubborn", "stubborn_child", ("--pidfile", str(pidfile))))
        deadline = time.monotonic() + 20.0
        while not pidfile.exists() or not pidfile.read_text():
            assert time.monotonic() < deadline, "the stubborn child did not start its grandchild"
            time.sleep(0.05)
        grandchild = int(pidfile.read_text())
        supervisor.stop(grace_s=0.3, term_s=0.3)
        assert supervisor.returncode("stubborn") == -signal.SIGKILL
    deadline = time.monotonic() + 5.0
    while _pid_alive(grandchild) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _pid_alive(grandchild)


def test_children_get_the_session_config_hub_and_parent(tmp_path):
    supervisor = Supervisor(tmp_path, "s1", tmp_path / "config.yaml", "tcp/127.0.0.1:7000")
    args = supervisor.common_args()
    assert args[args.index("--session") + 1] == "s1"
    assert args[args.index("--connect") + 1] == "tcp/127.0.0.1:7000"
    assert args[args.index("--config") + 1] == str(tmp_path / "config.yaml")
    assert int(args[args.index("--parent-pid") + 1]) == os.getpid()


def test_a_child_notices_it_lost_its_parent():
    assert not StopFlag(parent_pid=os.getppid())()
    assert StopFlag(parent_pid=os.getppid() + 100_000)()


def test_the_same_stage_cannot_start_twice(tmp_path, modules):
    with _supervisor(tmp_path, modules) as supervisor:
        supervisor.start(ProcessSpec("frontend", "crashing_child"))
        with pytest.raises(ProcessError, match="already running"):
            supervisor.start(ProcessSpec("frontend", "crashing_child"))


@pytest.mark.parametrize("given", [None, "glibc.malloc.arena_max=2"])
def test_children_get_the_malloc_tunables_unless_the_caller_set_their_own(tmp_path, modules, given):
    env = dict(modules)
    env.pop("GLIBC_TUNABLES", None)
    if given is not None:
        env["GLIBC_TUNABLES"] = given
    with _supervisor(tmp_path, env) as supervisor:
        supervisor.start(ProcessSpec("env", "env_child"))
        supervisor.wait_exit(timeout_s=30.0)
        # On x86-64 the pinned math kernels add glibc.cpu.hwcaps after them (tests/runtime/test_cpu_kernels.py).
        assert f"GLIBC_TUNABLES={given or MALLOC_TUNABLES}" in supervisor.log_tail("env")


def test_a_restartable_stage_is_restarted_a_bounded_number_of_times_within_the_window(tmp_path, modules):
    """Each failure of a restartable stage starts it again with ``--restart N``, its log kept and
    appended to; one failure more than ``max_restarts`` within the window raises as ``check`` does.
    A stage that is not restartable raises at its first failure."""
    config = SupervisionConfig(max_restarts=2, restart_window_s=600.0)
    with _supervisor(tmp_path, modules) as supervisor:
        supervisor.start(ProcessSpec("backend", "crashing_child", restartable=True))
        for restart in (1, 2):
            supervisor.wait_exit(timeout_s=30.0)
            assert supervisor.restart_failed(config) == [{"stage": "backend", "exit_code": 3, "restart": restart}]
        supervisor.wait_exit(timeout_s=30.0)
        with pytest.raises(ProcessError, match=r"backend exited with status 3 after 2 restart\(s\) within 600 s"):
            supervisor.restart_failed(config)
        log = (tmp_path / "run" / "logs" / "backend.log").read_text()
        assert log.count("calibration is nonsense") == 3 and "---- restart 2 of backend ----" in log
    with _supervisor(tmp_path / "second", modules) as supervisor:
        supervisor.start(ProcessSpec("frontend", "crashing_child"))
        supervisor.wait_exit(timeout_s=30.0)
        with pytest.raises(ProcessError, match=r"frontend exited with status 3; the end"):
            supervisor.restart_failed(config)
    assert SupervisionConfig(max_restarts=0)  # 0 is allowed: no restarts
    with pytest.raises(ConfigError, match="max_restarts"):
        SupervisionConfig(max_restarts=-1)


def test_a_restart_gets_its_resume_arguments_and_a_stage_reporting_its_own_error_is_not_restarted(tmp_path, modules):
    """The restart of a stage passes the arguments saying where to resume (a source: the newest frame
    tracked); a stage that exits with status 2 reported its own error (bad input, a bad setting),
    which a restart would meet again: the run fails at once."""
    config = SupervisionConfig(max_restarts=3)
    with _supervisor(tmp_path, modules) as supervisor:
        supervisor.start(ProcessSpec("source", "argv_child", ("--wait-for", "frontend"), restartable=True))
        supervisor.wait_exit(timeout_s=30.0)
        resume = {"source": ("--resume-after", "41"), "backend": ("--unrelated",)}
        assert supervisor.restart_failed(config, resume) == [{"stage": "source", "exit_code": 3, "restart": 1}]
        supervisor.wait_exit(timeout_s=30.0)
        with pytest.raises(ProcessError, match=r"source exited with status 2; the end"):
            supervisor.restart_failed(config, resume)
        log = (tmp_path / "run" / "logs" / "source.log").read_text()
    assert "--wait-for frontend --restart 1 --resume-after 41" in log and "--unrelated" not in log
