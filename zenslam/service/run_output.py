"""What a run leaves in recordings/<run-id>/: the resolved config, trajectories, metrics.json and a plot.

``RunLog`` collects what the run command receives: frontend/state and frontend/pose, the backend's
map updates (counted) and status timings, the backend's final keyframe poses, and the frames the
source skipped (its source/status ``skipped`` counts). ``write_outputs``
turns them into ``trajectory.tum`` (every frame tracked ok, as tracked: what a live consumer of
frontend/pose got), ``trajectory_final.tum`` (ORB-SLAM's saved trajectory: each of those frames
kept relative to its reference keyframe and composed with that keyframe's final pose, so mapping's
later corrections reach every frame), ``keyframes.tum`` (the backend's final keyframe poses; the
frontend's when no backend answered), ``metrics.json`` (ATE/RPE of the tracked trajectory, ATE of
the final one as ``ate_final``, when there is ground truth; ``loops``: loop candidates verified,
accepted and rejected (with ``false_accepted`` against ground truth) and the error where the path
returns to its start, see ``evaluation.loops``; tracking and backend timing, frame and keyframe
counts, ``skipped_frames``: ``{"total": N, "reasons": {"corrupt": n, ...}}`` (a bus source adds the
messages it could not use: ``malformed``, ``oversized``, ``unpaired``, ...), ``dropped_frames``:
``{"total": N, "source": n, "frontend": n}`` (frames that arrived while tracking was busy, passed
over for a newer one: by a bus source before sending, or by a live-mode frontend: the frames it never
saw, less those the source skipped), ``relocalisation``:
``{"count": N, "frames_lost": N, "new_maps": N}``) and ``trajectory_top.png``.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from array import array
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import get_args

import numpy as np

from zenslam.errors import ConfigError, TrajectoryError
from zenslam.runtime.stop import STOPPED
from zenslam.schemas import codec, keys
from zenslam.service.evaluation.loop_acceptance import acceptance_counts
from zenslam.service.evaluation.loops import loops_section
from zenslam.service.evaluation.metrics import Evaluation, EvaluationConfig, evaluate
from zenslam.service.evaluation.plot import Plane, save_evaluation_plot
from zenslam.service.evaluation.report import METRICS_FILENAME, write_metrics
from zenslam.service.evaluation.trajectory_io import write_tum
from zenslam.service.frame_table import FrameStates, FrameTable
from zenslam.service.run_config import RunConfig, run_config_to_yaml
from zenslam.service.sources.frame_stream import SkipReason
from zenslam.trajectory import Trajectory

logger = logging.getLogger(__name__)

CONFIG_FILENAME = "config.yaml"
TRAJECTORY_FILENAME = "trajectory.tum"
FINAL_TRAJECTORY_FILENAME = "trajectory_final.tum"
KEYFRAMES_FILENAME = "keyframes.tum"
PLOT_FILENAME = "trajectory_top.png"
_NO_POSE = Trajectory(np.zeros(0, dtype=np.int64), np.zeros((0, 4, 4)))


def new_run_id() -> str:
    """A fresh run id: local date and time plus the process id, e.g. ``20260314-091502-4242``."""
    return f"{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}"


def prepare_run_dir(output_root: Path, run_id: str) -> Path:
    """Create ``output_root/run_id``; an existing non-empty folder is an error (runs never overwrite)."""
    keys.session_prefix(run_id)  # the run id is also the bus session name: it must be a valid key chunk
    run_dir = Path(output_root) / run_id
    if run_dir.exists() and any(run_dir.iterdir()):
        raise ConfigError(f"run folder {run_dir} already holds files; choose another --run-id or --output")
    run_dir.mkdir(parents=True, exist_ok=True)
    return run_dir


def write_config(run_dir: Path, config: RunConfig) -> Path:
    """Write the resolved configuration as ``config.yaml`` (the stage processes read this very file)."""
    path = Path(run_dir) / CONFIG_FILENAME
    path.write_text(run_config_to_yaml(config))
    return path


def _timing_table(samples: dict[str, list[float]], count_name: str) -> dict[str, dict[str, float]]:
    """Per step: mean, median and max milliseconds, and how many samples."""
    return {
        name: {
            "mean_ms": float(np.mean(v)),
            "median_ms": float(np.median(v)),
            "max_ms": float(np.max(v)),
            count_name: len(v),
        }
        for name, v in sorted(samples.items())
    }


class RunLog:
    """The tracking states and poses a run received, keyed by frame index and stamp, and what it heard
    from the backend."""

    def __init__(self, live: bool = False) -> None:
        self.live = live  # a live-mode run: the frontend's own drops count (else its gaps are the source's skips)
        # Every frame's state (without its timings, kept apart in ``_timings``) and pose, as columns:
        # a long run holds one of each per frame.
        self.frames = FrameTable()
        self._timings: dict[str, array] = {}  # tracking step -> milliseconds of each frame that ran it
        self._first_step: tuple[int, float] | None = None  # the first frame's index and its tracking ms
        self.ended = False  # the frontend's end of stream arrived
        self.updated_keyframes: list[int] = []  # keyframe id of every backend map update received, in order
        self.corrected_poses: dict[int, np.ndarray] = {}  # keyframe id -> its newest T_world_cam from a map update
        self.removed_keyframes: set[int] = set()  # keyframe ids a map update removed (culled)
        self.backend_ended = False  # the backend's end of stream arrived
        # Updates the last answer announced that have not arrived (its local-mapping correction and
        # the loop corrections that announces), counted as the frontend counts what it waits for.
        self.corrections_owed = 0
        self.backend_timings: dict[int, dict[str, float]] = {}  # keyframes processed -> ms per step of that one
        self.backend_keyframes: codec.KeyframeTrajectoryMessage | None = None  # the backend's final keyframe poses
        self.backend_queue_max = 0  # most keyframes the backend reported waiting in its inbox after a step
        self.source_skipped: dict[str, int] = {}  # frames the source did not send, by reason (its latest count)
        self.source_failure: str | None = None  # what the source said when it failed (e.g. strict and a bad frame)
        self.dropped: dict[str, int] = {}  # stage -> frames it passed over for a newer one (its latest status)
        self.stopped_stages: list[str] = []  # stages whose last status says they stopped before their input's end
        self.loops: list[codec.LoopMessage] = []  # backend/loop: every verified loop candidate, in order
        # Stages the supervisor restarted after a crash or hang: {stage, signal | exit_code, [hung_s], restart, frame}.
        self.restarts: list[dict[str, object]] = []
        # The frontend's first keyframe id: 0, or past a saved map's ids when the run started from one
        # (its keyframes, with smaller ids, are the saved map's, not this run's).
        self.first_keyframe_id = 0
        # Seconds on the follower's monotonic clock at which the first tracking state and the last
        # state or map update arrived: the stream's span (a recording's log times are data stamps).
        self.first_state_s: float | None = None
        self.last_message_s: float | None = None

    @property
    def states(self) -> dict[int, codec.TrackingStateMessage]:
        """Frame index -> its state (without timings), built anew on each call: for tests and tools."""
        states = self.frames.states()
        return {int(states.index[k]): states.message(k) for k in range(len(states))}

    @property
    def poses(self) -> dict[int, np.ndarray]:
        """Stamp (ns) -> T_world_cam of every pose received, built anew on each call: for tests and tools."""
        stamps, poses = self.frames.poses()
        return dict(zip(stamps.tolist(), poses))

    def note_arrival(self, received_s: float, state: bool = False) -> None:
        """A tracking state (``state``) or map update arrived at ``received_s`` seconds."""
        if state and self.first_state_s is None:
            self.first_state_s = received_s
        self.last_message_s = received_s if self.last_message_s is None else max(self.last_message_s, received_s)

    def stream_timing(self) -> dict[str, float]:
        """``stream_s``: from the first frame sent to the last map update applied, and ``realtime_factor``:
        the data's duration over ``stream_s`` (above 1: faster than the camera); empty without states.

        The first frame was sent before its state arrived by the time the frontend took to track it,
        which its state reports; the data's duration is its stamps' span plus one frame period.
        """
        if self.first_state_s is None or self.last_message_s is None or not len(self.frames):
            return {}
        first_ms = self._first_step[1] if self._first_step is not None else 0.0
        stream_s = self.last_message_s - self.first_state_s + first_ms / 1e3
        stamps = np.sort(self.frames.states().stamp_ns)
        period_ns = float(np.median(np.diff(stamps))) if len(stamps) > 1 else 0.0
        duration_s = (float(stamps[-1] - stamps[0]) + period_ns) / 1e9
        out = {"stream_s": stream_s, "data_duration_s": duration_s}
        if stream_s > 0 and duration_s > 0:
            out["realtime_factor"] = duration_s / stream_s
        return out

    def add_map_update(self, update: object) -> None:
        """Count a backend/map_update message (a MapUpdate, or the stream's end)."""
        if isinstance(update, codec.EndOfStream):
            self.backend_ended = True
        else:
            if update.answers_keyframe:
                self.updated_keyframes.append(int(update.keyframe_id))
                self.corrections_owed = int(update.corrections_following)
            else:
                self.corrections_owed = max(self.corrections_owed - 1, 0) + int(update.corrections_following)
            for correction in update.keyframes:
                self.corrected_poses[int(correction.id)] = np.asarray(correction.T_world_cam, dtype=float)
            self.removed_keyframes.update(np.asarray(update.removed_keyframe_ids).tolist())

    def add_status(self, status: codec.StageStatusMessage) -> None:
        """Note a stage that ended before its input did; keep the backend's per-keyframe timings."""
        if status.state == "finished" and status.detail == STOPPED and status.stage not in self.stopped_stages:
            self.stopped_stages.append(status.stage)
        if status.stage in ("source", "frontend") and status.dropped:
            self.dropped[status.stage] = int(status.dropped)  # each status carries the total so far
        if status.stage == "backend":
            self.add_backend_status(status)
        elif status.stage == "source":
            self.add_source_status(status)

    def add_backend_status(self, status: codec.StageStatusMessage) -> None:
        """Keep the per-step timings of each keyframe the backend reports."""
        if status.state == "running" and status.timings_ms:
            self.backend_timings[status.processed] = dict(status.timings_ms)
            self.backend_queue_max = max(self.backend_queue_max, status.queue_depth)

    def add_source_status(self, status: codec.StageStatusMessage) -> None:
        """Keep the source's skipped-frame counts (each status carries the totals so far) and its failure."""
        self.source_skipped = dict(status.skipped)  # statuses arrive in order, lossless: the last one is the newest
        if status.state == "failed":
            self.source_failure = status.detail or "the source failed without saying why; see its log"

    def skipped_frames(self) -> dict[str, object]:
        """The ``skipped_frames`` section of metrics.json: the total and the count per reason."""
        reasons = {reason: int(count) for reason, count in sorted(self.source_skipped.items())}
        return {"total": sum(reasons.values()), "reasons": reasons}

    def dropped_frames(self) -> dict[str, int]:
        """The ``dropped_frames`` section of metrics.json: the total, by the source and by the frontend."""
        source, frontend = self.dropped.get("source", 0), 0
        if self.live:  # the frontend counts gaps in the frame numbers: frames it dropped, and frames never sent
            not_sent = sum(n for reason, n in self.source_skipped.items() if reason in get_args(SkipReason))
            frontend = max(0, self.dropped.get("frontend", 0) - not_sent)
        return {"total": source + frontend, "source": source, "frontend": frontend}

    def keyframe_counts(self) -> dict[str, int]:
        """Keyframes the frontend sent and the backend processed (updates received). The frontend numbers
        its keyframes 0, 1, 2, ... as it makes them, and a state names the keyframe its frame made, so
        the newest id counts the ones made from earlier frames too (a monocular map's first keyframe)."""
        newest = self.frames.newest_keyframe_id
        # A restarted backend may answer the keyframe in hand when its predecessor died a second time.
        return {"sent": max(newest + 1 - self.first_keyframe_id, 0), "processed": len(set(self.updated_keyframes))}

    def backend_timing(self) -> dict[str, dict[str, float]]:
        """Per local-mapping step: mean, median and max milliseconds over the keyframes processed."""
        samples: dict[str, list[float]] = {}
        for processed in sorted(self.backend_timings):
            for name, ms in self.backend_timings[processed].items():
                samples.setdefault(name, []).append(ms)
        return _timing_table(samples, "keyframes")

    def add_state(self, state: codec.TrackingStateMessage) -> None:
        first = not self.frames.has(state.index)
        if not self.frames.add_state(state):
            return
        if state.timings_ms and first:
            for name, ms in state.timings_ms.items():
                self._timings.setdefault(name, array("d")).append(ms)
        if self._first_step is None or state.index <= self._first_step[0]:
            self._first_step = (state.index, state.timings_ms.get("total", 0.0))

    def add_pose(self, pose: codec.StampedPose) -> None:
        self.frames.add_pose(pose.stamp_ns, pose.T_world_cam)

    def missing_poses(self) -> int:
        """Poses announced by a state (has_pose) that have not arrived."""
        return self.frames.missing_poses()

    def _posed(self, states: FrameStates, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(rows of ``states`` in ``keep`` whose pose arrived, by stamp; their T_world_cam)."""
        stamps, poses = self.frames.poses()
        rows = np.flatnonzero(keep)
        at = np.searchsorted(stamps, states.stamp_ns[rows])
        found = at < len(stamps)
        found[found] = stamps[at[found]] == states.stamp_ns[rows[found]]
        rows, at = rows[found], at[found]
        order = np.argsort(states.stamp_ns[rows], kind="stable")
        return rows[order], poses[at[order]]

    def trajectory(self) -> Trajectory | None:
        """T_world_cam of every frame tracked ok, by stamp; None if there is none."""
        states = self.frames.states()
        rows, poses = self._posed(states, states.is_state("ok"))
        return Trajectory(states.stamp_ns[rows], poses) if len(rows) else None

    def final_trajectory(self) -> Trajectory | None:
        """ORB-SLAM's saved trajectory: every frame tracked ok as its reference keyframe's final pose
        times the camera in that keyframe's frame. A keyframe's final pose is the backend's answer
        (for a culled keyframe, where its spanning-tree parent now puts it), else its last corrected
        pose; a frame whose keyframe was never corrected keeps the pose it was tracked with (then
        nothing moved that keyframe)."""
        final = dict(self.corrected_poses)
        backend = self.backend_keyframes
        if backend is not None:
            final.update(zip(np.asarray(backend.culled_keyframe_ids).tolist(), backend.culled_T_world_cam))
            final.update(zip(np.asarray(backend.keyframe_ids).tolist(), backend.T_world_cam))
        states = self.frames.states()
        rows, tracked = self._posed(states, states.is_state("ok"))
        if not len(rows):
            return None
        poses = []
        for k, T in zip(rows.tolist(), tracked):
            reference, T_reference_cam = final.get(int(states.reference_keyframe_id[k])), states.T_reference_cam[k]
            poses.append(T if reference is None or np.isnan(T_reference_cam[0, 0]) else reference @ T_reference_cam)
        return Trajectory(states.stamp_ns[rows], np.stack(poses))

    def keyframe_trajectory(self) -> Trajectory | None:
        """The backend's final poses of this run's keyframes when it answered; else the keyframes the frontend made,
        less those a map update removed, each at its newest pose from a map update (as tracked when
        no update moved it): the map as far as the backend's updates told."""
        backend = self.backend_keyframes
        if backend is not None:
            mine = np.asarray(backend.keyframe_ids) >= self.first_keyframe_id  # not a saved map's keyframes
            if not np.any(mine):
                return None
            stamps, poses = np.asarray(backend.stamps_ns, dtype=np.int64)[mine], np.asarray(backend.T_world_cam)[mine]
            order = np.argsort(stamps, kind="stable")
            return Trajectory(stamps[order], poses[order])
        states = self.frames.states()
        made = (states.keyframe_id >= 0) & ~np.isin(states.keyframe_id, list(self.removed_keyframes))
        rows, tracked = self._posed(states, made)
        if not len(rows):
            return None
        poses = [self.corrected_poses.get(int(states.keyframe_id[k]), T) for k, T in zip(rows.tolist(), tracked)]
        return Trajectory(states.stamp_ns[rows], np.stack(poses))

    def timing(self) -> dict[str, dict[str, float]]:
        """Per tracking step: mean, median and max milliseconds over the frames that ran it."""
        return _timing_table({name: list(ms) for name, ms in self._timings.items()}, "frames")

    def frame_counts(self) -> dict[str, object]:
        """The ``frames``, ``lost_frames``, ``lost_reasons``, ``initializing_*`` and ``keyframes`` sections of metrics.json."""
        states = self.frames.states()
        lost = states.is_state("lost")
        reasons = Counter(reason or "unknown" for reason in states.lost_reasons(lost))
        waiting = Counter(reason for reason in states.lost_reasons(states.is_state("initializing")) if reason)
        return {
            "frames": len(states),
            "tracked_ok": int(np.count_nonzero(states.is_state("ok"))),
            "lost_frames": int(np.count_nonzero(lost)),
            "lost_reasons": dict(sorted(reasons.items())),
            # Frames without a map yet (or starting one over), by what they waited for, e.g. waiting_for_parallax.
            "initializing_frames": sum(waiting.values()),
            "initializing_reasons": dict(sorted(waiting.items())),
            "keyframes": int(np.count_nonzero(states.keyframe_id >= 0)),
        }

    def restart_events(self) -> list[dict[str, object]]:
        """The stage restarts (``restarts``), each frontend restart with ``frames_lost``: the frames
        between the last pose before the crash and the first after it, when the restarted frontend
        had relocalised into the backend's map (None: it never did), and ``relocalised_at``, that frame."""
        states = self.frames.states()
        posed = states.index[states.has_pose].tolist()
        events = []
        for event in self.restarts:
            if event.get("stage") == "frontend" and "last_frame_index" in event:
                crash = int(event["last_frame_index"])  # type: ignore[call-overload]
                before = [i for i in posed if i <= crash]
                after = next((i for i in posed if i > crash), None)
                last = before[-1] if before else -1
                event = {**event, "frames_lost": None if after is None else after - last - 1, "relocalised_at": after}
            events.append(event)
        return events

    def relocalisation_counts(self) -> dict[str, int]:
        """The ``relocalisation`` section of metrics.json: ``count``, frames that found the map again
        after tracking was lost (or, in localisation mode, ran on visual odometry); ``frames_lost``, frames without a pose once tracking had started
        (lost, or waiting to start a new map); ``new_maps``, maps started over after a loss."""
        states = self.frames.states()
        posed = np.flatnonzero(states.has_pose)
        first = int(posed[0]) if len(posed) else len(states)
        after = np.arange(len(states)) > first
        return {
            "count": int(np.count_nonzero(states.relocalised)),
            "frames_lost": int(np.count_nonzero(~states.has_pose[first:])),
            "new_maps": int(np.count_nonzero(after & states.is_state("initializing") & states.has_pose)),
        }


@dataclass(frozen=True)
class RunResult:
    """What ``write_outputs`` wrote, and the evaluation when there was ground truth."""

    run_dir: Path
    evaluation: Evaluation | None
    evaluation_error: str | None  # why there is no evaluation despite ground truth
    files: tuple[Path, ...]


def write_outputs(
    run_dir: Path,
    log: RunLog,
    ground_truth: Trajectory | None,
    evaluation_config: EvaluationConfig,
    extra: dict[str, object] | None = None,
    plane: Plane = "auto",
) -> RunResult:
    """Write trajectory.tum, trajectory_final.tum, keyframes.tum, metrics.json and (with ground truth)
    trajectory_top.png, drawn in ``plane`` (``auto``: see ``plot_plane``)."""
    run_dir = Path(run_dir)
    files: list[Path] = []
    estimate = log.trajectory()
    final = log.final_trajectory()
    keyframes = log.keyframe_trajectory()
    outputs = ((TRAJECTORY_FILENAME, estimate), (FINAL_TRAJECTORY_FILENAME, final), (KEYFRAMES_FILENAME, keyframes))
    for name, trajectory in outputs:
        # Every file is written, without a pose when there is none (a run stopped before its first frame).
        files.append(write_tum(run_dir / name, _NO_POSE if trajectory is None else trajectory))
    evaluation, error = None, None
    final_evaluation = None
    if ground_truth is not None and estimate is not None:
        try:
            evaluation = evaluate(estimate, ground_truth, evaluation_config)
            final_evaluation = evaluate(final, ground_truth, evaluation_config)
        except TrajectoryError as exc:
            error = str(exc)
            logger.warning("no ATE for this run: %s", exc)
    elif ground_truth is not None:
        error = "no frame was tracked, so there is nothing to compare with the ground truth"
    sections: dict[str, object] = {"timing": log.timing(), **log.frame_counts()}
    sections["keyframes"] = log.keyframe_counts()
    sections["skipped_frames"] = log.skipped_frames()
    sections["dropped_frames"] = log.dropped_frames()
    sections["relocalisation"] = log.relocalisation_counts()
    sections["keyframes_from"] = "backend" if log.backend_keyframes is not None else "frontend"
    sections["backend_timing"] = log.backend_timing()
    sections["backend_queue_depth_max"] = log.backend_queue_max
    if final_evaluation is not None:
        sections["ate_final"] = final_evaluation.to_json()["ate"]
    metres_per_unit = evaluation.ate.scale if evaluation is not None and evaluation.ate.scale else 1.0  # Sim(3): monocular
    sections["loops"] = {
        **acceptance_counts(log.loops, ground_truth, metres_per_unit), **loops_section(evaluation, final_evaluation)
    }
    sections.update(extra or {})
    if error is not None:
        sections["evaluation_error"] = error
    files.append(write_metrics(run_dir / METRICS_FILENAME, evaluation, **sections))
    if evaluation is not None:
        files.append(save_evaluation_plot(run_dir / PLOT_FILENAME, evaluation, plane=plane))
    return RunResult(run_dir, evaluation, error, tuple(files))


def evaluation_config_for(config: EvaluationConfig, sensor: str) -> EvaluationConfig:
    """Monocular runs have no metric scale: compare them after a Sim(3) alignment, others after SE(3)."""
    if sensor == "mono" and config.alignment == "se3":
        return dataclasses.replace(config, alignment="sim3")
    return config
