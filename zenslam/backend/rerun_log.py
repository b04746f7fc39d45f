"""What the backend process logs to its rerun recording per keyframe, beside its node.

Entity paths (the recording itself, its timelines and blueprint are ``zenslam.runtime.rerun_log``'s)::

    backend/keyframes               keyframe centres (Points3D, world, metres), per keyframe
    backend/map_points              every map point (Points3D, world, metres), at most once per
                                    ``map_period_s`` of sensor time, and the final map
    backend/covisibility            covisibility edges between keyframe centres (LineStrips3D), as map_points
    backend/loops                   loop edges between keyframe centres (LineStrips3D), as map_points
    backend/trajectory              the keyframe centres in time order (LineStrips3D)
    backend/local_ba/before|after   local BA graph error before and after optimisation (Scalars)
    backend/counts/<name>           keyframes, map points, keyframe queue depth (Scalars)
    backend/timing/<step>           milliseconds per local-mapping step (Scalars)
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr

from zenslam.runtime.rerun_log import StageRecording, _log_world_axes

if TYPE_CHECKING:
    from zenslam.backend.map import BackendMap
    from zenslam.schemas.codec import KeyframeMessage

# Colours (RGB) the blueprint's map view shows; fixed so two recordings look alike.
_KEYFRAME_RGB = (60, 120, 255)
_MAP_POINT_RGB = (230, 230, 230)
_COVISIBILITY_RGB = (255, 170, 0)
_LOOP_RGB = (255, 64, 200)  # loop edges: magenta, drawn thicker than covisibility
_TRAJECTORY_RGB = (255, 60, 60)


class BackendLog:
    """What the backend process logs per keyframe: keyframes, local BA errors, counts, timings; the map
    and its covisibility graph at most once per ``map_period_s`` of sensor time, and the final map."""

    def __init__(self, recording: StageRecording) -> None:
        self.recording = recording
        self._map_logged_ns: int | None = None  # stamp of the last logged map
        self._unlogged: tuple[KeyframeMessage, BackendMap] | None = None  # a map change not logged yet
        _log_world_axes(recording)

    def log_keyframe(
        self, keyframe: KeyframeMessage, bmap: BackendMap, ba_stats: Mapping[str, float], timings_ms: Mapping[str, float]
    ) -> None:
        """Log ``bmap`` after local mapping (and loop closing) processed ``keyframe``, at that keyframe's
        frame: ``ba_stats`` are the bundle adjuster's stats of that step (``initial_error`` and
        ``final_error`` when it ran), ``timings_ms`` its milliseconds per step."""
        rec = self.recording
        rec.at(keyframe.frame_index, keyframe.stamp_ns)
        keyframes = sorted(bmap.keyframes.values(), key=lambda kf: (kf.stamp_ns, kf.id))
        positions = np.array([kf.centre_world for kf in keyframes], dtype=float).reshape(-1, 3)
        rec.log("backend/keyframes", rr.Points3D(positions, radii=0.05, colors=_KEYFRAME_RGB))
        rec.log("backend/trajectory", rr.LineStrips3D([positions], colors=_TRAJECTORY_RGB))
        period_ns = round(self.recording.config.map_period_s * 1e9)
        if self._map_logged_ns is None or keyframe.stamp_ns - self._map_logged_ns >= period_ns:
            self._log_map(keyframe, bmap)
        else:
            self._unlogged = (keyframe, bmap)
        if "initial_error" in ba_stats and "final_error" in ba_stats:
            rec.log("backend/local_ba/before", rr.Scalars(float(ba_stats["initial_error"])))
            rec.log("backend/local_ba/after", rr.Scalars(float(ba_stats["final_error"])))
        rec.scalars("backend/counts", {"keyframes": len(keyframes), "map_points": len(bmap.points)})
        rec.scalars("backend/timing", timings_ms)

    def finish(self) -> None:
        """Log the final map, if the last keyframes came too soon after the previous logged map."""
        if self._unlogged is not None:
            keyframe, bmap = self._unlogged
            self.recording.at(keyframe.frame_index, keyframe.stamp_ns)
            self._log_map(keyframe, bmap)

    def _log_map(self, keyframe: KeyframeMessage, bmap: BackendMap) -> None:
        """The map points, covisibility and loop edges of ``bmap`` now, at the current time."""
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

    def log_queue_depth(self, keyframe: KeyframeMessage, depth: int) -> None:
        """Keyframes waiting in the backend's inbox after ``keyframe`` was processed."""
        self.recording.at(keyframe.frame_index, keyframe.stamp_ns)
        self.recording.log("backend/counts/queue_depth", rr.Scalars(float(depth)))
