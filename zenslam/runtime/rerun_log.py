"""The rerun recording of the frontend and backend processes: one ``<run>/<stage>.rrd`` each, one recording per run.

This is the only module that configures rerun. The frontend and the backend each open a ``StageRecording``
(application id "zenslam", recording id = the run id, so the viewer opens the files of a run as
one recording) saved next to the run's ``config.yaml``, with the default blueprint of
``default_blueprint``. Data is logged on explicit timelines only: ``frame`` (the source's frame
index) and ``sensor_time`` (the frame's stamp); rerun's automatic wall-clock ``log_time`` and
``log_tick`` are switched off and the wall-clock start-time property is not sent, so two lockstep
runs log the same data (the timing entities aside, which hold measured milliseconds).

The source and the recorder log nothing to rerun: the frontend logs the images it tracks (under its
keypoints), and the rerun SDK with the pyarrow it loads costs each process that imports it about
70 MB. The recorder's run.mcap holds every bus message, for Foxglove or a replay.

Entity paths mirror the packages (the frontend's are listed in ``zenslam.frontend.rerun_log``)::

    frontend/...                    the frontend's image, keypoints, pose, state, counts and timings
    backend/keyframes               keyframe centres (Points3D, world, metres), per keyframe
    backend/map_points              every map point (Points3D, world, metres), at most once per
                                    ``map_period_s`` of sensor time, and the final map
    backend/covisibility            covisibility edges between keyframe centres (LineStrips3D), as map_points
    backend/trajectory              the keyframe centres in time order (LineStrips3D)
    backend/local_ba/before|after   local BA graph error before and after optimisation (Scalars)
    backend/counts/<name>           keyframes, map points, keyframe queue depth (Scalars)
    backend/timing/<step>           milliseconds per local-mapping step (Scalars)

The loggers read what the algorithms already expose (the frontend's TrackingOutput, KeyframeMessage, the
LocalMapper's map and statistics); algorithm modules never import rerun.
"""

from __future__ import annotations

import importlib.abc
import logging
import sys
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from zenslam.camera import PinholeCalibration
from zenslam.runtime.rerun_config import RerunConfig

logger = logging.getLogger(__name__)


APPLICATION_ID = "zenslam"
FRAME_TIMELINE = "frame"  # sequence: the source's frame index
SENSOR_TIMELINE = "sensor_time"  # the frame's stamp: a timestamp, or a duration for stamps counted from 0
RRD_SUFFIX = ".rrd"
# Stamps before 2000-01-01 are taken as time since the sequence start (KITTI, synthetic), not epoch time.
_EPOCH_STAMP_MIN_NS = 946_684_800 * 1_000_000_000
# Logged rows are gathered into chunks (one per entity) until this much time or data has piled up.
# rerun's default (200 ms) suits a live viewer; saved to a file it makes a chunk of one row for most
# of a stage's per-frame entities, each with its own schema, so that the file's size depended on
# the machine's speed and was up to half overhead. A stage killed with SIGKILL loses what is pending.
_FLUSH_TICK_S = 5.0  # seconds
_FLUSH_BYTES = 4 * 1024 * 1024  # bytes

# Colours (RGB) the blueprint's views show; fixed so two recordings look alike.
_KEYFRAME_RGB = (60, 120, 255)
_MAP_POINT_RGB = (230, 230, 230)
_COVISIBILITY_RGB = (255, 170, 0)
_LOOP_RGB = (255, 64, 200)  # loop edges: magenta, drawn thicker than covisibility
_TRAJECTORY_RGB = (255, 60, 60)


def rrd_path(run_dir: str | Path, stage: str) -> Path:
    """The file a stage writes: ``<run_dir>/<stage>.rrd``."""
    return Path(run_dir) / f"{stage}{RRD_SUFFIX}"


def default_blueprint() -> rrb.Blueprint:
    """The layout the viewer opens with: the image with keypoints, the 3D map, and time series below."""
    image = rrb.Spatial2DView(
        name="left image", origin="/", contents=["frontend/camera/left", "frontend/keypoints", "frontend/matches"]
    )
    world = rrb.Spatial3DView(
        name="map",
        origin="/",
        contents=[
            "frontend/pose/**",
            "backend/keyframes",
            "backend/map_points",
            "backend/covisibility",
            "backend/trajectory",
        ],
    )
    timings = rrb.TimeSeriesView(name="timings (ms)", origin="/", contents=["frontend/timing/**", "backend/timing/**"])
    counts = rrb.TimeSeriesView(name="counts", origin="/", contents=["frontend/counts/**", "backend/counts/**"])
    ba = rrb.TimeSeriesView(name="local BA error", origin="backend/local_ba")
    states = rrb.TextLogView(name="tracking state", origin="frontend/state")
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(image, world),
            rrb.Horizontal(timings, counts, rrb.Tabs(ba, states)),
            row_shares=[3, 2],
        ),
        collapse_panels=True,
    )


def sensor_time(stamp_ns: int) -> dict[str, np.datetime64 | np.timedelta64]:
    """The ``set_time`` argument for a stamp in ns: a timestamp for epoch stamps, a duration for stamps from 0."""
    stamp_ns = int(stamp_ns)
    if stamp_ns >= _EPOCH_STAMP_MIN_NS:
        return {"timestamp": np.datetime64(stamp_ns, "ns")}
    return {"duration": np.timedelta64(stamp_ns, "ns")}


class _NoPandas(importlib.abc.MetaPathFinder):
    """An import finder under which ``import pandas`` fails as if pandas were not installed."""

    def find_spec(self, name: str, path: Any = None, target: Any = None) -> None:
        if name.partition(".")[0] == "pandas":
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None


@contextmanager
def _pandas_hidden() -> Iterator[None]:
    """Hide pandas while pyarrow first looks for it: a stage never converts to pandas.

    pyarrow imports pandas (when installed, as evo needs it) the first time it builds an array from
    a Python list, only to check for pandas types; rerun does that on its first log call. That
    import costs a stage process about 27 MB. pyarrow looks once per process, so after the first
    log call pandas can be importable again (and its explicit conversions still import it).
    """
    if "pandas" in sys.modules:
        yield
        return
    finder = _NoPandas()
    sys.meta_path.insert(0, finder)
    try:
        yield
    finally:
        sys.meta_path.remove(finder)


class StageRecording:
    """One stage's recording stream, saved to ``<run_dir>/<stage>.rrd``; use with ``with`` (flushes on exit)."""

    def __init__(self, run_dir: str | Path, run_id: str, stage: str, config: RerunConfig) -> None:
        self.path = rrd_path(run_dir, stage)
        self.stage = stage
        self.config = config
        self.path.parent.mkdir(parents=True, exist_ok=True)
        # No properties: the recording-start property is wall-clock time and would differ run to run.
        self.stream = rr.RecordingStream(
            APPLICATION_ID, recording_id=run_id, send_properties=False,
            batcher_config=rr.ChunkBatcherConfig(flush_tick=_FLUSH_TICK_S, flush_num_bytes=_FLUSH_BYTES),
        )
        self.stream.set_log_time_enabled(False)  # wall clock: logged data must compare equal across runs
        self.stream.set_log_tick_enabled(False)  # counts log calls, which differ between processes
        with _pandas_hidden():  # the blueprint is the first thing logged
            self.stream.save(self.path, default_blueprint=default_blueprint())
        self._closed = False

    def __enter__(self) -> StageRecording:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def at(self, index: int, stamp_ns: int) -> None:
        """Log what follows at frame ``index`` and stamp ``stamp_ns`` (ns) on both timelines."""
        self.stream.set_time(FRAME_TIMELINE, sequence=int(index))
        self.stream.set_time(SENSOR_TIMELINE, **sensor_time(stamp_ns))

    def log(self, entity_path: str, entity: Any, static: bool = False) -> None:
        self.stream.log(entity_path, entity, static=static)

    def scalars(self, prefix: str, values: Mapping[str, float]) -> None:
        """One Scalars entity ``<prefix>/<name>`` per value, in sorted name order."""
        for name in sorted(values):
            self.stream.log(f"{prefix}/{name}", rr.Scalars(float(values[name])))

    def close(self) -> None:
        """Write everything logged to the file and close it (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self.stream.flush()
        self.stream.disconnect()
        logger.info("rerun recording written to %s", self.path)


@contextmanager
def open_stage_recording(
    stage: str, run_id: str, config_path: str | Path | None, config: RerunConfig, restart: int = 0
) -> Iterator[StageRecording | None]:
    """The stage's recording next to the run's config file, or None when disabled or there is no run folder.

    Stage processes get the run's resolved ``config.yaml`` (``--config``), which lives in the run
    folder: the ``.rrd`` goes beside it. A restarted stage (``restart`` > 0) writes
    ``<stage>.restart<N>.rrd``, leaving what the process before it wrote; the viewer opens both as
    one recording.
    """
    if not config.enabled:
        yield None
        return
    if config_path is None:
        logger.info("no --config, hence no run folder: %s writes no rerun recording", stage)
        yield None
        return
    name = f"{stage}.restart{restart}" if restart else stage
    with StageRecording(Path(config_path).parent, run_id, name, config) as recording:
        yield recording


def _log_world_axes(recording: StageRecording) -> None:
    # zenslam's world is the first camera's frame: x right, y down, z forward.
    recording.log("/", rr.ViewCoordinates.RDF, static=True)


def __getattr__(name: str) -> Any:
    """``FrontendLog`` lives beside the frontend's node (``zenslam.frontend.rerun_log``); this name is
    kept only for the frontend's ``main()`` until its start-up moves to the shared stage skeleton."""
    if name == "FrontendLog":
        from zenslam.frontend.rerun_log import FrontendLog

        return FrontendLog
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class BackendLog:
    """What the backend process logs per keyframe: keyframes, local BA errors, counts, timings; the map
    and its covisibility graph at most once per ``map_period_s`` of sensor time, and the final map."""

    def __init__(self, recording: StageRecording) -> None:
        self.recording = recording
        self._map_logged_ns: int | None = None  # stamp of the last logged map
        self._unlogged: tuple[Any, Any] | None = None  # (keyframe, mapper) of a map change not logged yet
        _log_world_axes(recording)

    def log_keyframe(self, keyframe: Any, mapper: Any) -> None:
        """Log the LocalMapper's map after it processed ``keyframe`` (a KeyframeMessage), at that keyframe's frame."""
        rec = self.recording
        rec.at(keyframe.frame_index, keyframe.stamp_ns)
        bmap = mapper.map
        keyframes = sorted(bmap.keyframes.values(), key=lambda kf: (kf.stamp_ns, kf.id))
        positions = np.array([kf.centre_world for kf in keyframes], dtype=float).reshape(-1, 3)
        rec.log("backend/keyframes", rr.Points3D(positions, radii=0.05, colors=_KEYFRAME_RGB))
        rec.log("backend/trajectory", rr.LineStrips3D([positions], colors=_TRAJECTORY_RGB))
        period_ns = round(self.recording.config.map_period_s * 1e9)
        if self._map_logged_ns is None or keyframe.stamp_ns - self._map_logged_ns >= period_ns:
            self._log_map(keyframe, mapper)
        else:
            self._unlogged = (keyframe, mapper)
        ba = getattr(mapper, "last_ba_stats", {}) or {}
        if "initial_error" in ba and "final_error" in ba:
            rec.log("backend/local_ba/before", rr.Scalars(float(ba["initial_error"])))
            rec.log("backend/local_ba/after", rr.Scalars(float(ba["final_error"])))
        rec.scalars("backend/counts", {"keyframes": len(keyframes), "map_points": len(bmap.points)})
        rec.scalars("backend/timing", mapper.last_timings_ms)

    def finish(self) -> None:
        """Log the final map, if the last keyframes came too soon after the previous logged map."""
        if self._unlogged is not None:
            keyframe, mapper = self._unlogged
            self.recording.at(keyframe.frame_index, keyframe.stamp_ns)
            self._log_map(keyframe, mapper)

    def _log_map(self, keyframe: Any, mapper: Any) -> None:
        """The map points, covisibility and loop edges of ``mapper``'s map now, at the current time."""
        bmap = mapper.map
        centres = {kf.id: kf.centre_world for kf in bmap.keyframes.values()}
        point_ids = sorted(bmap.points)
        p_world = np.array([bmap.points[p].p_world for p in point_ids], dtype=float).reshape(-1, 3)
        self.recording.log("backend/map_points", rr.Points3D(p_world, radii=0.02, colors=_MAP_POINT_RGB))
        edges = [(centres[a], centres[b]) for a, b, _ in bmap.covisibility.edges() if a in centres and b in centres]
        strips = np.array(edges, dtype=float).reshape(-1, 2, 3)
        self.recording.log("backend/covisibility", rr.LineStrips3D(strips, colors=_COVISIBILITY_RGB))
        loops = [(centres[a], centres[b]) for a, b in bmap.essential_graph.loop_edges() if a in centres and b in centres]
        loop_strips = np.array(loops, dtype=float).reshape(-1, 2, 3)
        self.recording.log("backend/loops", rr.LineStrips3D(loop_strips, colors=_LOOP_RGB, radii=0.03))
        self._map_logged_ns, self._unlogged = keyframe.stamp_ns, None

    def log_queue_depth(self, keyframe: Any, depth: int) -> None:
        """Keyframes waiting in the backend's inbox after ``keyframe`` was processed."""
        self.recording.at(keyframe.frame_index, keyframe.stamp_ns)
        self.recording.log("backend/counts/queue_depth", rr.Scalars(float(depth)))


# ---- reading recordings back (tests, comparisons of runs) ----


def recording_ids(path: str | Path) -> list[tuple[str, str]]:
    """(application id, recording id) of every recording store in the .rrd file ``path``."""
    from rerun.chunk import RrdReader

    return [(entry.application_id, entry.recording_id) for entry in RrdReader(Path(path)).recordings()]


def read_rrd(path: str | Path) -> dict[tuple[str, str, int | None], list[Any]]:
    """Everything logged in the .rrd file ``path``, keyed by (entity path, component, frame index).

    The frame index is None for static data. Each value lists the logged cells (pyarrow arrays,
    compared with ``==``) in logging order. Rows not on the frame timeline are keyed with None too.
    """
    from rerun.chunk import RrdReader

    cells: dict[tuple[str, str, int | None], list[tuple[Any, Any]]] = {}
    for chunk in RrdReader(Path(path)).store().stream().to_chunks():
        batch = chunk.to_record_batch()
        names = batch.schema.names
        row_ids = batch.column("rerun.controls.RowId").to_pylist()
        frames = batch.column(FRAME_TIMELINE).to_pylist() if FRAME_TIMELINE in names else [None] * batch.num_rows
        components = [n for n in names if n not in ("rerun.controls.RowId", FRAME_TIMELINE, SENSOR_TIMELINE)]
        for component in components:
            column = batch.column(component)
            for row in range(batch.num_rows):
                if column[row].is_valid:
                    key = (chunk.entity_path, component, frames[row])
                    cells.setdefault(key, []).append((row_ids[row], column.slice(row, 1)))
    return {key: [cell for _, cell in sorted(values, key=lambda v: v[0])] for key, values in cells.items()}
