"""``zenslam run [SOURCE]``: run the source, frontend and backend processes over zenoh and write recordings/<run-id>/.

This process is the run's hub: it opens the session the stages connect to, subscribes to
frontend/pose, frontend/state, backend/map_update and the stages' statuses (the source's carry the
frames it skipped, by reason, and a strict source's failure) like any other consumer would, starts and supervises the stage processes, and shows progress from the states arriving.
It writes its session name and listening endpoint (``--listen``; default a free loopback port) to
``session.json`` in the run folder, for clients (``zenslam.client``); ``--wait-for NAME`` makes the
stages wait for a client announced as NAME before publishing anything. The stages are those
``zenslam stage`` starts one by one on several machines (``service.stages``).
After the frontend's end of stream it waits, in live mode too, until the backend has processed
every keyframe (its map-update stream ends), asks it for its final keyframe poses
(backend/trajectory), lets the stages exit and writes the outputs.

Interrupted (Ctrl-C reaches only this process: the stages run in process groups of their own), it
stops the stages in the order the data flows, so nothing already sent is lost: the source first
(it ends its stream), the frontend tracks the frames in flight and ends its own, then the backend
ends its stream after the keyframe in hand; the recorder ends once they are gone. The outputs are
written as for a finished run, with ``run.completed: false``. A stage that dies or fails ends the run
the same way, with exit status 2 and the failed stages in ``run.failures``.

The run's configuration is resolved and checked here (its vocabulary files too, by
``service.vocabulary_check``) before any process starts; ``service.run_stages`` starts, follows
and stops the stages, and ``service.run_follower`` takes what they publish into the run's log.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import time
from pathlib import Path

from zenslam.backend.journal import JOURNAL_NAME
from zenslam.config import load_yaml
from zenslam.errors import ConfigError, ProcessError
from zenslam.runtime import bus, environment
from zenslam.runtime.session_file import SessionInfo, write_session_file
from zenslam.runtime.stage import log_cpu_times
from zenslam.runtime.stop import EXIT_FAILED, EXIT_INTERRUPTED, StopFlag
from zenslam.runtime.supervisor import Supervisor
from zenslam.service import mcap_io
from zenslam.service.evaluation.plot import PLANES
from zenslam.service.recorder_config import RECORDING_NAME
from zenslam.service.ros2.run_bridge import (
    Ros2RunBridge,
    add_ros2_publish_arguments,
    domain_id_from,
    open_run_bridge,
    ros2_publish_config,
)
from zenslam.service.run_config import (
    RunConfig,
    apply_orbslam_settings,
    fit_calibration_to_images,
    load_run_config,
    read_orbslam_settings,
)
from zenslam.service.run_failure import RunFailure
from zenslam.service.run_follower import RunFollower
from zenslam.service.run_input import recorded_sensor, run_input
from zenslam.service.run_output import (
    RunLog,
    RunResult,
    evaluation_config_for,
    new_run_id,
    prepare_run_dir,
    write_config,
    write_outputs,
)
from zenslam.service.run_stages import (
    EXIT_WAIT_S,
    POSE_GRACE_S,
    follow_backend,
    follow_frontend,
    report_exits,
    start_stages,
    stop_backend,
)
from zenslam.service.saved_map import check_map_fits, with_map_options
from zenslam.service.sources import Source, is_bus_spec
from zenslam.service.sources.config import DEFAULT_BUS_INPUT
from zenslam.service.vocabulary_check import check_vocabularies
from zenslam.trajectory import Trajectory

logger = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "run",
        help="run SLAM on a dataset or synthetic scene and write recordings/<run-id>/",
        description="Start the source, tracking and mapping processes over zenoh, follow the poses, and write the "
        "trajectories, metrics.json (ATE/RPE when there is ground truth) and a plot to OUTPUT/<run-id>/.",
    )
    parser.add_argument(
        "source", nargs="?", default=None,
        help="kitti:<root>/sequences/NN | euroc:<folder> | tum:<folder> | synthetic[:<scene>[/<sensor>][,laps=N][,seed=N]] | mcap:<run.mcap> "
        "| zenoh:<key> (frames another program publishes, e.g. `zenslam publish`) "
        "(default: source.spec of the config, which defaults to synthetic)",
    )
    parser.add_argument(
        "--connect", action="append", default=None, metavar="ENDPOINT",
        help=f"zenoh:<key> sources: zenoh endpoint where the frames are published (repeatable; source.connect, "
        f"default {DEFAULT_BUS_INPUT}, where `zenslam publish` listens)",
    )
    parser.add_argument(
        "--ground-truth", default=None, metavar="FILE|SPEC",
        help="ground truth to score the run against, e.g. for a zenoh: source: a trajectory file (TUM, EuRoC) or the "
        "spec of the dataset being published (kitti:<root>/sequences/NN)",
    )
    parser.add_argument("--output", type=Path, default=Path("recordings"), help="folder of the run folders (default recordings)")
    parser.add_argument("--config", type=Path, default=None, help=_config_help())
    parser.add_argument("--orbslam-settings", type=Path, default=None, help="ORB-SLAM2/3 settings file: calibration and ORB values")
    pacing = parser.add_mutually_exclusive_group()
    pacing.add_argument(
        "--lockstep", dest="pacing", action="store_const", const="lockstep", default=None,
        help="deterministic, nothing dropped: frames wait for tracking, tracking for each keyframe's map update (the default)",
    )
    pacing.add_argument(
        "--pipelined", dest="pacing", action="store_const", const="pipelined",
        help="nothing dropped, as fast as the machine allows: frames wait for tracking, but mapping runs in parallel "
        "(map updates applied as they arrive; not deterministic)",
    )
    pacing.add_argument(
        "--live", dest="pacing", action="store_const", const="live",
        help="play at the recorded rate (see --rate) like a camera; a slow stage skips frames",
    )
    parser.add_argument(
        "--sensor", choices=("mono", "stereo", "rgbd"), default=None,
        help="play the source as this sensor (source.sensor): mono runs a stereo or RGB-D dataset on its left images; "
        "a synthetic scene renders any (default: the source's own)",
    )
    parser.add_argument("--rate", type=float, default=None, help="live playback speed, multiple of the recorded rate (0: fastest)")
    parser.add_argument("--max-frames", type=int, default=None, help="stop after this many frames")
    parser.add_argument(
        "--strict", action="store_true", default=None,
        help="fail on the first frame that cannot be read or whose stamp does not increase (source.strict); "
        "by default such frames are skipped with a warning and counted in metrics.json",
    )
    parser.add_argument(
        "--no-faults", action="store_true",
        help="ignore source.faults of the config (replays use it: the recorded frames already carry the faults)",
    )
    parser.add_argument("--run-id", default=None, help="name of the run folder and bus session (default: date-time-pid)")
    parser.add_argument("--bus-config", type=Path, default=None, help="zenoh JSON5 config file (routers, other machines)")
    parser.add_argument(
        "--listen", default=None, metavar="ENDPOINT",
        help="zenoh endpoint of the run's hub, e.g. tcp/127.0.0.1:7447, for other programs to connect to (default: a "
        "free loopback port; either way <run folder>/session.json names it with the session)",
    )
    parser.add_argument(
        "--wait-for", action="append", default=[], metavar="NAME",
        help="before publishing anything, the stages wait for the process announcing NAME on the run's session "
        "(a zenslam.client; repeatable): it then receives every message",
    )
    parser.add_argument(
        "--plane", choices=PLANES, default="auto",
        help="world axes of trajectory_top.png (default auto: the ground plane of the ground-truth cameras, held "
        "upright; else the two axes along which the ground truth varies most)",
    )
    parser.add_argument(
        "--save-map", type=Path, default=None, metavar="FILE",
        help="write the backend's map to FILE at the end of the run (backend.save_map; format: zenslam-map, see docs/maps.md)",
    )
    parser.add_argument(
        "--map", type=Path, default=None, metavar="FILE",
        help="start from the saved map FILE (backend.map_file): tracking relocalises into it, then maps on",
    )
    parser.add_argument(
        "--localization", action="store_true",
        help="with --map: track against the map without adding keyframes or points (ORB-SLAM's localisation mode)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_ros2_publish_arguments(parser)
    parser.set_defaults(handler=run, stop_flag=True)  # args.stop: the CLI's Ctrl-C flag, held from its start


def _config_help() -> str:
    """What --config takes, from RunConfig's fields: its top-level keys and its sections (dataclass fields)."""
    defaults = RunConfig()
    names = [f.name for f in dataclasses.fields(RunConfig)]
    sections = [name for name in names if dataclasses.is_dataclass(getattr(defaults, name))]
    keys = [name for name in names if name not in sections]
    top = f"keys {', '.join(keys)} and " if keys else ""
    return f"YAML with {top}sections {', '.join(sections)} (each optional)"


def resolve_config(args: argparse.Namespace) -> RunConfig:
    """The run's configuration: the file (or defaults), then the ORB-SLAM settings, then the options."""
    config = load_run_config(args.config)
    if args.orbslam_settings is not None:
        config = apply_orbslam_settings(config, read_orbslam_settings(args.orbslam_settings))
    source = config.source
    if args.source is not None:
        source = dataclasses.replace(source, spec=args.source)
    if args.sensor is not None:
        source = dataclasses.replace(source, sensor=args.sensor)
    if args.rate is not None:
        source = dataclasses.replace(source, rate=args.rate)
    if args.max_frames is not None:
        source = dataclasses.replace(source, max_frames=args.max_frames)
    if args.strict:
        source = dataclasses.replace(source, strict=True)
    if args.no_faults:
        source = dataclasses.replace(source, faults=())
    if getattr(args, "connect", None):
        source = dataclasses.replace(source, connect=tuple(args.connect))
    if source.spec.startswith("ros2:") and hasattr(args, "ros_domain"):
        source = dataclasses.replace(source, ros_domain=domain_id_from(args.ros_domain))
    bus_config = config.bus
    if args.bus_config is not None:
        bus_config = dataclasses.replace(bus_config, zenoh_config_file=str(args.bus_config))
    mode = config.mode if args.pacing is None else args.pacing
    if args.pacing is None and is_bus_spec(source.spec) and not _config_names_mode(args.config):
        mode = "pipelined"  # live input: mapping in parallel, so tracking keeps up with the camera
    config = dataclasses.replace(config, mode=mode, source=source, bus=bus_config)
    return with_map_options(config, getattr(args, "map", None), getattr(args, "save_map", None), bool(getattr(args, "localization", False)))


def _config_names_mode(path: Path | None) -> bool:
    """True when the YAML file ``path`` sets the run mode itself."""
    return path is not None and "mode" in load_yaml(path)


def _child_env(config: RunConfig) -> dict[str, str]:
    env = dict(os.environ)
    if config.mode != "live":
        # Single-threaded numerics in lockstep runs: same input, same bytes out.
        for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            env[name] = "1"
    return env

def track(
    config: RunConfig, run_id: str, run_dir: Path, config_path: Path, source: Source | None, progress: bool,
    stop: StopFlag | None = None, ground_truth: Trajectory | None = None, ros2: Ros2RunBridge | None = None,
    listen: str | None = None, wait_for: tuple[str, ...] = (),
) -> tuple[RunLog, bool, RunFailure | None]:
    """Start the stages, follow them to the end of stream, and see them exit; returns (log, completed,
    failure): the failure (a stage that died or failed) when the run could not go on, with the log of
    what reached the hub up to then.

    The hub listens on ``listen`` (a zenoh endpoint; default a free loopback port) and writes it with
    the session to ``run_dir/session.json``; the stages wait for the processes named in ``wait_for``
    (clients) before publishing.

    ``stop`` (installed; default: one installed here) ends the run early: the stages wind down in
    order, so every pose the frontend published is in the log, and completed is False.
    ``ground_truth`` (the source's) goes into the recording, so a replay of it is scored too.
    ``source`` None: frames from the bus, their number unknown.
    ``ros2`` publishes the poses and keyframe path on ROS 2 topics as they arrive.
    """
    if listen is not None and config.bus.zenoh_config_file:
        raise ConfigError(f"--listen {listen} and a zenoh config file ({config.bus.zenoh_config_file}): give the endpoint in that file")
    hub = None if config.bus.zenoh_config_file else listen or bus.free_tcp_endpoint()
    hub_bus = config.bus if hub is None else dataclasses.replace(config.bus, listen=(hub,))
    total = None if source is None else len(source)
    if config.source.max_frames is not None:
        total = config.source.max_frames if total is None else min(total, config.source.max_frames)
    owned = stop is None
    stop = StopFlag(quiet=True).install() if stop is None else stop
    failure: RunFailure | None = None
    completed = False
    try:
        with bus.open_session(hub_bus) as session:
            write_session_file(run_dir, SessionInfo(run_id, () if hub is None else (hub,)))
            follower = RunFollower(session, run_id, config, total, progress, ros2)
            follower.log.first_keyframe_id = config.frontend.tracking.local_map.keyframe_id_start
            try:
                supervisor = Supervisor(run_dir, run_id, config_path, hub, env=_child_env(config))
                with supervisor, bus.declare_alive(session, run_id, "run"):
                    try:
                        started = start_stages(supervisor, session, config, run_dir, stop, ground_truth, follower, wait_for)
                        if started:
                            log_cpu_times("at stream start")
                            follow_frontend(follower, supervisor, stop, config.supervision)
                            follow_backend(follower, supervisor, stop, config.supervision)
                            stop_backend(follower, supervisor, session, run_id)
                            log_cpu_times("at stream end")
                        statuses = supervisor.wait_exit(EXIT_WAIT_S)
                        follower.poll_backend()  # the stages' last statuses: the source's final skipped-frame counts
                        report_exits(supervisor, stop, statuses)
                        log = follower.log
                        completed = started and log.ended and log.backend_ended and not log.stopped_stages and not stop()
                    except ProcessError as exc:
                        # A stage died or failed: what reached the hub is kept. Leaving this block stops
                        # the other stages (the recorder finishes run.mcap); the caller writes the outputs.
                        frame = len(follower.log.frames)
                        follower.drain(time.monotonic() + POSE_GRACE_S)  # also lets a stage that reported its failure exit
                        if follower.log.source_failure is not None:  # it said so before exiting: let it exit
                            supervisor.wait_for_exit("source", POSE_GRACE_S)
                        failure = RunFailure(str(exc), frame, [{**f, "frame": frame} for f in supervisor.failures()])
            finally:
                follower.close()
    finally:
        if owned:
            stop.uninstall()
    return follower.log, completed, failure


def _summary(result: RunResult, log: RunLog) -> list[str]:
    counts = log.frame_counts()
    keyframes = log.keyframe_counts()
    lines = [
        f"frames {counts['frames']}: {counts['tracked_ok']} tracked, {counts['lost_frames']} lost, "
        f"{keyframes['sent']} keyframes ({keyframes['processed']} processed by the backend)",
    ]
    stream = log.stream_timing()
    if "realtime_factor" in stream:
        lines.append(
            f"stream {stream['stream_s']:.1f} s for {stream['data_duration_s']:.1f} s of data "
            f"({stream['realtime_factor']:.2f}x real time)"
        )
    if counts["tracked_ok"] == 0 and counts["initializing_frames"]:
        reasons = ", ".join(f"{count} {reason}" for reason, count in counts["initializing_reasons"].items())
        lines.append(f"no map was made: tracking never initialised ({reasons})")
    skipped = log.skipped_frames()
    if skipped["total"]:
        reasons = ", ".join(f"{count} {reason}" for reason, count in skipped["reasons"].items())
        lines.append(f"frames skipped by the source: {skipped['total']} ({reasons})")
    dropped = log.dropped_frames()
    if dropped["total"]:
        lines.append(f"frames dropped because tracking was busy (the newest was tracked): {dropped['total']}")
    if result.evaluation is not None:
        ate, rpe = result.evaluation.ate, result.evaluation.rpe
        lines.append(f"ATE RMSE {ate.rmse_m:.4f} m ({ate.alignment} alignment, {ate.matched_poses} poses)")
        lines.append(f"RPE {rpe.trans_rmse_m:.4f} m, {rpe.rot_rmse_deg:.3f} deg per {rpe.delta:g} {rpe.delta_unit}")
    else:
        lines.append(f"ATE not available: {result.evaluation_error or 'the source has no ground truth'}")
    lines.append(f"wrote {result.run_dir}")
    return lines


def _interrupted_line(log: RunLog, total: int | None, run_dir: Path, here: bool) -> str:
    """The one line an interrupted run ends with; ``here``: this process got the signal (else a stage did)."""
    frames = log.frame_counts()["frames"]
    of_total = "" if total is None else f" of {total}"
    trajectory = log.trajectory()
    by = "" if here else f" (the {' and the '.join(log.stopped_stages)} stopped by a signal of its own)"
    return (
        f"interrupted at frame {frames}{of_total}{by}: wrote the {0 if trajectory is None else len(trajectory)} tracked "
        f"poses to {run_dir} (metrics.json run.completed: false)"
    )


def run(args: argparse.Namespace) -> int:
    """Resolve the config, prepare the run folder, track, write the outputs, print the accuracy.

    Interrupted (SIGINT or SIGTERM, from ``args.stop`` set by the CLI, at any moment), it still writes
    every output, marks metrics.json ``run.completed: false``, ends with one line saying so, and
    returns 130.
    """
    if getattr(args, "stop", None) is not None:
        return _run(args, args.stop)
    stop = StopFlag(quiet=True).install()  # called other than through the CLI
    try:
        return _run(args, stop)
    finally:
        stop.uninstall()


def _run(args: argparse.Namespace, stop: StopFlag) -> int:
    """``run`` with the installed stop flag ``stop``."""
    config = resolve_config(args)
    check_vocabularies(config)  # a bad file would stop a stage only once the others are up
    given = run_input(config.source.spec, config.source.sensor, config.source.max_frames, getattr(args, "ground_truth", None))
    if given.image_size is not None:
        config = fit_calibration_to_images(config, *given.image_size)  # a bus source's is fitted to its first frame
    calibration = config.source.calibration or (given.source.calibration if given.source is not None else None)
    check_map_fits(config, calibration, given.sensor)
    run_id = args.run_id or new_run_id()
    run_dir = prepare_run_dir(args.output, run_id)
    config_path = write_config(run_dir, config)
    count = "frames from the bus" if given.total is None else f"{given.total} frames"
    logger.info("run %s: %s (%s, %s) -> %s", run_id, given.name, given.sensor or "sensor of the input", count, run_dir)
    total, ground_truth = given.total, given.ground_truth
    with open_run_bridge(ros2_publish_config(args)) as ros2:
        log, completed, failure = track(
            config, run_id, run_dir, config_path, given.source, not args.no_progress, stop, ground_truth, ros2,
            listen=getattr(args, "listen", None), wait_for=tuple(getattr(args, "wait_for", ())),
        )
        if ros2 is not None:
            ros2.publish_path(log.keyframe_trajectory())  # the backend's final keyframe poses
    recording = run_dir / RECORDING_NAME
    if config.recorder.enabled and not recording.exists():
        mcap_io.RecordingWriter(recording).finish()  # stopped before the recorder started: nothing crossed the bus
    extra = {"run": {
        "run_id": run_id, "source": config.source.spec, "mode": config.mode, "completed": completed, **log.stream_timing(),
        "failures": [] if failure is None else failure.stages,
        "restarts": len(log.restarts), "restart_events": log.restart_events(),
        "environment": environment.describe(),
    }}
    sensor = given.sensor or recorded_sensor(recording) or "stereo"  # a bus source's sensor: what was recorded
    evaluation_config = evaluation_config_for(config.evaluation, sensor)
    result = write_outputs(run_dir, log, ground_truth, evaluation_config, extra, plane=args.plane)
    if completed:
        # The backend's journal serves only to rebuild a crashed backend: a finished run's map is in
        # the outputs. An interrupted or failed run keeps it (what the backend was given, in order).
        (run_dir / JOURNAL_NAME).unlink(missing_ok=True)
    for line in _summary(result, log):
        print(line)
    if failure is not None:
        logger.error("%s", failure.error)
        logger.error("%s", failure.line(run_dir))
        return EXIT_FAILED
    if completed:
        return 0
    logger.warning("%s", _interrupted_line(log, total, run_dir, here=stop()))
    return EXIT_INTERRUPTED
