"""Ctrl-C at any moment of ``zenslam run`` loses nothing: the real command, interrupted with SIGINT.

Each test starts ``zenslam run`` in a session of its own (as a terminal runs a foreground job),
waits for a moment of the run to be observable (the command's imports under way, a stage starting,
frames tracked, the backend still mapping after the frontend's end of stream), sends SIGINT to the
process group (what a terminal's Ctrl-C does), to the command alone, or to every process of the
run, and checks what the run left: exit status 130, one line saying so, no traceback anywhere,
a trajectory with every pose the frontend published, keyframes.tum, metrics.json marked as not
completed, and a recording that opens as is.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from zenslam.schemas import codec
from zenslam.service import mcap_io
from zenslam.service.recorder_config import RecorderConfig

pytestmark = pytest.mark.integration

DEADLINE_S = 600.0  # for each moment to come and for the command to exit: generous, the stages start slowly on a busy machine
INTERRUPTED_LINE = "interrupted at frame"

# Pipelined, a keyframe at every frame and a deliberately slow local BA (every iteration run): the
# backend is still mapping queued keyframes when the frontend ends its stream.
SLOW_BACKEND_YAML = """\
mode: pipelined
frontend:
  keyframe:
    max_frames: 1
    ref_ratio_stereo: 1.0
    max_queued_keyframes: 3
backend:
  local_mapping:
    defer_when_queued: false
  local_ba:
    robust_iterations: 40
    refine_iterations: 80
    relative_error_tolerance: 0.0
    absolute_error_tolerance: 0.0
"""


class _Run:
    """A ``zenslam run`` in its own session, with its output collected as it comes."""

    def __init__(self, tmp_path: Path, source: str, *options: str, run_id: str = "it-interrupt"):
        self.run_dir = tmp_path / run_id
        command = [sys.executable, "-m", "zenslam.service.cli", "run", source, "--output", str(tmp_path),
                   "--run-id", run_id, *options]  # fmt: skip
        self.popen = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
        self._out: list[bytes] = []
        self._err: list[bytes] = []
        self._readers = [
            threading.Thread(target=self._read, args=(self.popen.stdout, self._out), daemon=True),
            threading.Thread(target=self._read, args=(self.popen.stderr, self._err), daemon=True),
        ]
        for reader in self._readers:
            reader.start()

    @staticmethod
    def _read(stream, into: list[bytes]) -> None:
        while chunk := stream.read1(65536):
            into.append(chunk)

    @property
    def stdout(self) -> str:
        return b"".join(self._out).decode(errors="replace")

    @property
    def stderr(self) -> str:
        return b"".join(self._err).decode(errors="replace")

    def wait_for(self, what: str, condition: Callable[[], bool]) -> None:
        """Wait until ``condition()``; fail if the run exits first or the deadline passes."""
        deadline = time.monotonic() + DEADLINE_S
        while not condition():
            assert self.popen.poll() is None, f"the run exited ({self.popen.returncode}) before {what}:\n{self.stderr[-3000:]}"
            assert time.monotonic() < deadline, f"no {what} within {DEADLINE_S:.0f} s:\n{self.stderr[-3000:]}"
            time.sleep(0.005)

    def frames_tracked(self) -> int:
        """The last count the progress bar showed (frames whose state the command received)."""
        counts = re.findall(r"(\d+)/\d+ \[", self.stderr)
        return int(counts[-1]) if counts else 0

    def children(self) -> list[int]:
        """The pids of the run's stage processes (children of the command)."""
        pids = []
        for stat in Path("/proc").glob("[0-9]*/stat"):
            try:
                fields = stat.read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == self.popen.pid:
                pids.append(int(stat.parent.name))
        return pids

    def finish(self) -> int:
        code = self.popen.wait(timeout=DEADLINE_S)
        for reader in self._readers:
            reader.join(timeout=30.0)
        return code


def _imports_under_way(run: _Run) -> bool:
    """The command has loaded zenoh (its command modules are importing) and made no run folder yet."""
    maps = Path(f"/proc/{run.popen.pid}/maps")
    try:
        return "zenoh" in maps.read_text() or (run.run_dir / "config.yaml").exists()
    except OSError:
        return False


def _pose_lines(path: Path) -> int:
    return sum(1 for line in path.read_text().splitlines() if line and not line.startswith("#"))


def _check_what_was_left(run: _Run, code: int) -> dict:
    """The run's promises after an interrupt; returns its metrics."""
    stdout, stderr = run.stdout, run.stderr
    context = f"stdout:\n{stdout[-2000:]}\nstderr:\n{stderr[-4000:]}"
    assert code == 130, context
    assert "Traceback" not in stdout + stderr, context
    assert sum(INTERRUPTED_LINE in line for line in stderr.splitlines()) == 1, context
    for log in (run.run_dir / "logs").glob("*.log"):
        assert "Traceback" not in log.read_text(errors="replace"), f"{log}:\n{log.read_text(errors='replace')[-4000:]}"
    metrics = json.loads((run.run_dir / "metrics.json").read_text())
    assert metrics["run"]["completed"] is False
    recording = run.run_dir / "run.mcap"
    assert mcap_io.has_summary(recording), "run.mcap was not finished (no summary)"
    states = [decoded for _, decoded in mcap_io.iter_decoded(recording, ["/frontend/state"])]
    published = sum(1 for _ in mcap_io.iter_messages(recording, ["/frontend/pose"]))
    assert published == sum(1 for s in states if not isinstance(s, codec.EndOfStream) and s.has_pose)
    # Every pose the frontend published for a frame tracked ok is in trajectory.tum.
    tracked_ok = sum(1 for s in states if not isinstance(s, codec.EndOfStream) and s.has_pose and s.state == "ok")
    assert _pose_lines(run.run_dir / "trajectory.tum") == metrics["tracked_ok"] == tracked_ok
    assert metrics["frames"] == len(states) - (1 if states and isinstance(states[-1], codec.EndOfStream) else 0)
    assert (run.run_dir / "keyframes.tum").is_file()
    if metrics["frames"]:
        assert _pose_lines(run.run_dir / "keyframes.tum") >= 1
        assert isinstance(states[-1], codec.EndOfStream), "the frontend's end of stream is not in run.mcap"
    return metrics


def _interrupt(run: _Run, whom: str) -> None:
    if whom == "group":
        os.killpg(run.popen.pid, signal.SIGINT)
    elif whom == "command":
        os.kill(run.popen.pid, signal.SIGINT)
    else:  # every process of the run, as a terminal that signals the whole session would
        for pid in [run.popen.pid, *run.children()]:
            try:
                os.kill(pid, signal.SIGINT)
            except ProcessLookupError:
                pass


@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="needs /proc to see the command's imports")
def test_ctrl_c_during_the_imports(tmp_path):
    run = _Run(tmp_path, "synthetic", "--max-frames", "200")
    run.wait_for("the command's imports", lambda: _imports_under_way(run))
    _interrupt(run, "group")
    metrics = _check_what_was_left(run, run.finish())
    assert metrics["frames"] == 0


def test_ctrl_c_while_the_stages_start(tmp_path):
    """The recorder is up and the backend is importing: it gets the stop held until its handler is in."""
    run = _Run(tmp_path, "synthetic", "--max-frames", "200")
    run.wait_for("the backend's start", lambda: (run.run_dir / "logs" / "backend.log").exists())
    _interrupt(run, "group")
    metrics = _check_what_was_left(run, run.finish())
    assert metrics["frames"] == 0
    assert not (run.run_dir / "logs" / "source.log").exists()  # no stage is started after the interrupt


@pytest.mark.parametrize("whom", ["group", "command", "every process"])
def test_ctrl_c_mid_stream(tmp_path, whom):
    run = _Run(tmp_path, "synthetic", "--max-frames", "200")
    run.wait_for("5 frames tracked", lambda: run.frames_tracked() >= 5)
    _interrupt(run, whom)
    metrics = _check_what_was_left(run, run.finish())
    assert 5 <= metrics["frames"] < 200


@pytest.mark.slow(11)
def test_ctrl_c_while_the_backend_drains(tmp_path):
    config = tmp_path / "slow_backend.yaml"
    config.write_text(SLOW_BACKEND_YAML)
    run = _Run(tmp_path, "synthetic", "--max-frames", "30", "--config", str(config))
    waiting = re.compile(r"waiting for the backend: (\d+) of (\d+) keyframes")
    run.wait_for("the backend's drain", lambda: waiting.search(run.stderr) is not None)
    _interrupt(run, "group")
    metrics = _check_what_was_left(run, run.finish())
    processed, sent = map(int, waiting.search(run.stderr).groups())
    assert processed < sent, "the backend had caught up: this run did not test a drain"
    assert metrics["frames"] == 30  # the frontend had ended: every frame was tracked
    assert metrics["keyframes"]["processed"] < metrics["keyframes"]["sent"]


@pytest.mark.parametrize("moment", ["start-up", "mid-stream"])
def test_ctrl_c_on_the_kitti_clip(tmp_path, kitti_root, moment):
    run = _Run(tmp_path, f"kitti:{kitti_root / 'sequences' / '06'}")
    if moment == "start-up":
        run.wait_for("the backend's start", lambda: (run.run_dir / "logs" / "backend.log").exists())
    else:
        run.wait_for("10 frames tracked", lambda: run.frames_tracked() >= 10)
    _interrupt(run, "group")
    metrics = _check_what_was_left(run, run.finish())
    assert metrics["frames"] < 51


def _stage_pid(run: _Run, module: str) -> int:
    """The pid of the run's stage process started as ``python -m module``."""
    for pid in run.children():
        try:
            if module in Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace"):
                return pid
        except OSError:
            continue
    raise AssertionError(f"no stage process runs {module}")


NO_RESTARTS_YAML = "supervision:\n  max_restarts: 0\n"


# The stages whose failure a run reports; the frontend's case goes through the supervisor's same path,
# so CI runs it after the README's command (extended), to keep that command a few minutes long.
STAGES = [
    pytest.param("backend", "zenslam.backend.node", id="backend-zenslam.backend.node"),
    pytest.param("frontend", "zenslam.frontend.node", id="frontend-zenslam.frontend.node", marks=pytest.mark.extended),
]


@pytest.mark.parametrize(("stage", "module"), STAGES)
def test_a_stage_killed_mid_stream_fails_the_run_and_its_outputs_are_written(tmp_path, stage, module):
    """SIGKILL of a stage (an out-of-memory kill, a segfault) with restarts disabled: exit 2, one
    line naming the stage and the signal, and the run folder holds what reached the hub, as after
    an interrupt."""
    config = tmp_path / "no-restarts.yaml"
    config.write_text(NO_RESTARTS_YAML)
    run = _Run(tmp_path, "synthetic", "--max-frames", "200", "--config", str(config))
    run.wait_for("5 frames tracked", lambda: run.frames_tracked() >= 5)
    os.kill(_stage_pid(run, module), signal.SIGKILL)
    code = run.finish()
    stdout, stderr = run.stdout, run.stderr
    context = f"stdout:\n{stdout[-2000:]}\nstderr:\n{stderr[-4000:]}"
    assert code == 2, context
    assert "Traceback" not in stdout + stderr, context
    assert sum("the run failed at frame" in line and f"the {stage}: signal SIGKILL" in line for line in stderr.splitlines()) == 1, context
    metrics = json.loads((run.run_dir / "metrics.json").read_text())
    assert metrics["run"]["completed"] is False
    assert metrics["run"]["restarts"] == 0
    failures = metrics["run"]["failures"]
    assert [(f["stage"], f["signal"]) for f in failures] == [(stage, "SIGKILL")], failures
    assert failures[0]["frame"] >= 5
    assert (run.run_dir / "backend.journal").is_file(), "a failed run keeps the backend's journal"
    assert mcap_io.has_summary(run.run_dir / "run.mcap"), "run.mcap was not finished (no summary)"
    assert _pose_lines(run.run_dir / "trajectory.tum") == metrics["tracked_ok"] >= 5
    assert (run.run_dir / "keyframes.tum").is_file()


@pytest.mark.parametrize(("stage", "module"), STAGES)
def test_a_stopped_stage_is_caught_as_hung_and_fails_the_run_with_its_outputs(tmp_path, stage, module):
    """SIGSTOP (a stage that hangs) with restarts disabled: after supervision.hang_timeout_s without a
    word from it while its input waits, the run kills it and fails as for a crash, naming the stage as hung."""
    config = tmp_path / "hang.yaml"
    config.write_text("supervision:\n  hang_timeout_s: 4\n  max_restarts: 0\n")
    run = _Run(tmp_path, "synthetic", "--max-frames", "200", "--config", str(config))
    run.wait_for("5 frames tracked", lambda: run.frames_tracked() >= 5)
    pid = _stage_pid(run, module)
    os.kill(pid, signal.SIGSTOP)
    try:
        code = run.finish()
    finally:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    context = f"stdout:\n{run.stdout[-2000:]}\nstderr:\n{run.stderr[-4000:]}"
    assert code == 2, context
    assert "Traceback" not in run.stdout + run.stderr, context
    assert any(f"the {stage}: no progress for" in line for line in run.stderr.splitlines()), context
    metrics = json.loads((run.run_dir / "metrics.json").read_text())
    assert metrics["run"]["completed"] is False
    [failure] = metrics["run"]["failures"]
    assert failure["stage"] == stage and failure["signal"] == "SIGKILL" and failure["hung_s"] >= 4, failure
    assert mcap_io.has_summary(run.run_dir / "run.mcap")
    assert _pose_lines(run.run_dir / "trajectory.tum") == metrics["tracked_ok"] >= 5


def _completed_with_one_restart(run: _Run, code: int, stage: str) -> tuple[dict, dict]:
    """What a run whose ``stage`` was killed (or killed as hung) and restarted once leaves: exit 0,
    no traceback, completed, the restart counted, a finished run.mcap; returns metrics.json and the
    restart event."""
    context = f"stdout:\n{run.stdout[-2000:]}\nstderr:\n{run.stderr[-4000:]}"
    assert code == 0, context
    assert "Traceback" not in run.stdout + run.stderr, context
    metrics = json.loads((run.run_dir / "metrics.json").read_text())
    assert metrics["run"]["completed"] is True and metrics["run"]["failures"] == []
    assert metrics["run"]["restarts"] == 1
    [event] = metrics["run"]["restart_events"]
    assert event["stage"] == stage and event["signal"] == "SIGKILL" and event["restart"] == 1, event
    assert mcap_io.has_summary(run.run_dir / "run.mcap")
    return metrics, event


def _completed_with_one_backend_restart(run: _Run, code: int) -> dict:
    """What a run whose backend was restarted once leaves: as ``_completed_with_one_restart``, the
    map rebuilt from the journal, both rerun files, no journal left; returns the restart event."""
    _, event = _completed_with_one_restart(run, code, "backend")
    assert "rebuilt the map from the journal" in (run.run_dir / "logs" / "backend.log").read_text()
    assert (run.run_dir / "backend.restart1.rrd").is_file() and (run.run_dir / "backend.rrd").is_file()
    assert not (run.run_dir / "backend.journal").exists(), "a finished run keeps no journal"
    return event


@pytest.mark.extended  # two runs side by side: CI runs it after the README's command
def test_a_backend_killed_mid_stream_is_restarted_and_the_lockstep_outputs_are_those_of_an_unharmed_run(tmp_path):
    """SIGKILL of the backend half-way through a lockstep run: the supervisor restarts it, it
    rebuilds its map from its journal, and the run ends as an unharmed run of the same input does,
    byte for byte (the two runs go side by side)."""
    options = ("--max-frames", "120")
    unharmed = _Run(tmp_path, "synthetic", *options, run_id="it-unharmed")  # its own session
    run = _Run(tmp_path, "synthetic", *options)
    run.wait_for("40 frames tracked", lambda: run.frames_tracked() >= 40)
    os.kill(_stage_pid(run, "zenslam.backend.node"), signal.SIGKILL)
    event = _completed_with_one_backend_restart(run, run.finish())
    assert event["frame"] >= 40
    assert unharmed.finish() == 0, unharmed.stderr[-3000:]
    for name in ("trajectory.tum", "keyframes.tum"):
        assert (run.run_dir / name).read_bytes() == (unharmed.run_dir / name).read_bytes(), name


@pytest.mark.extended  # waits out a 10 s hang: CI runs it after the README's command
def test_a_stopped_backend_is_caught_as_hung_and_restarted(tmp_path):
    """SIGSTOP of the backend: after supervision.hang_timeout_s of silence while keyframes wait, it is
    killed and restarted like a crashed one, and the run completes."""
    config = tmp_path / "hang.yaml"
    # 10 s: well above a local-mapping step on a loaded machine (a second restart would fail the count).
    config.write_text("supervision:\n  hang_timeout_s: 10\n")
    run = _Run(tmp_path, "synthetic", "--max-frames", "80", "--config", str(config))
    run.wait_for("20 frames tracked", lambda: run.frames_tracked() >= 20)
    pid = _stage_pid(run, "zenslam.backend.node")
    stopped_at = time.monotonic()
    os.kill(pid, signal.SIGSTOP)
    run.wait_for("the backend killed as hung", lambda: not Path(f"/proc/{pid}").exists() or _zombie(pid))
    caught_s = time.monotonic() - stopped_at
    event = _completed_with_one_backend_restart(run, run.finish())
    assert event["hung_s"] >= 10, event
    assert caught_s < 10 + 30, f"the hung backend was killed {caught_s:.0f} s after it stopped"
    metrics = json.loads((run.run_dir / "metrics.json").read_text())
    assert metrics["tracked_ok"] == 80


@pytest.mark.extended  # CI runs it after the README's command
def test_a_killed_frontend_is_restarted_and_relocalises_into_the_backends_map(tmp_path):
    """SIGKILL of the frontend mid-stream: the supervisor restarts it, the source sends it the frames
    in flight again, it relocalises into the backend's map, and tracking goes on with its keyframe
    and point ids past the map's; the frames between the last pose before the crash and the first
    after it are counted in the restart event."""
    run = _Run(tmp_path, "synthetic", "--max-frames", "120")
    run.wait_for("40 frames tracked", lambda: run.frames_tracked() >= 40)
    os.kill(_stage_pid(run, "zenslam.frontend.node"), signal.SIGKILL)
    metrics, event = _completed_with_one_restart(run, run.finish(), "frontend")
    assert event["relocalised_at"] is not None and 0 <= event["frames_lost"] <= 10, event
    assert metrics["relocalisation"]["count"] >= 1
    assert metrics["tracked_ok"] >= 120 - 10
    assert metrics["keyframes"]["processed"] == metrics["keyframes"]["sent"], metrics["keyframes"]
    assert metrics["ate"]["rmse_m"] < 0.02, metrics["ate"]  # an unharmed run: 4 mm
    log = (run.run_dir / "logs" / "frontend.log").read_text()
    assert "---- restart 1 of frontend ----" in log and "entering the backend's map" in log
    assert (run.run_dir / "frontend.restart1.rrd").is_file()


@pytest.mark.extended  # two runs side by side: CI runs it after the README's command
def test_a_killed_source_resumes_at_the_first_frame_not_tracked_and_lockstep_outputs_are_unharmed(tmp_path):
    """SIGKILL of the source mid-stream: the supervisor restarts it after the newest frame tracked,
    every frame is tracked once, in order (a frame in flight sent again is refused as not newer),
    so the lockstep outputs are those of an unharmed run, byte for byte."""
    options = ("--max-frames", "80")
    unharmed = _Run(tmp_path, "synthetic", *options, run_id="it-unharmed")
    run = _Run(tmp_path, "synthetic", *options)
    run.wait_for("30 frames tracked", lambda: run.frames_tracked() >= 30)
    os.kill(_stage_pid(run, "zenslam.service.source_node"), signal.SIGKILL)
    metrics, event = _completed_with_one_restart(run, run.finish(), "source")
    assert event["last_frame_index"] >= 29, event
    assert metrics["frames"] == metrics["tracked_ok"] == 80
    assert "resuming after frame" in (run.run_dir / "logs" / "source.log").read_text()
    assert unharmed.finish() == 0, unharmed.stderr[-3000:]
    for name in ("trajectory.tum", "keyframes.tum"):
        assert (run.run_dir / name).read_bytes() == (unharmed.run_dir / name).read_bytes(), name


def _zombie(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True


def _one_stretch(missing: list[int], topic: str) -> None:
    """Frames lost on ``topic`` (frame indices, sorted) are one run of consecutive frames, or none."""
    if missing:
        assert missing == list(range(missing[0], missing[-1] + 1)), f"{topic}: frames lost in more than one stretch: {missing}"


@pytest.mark.extended  # CI runs it after the README's command
def test_a_killed_recorder_is_restarted_and_the_recording_stays_one_readable_file(tmp_path):
    """SIGKILL of the recorder: the run goes on and completes, the restarted recorder carries its
    predecessor's finished chunks over into run.mcap, which is finished, replays and exports."""
    from zenslam.service.commands.export import export_recording

    run = _Run(tmp_path, "synthetic", "--max-frames", "120")
    run.wait_for("40 frames tracked", lambda: run.frames_tracked() >= 40)
    os.kill(_stage_pid(run, "zenslam.service.recorder"), signal.SIGKILL)
    _completed_with_one_restart(run, run.finish(), "recorder")
    recording = run.run_dir / "run.mcap"
    assert not list(run.run_dir.glob("run.crashed*"))
    assert "carried" in (run.run_dir / "logs" / "recorder.log").read_text()
    states = [decoded for _, decoded in mcap_io.iter_decoded(recording, ["/frontend/state"])]
    assert isinstance(states[-1], codec.EndOfStream)
    # Lost: the crashed recorder's open chunk (recorder.chunk_size of messages, a few frames here) and
    # the outputs sent while it restarted (the source holds its frames meanwhile): one stretch of
    # frames on each topic, and no more camera frames than one chunk holds.
    assert len(states) - 1 >= 100, len(states)
    _one_stretch(sorted(set(range(120)) - {state.index for state in states[:-1]}), "/frontend/state")
    frames = {
        message.frame.index: len(stored.data)
        for stored, message in mcap_io.iter_decoded(recording, [mcap_io.SENSOR_FRAME_TOPIC])
        if isinstance(message, codec.FrameMessage)
    }
    lost = sorted(set(range(120)) - set(frames))
    _one_stretch(lost, mcap_io.SENSOR_FRAME_TOPIC)
    assert (len(lost) - 1) * min(frames.values()) < RecorderConfig().chunk_size, f"{len(lost)} camera frames lost"
    exported = export_recording(recording, tmp_path / "export")
    assert exported.poses == len(states) - 1 and exported.keyframes > 0
