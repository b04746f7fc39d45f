"""The rerun recording of the frontend and backend processes: one ``<run>/<stage>.rrd`` each, one recording per run.

This is the only module that configures rerun. The frontend and the backend each open a ``StageRecording``
(application id "zenslam", recording id = the run id, so the viewer opens the files of a run as
one recording) saved next to the run's ``config.yaml``, with the default blueprint of
``default_blueprint``. Data is logged on explicit timelines only: ``frame`` (the source's frame
index) and ``sensor_time`` (the frame's stamp); rerun's automatic wall-clock ``log_time`` and
``log_tick`` are switched off and the wall-clock start-time property is not sent, so two lockstep
runs log the same data (the timing entities aside, which hold measured milliseconds).

The source and the recorder log nothing to rerun: the frontend logs the images it tracks (under its
keypoints), and the rerun SDK with the pyarrow it loads costs each process that imports it memory
of its own (benchmarks/footprint.md). The recorder's run.mcap holds every bus message, for Foxglove or a replay.

Entity paths mirror the packages (the frontend's are listed in ``zenslam.frontend.rerun_log``)::

    frontend/...                    the frontend's image, keypoints, pose, state, counts and timings
                                    (listed in ``zenslam.frontend.rerun_log``)
    backend/...                     the backend's map, graphs, local BA errors, counts and timings
                                    (listed in ``zenslam.backend.rerun_log``)

Each stage's logger sits beside its node and reads what that stage's algorithms expose
(``zenslam.frontend.rerun_log``, ``zenslam.backend.rerun_log``); algorithm modules never import rerun.
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
# of a stage's per-frame entities, each with its own schema, so that the file's size would depend
# on the machine's speed and much of it be overhead (benchmarks/footprint.md). A stage killed with
# SIGKILL loses what is pending.
_FLUSH_TICK_S = 5.0  # seconds
_FLUSH_BYTES = 4 * 1024 * 1024  # bytes


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
    import costs a stage process memory for nothing (benchmarks/footprint.md). pyarrow looks once per process, so after the first
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


def log_world_axes(recording: StageRecording) -> None:
    # zenslam's world is the first camera's frame: x right, y down, z forward.
    recording.log("/", rr.ViewCoordinates.RDF, static=True)


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
