"""Local mapping as ORB-SLAM's ``LocalMapping::Run`` does it, one keyframe message at a time.

``LocalMapper.process`` inserts the keyframe (its associations become observations, its new points
map points on the recent list), culls recent points, triangulates new points with the neighbours,
fuses duplicates, runs local bundle adjustment over the covisibility window and culls redundant
keyframes; it returns the ``MapUpdate`` the frontend applies: every keyframe whose pose or
associations changed, every point created, moved or re-described, and the removed ids.
"""

from __future__ import annotations

import logging
import math
import time
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from zenslam.backend.ba_problem import BAProblem, BAResult, LocalBAConfig
from zenslam.backend.keyframe_culling import KeyframeCullingConfig, cull_redundant_keyframes
from zenslam.backend.keyframe_placement import PlacementConfig, placement
from zenslam.backend.map import BackendKeyframe, BackendMap, MapChanges
from zenslam.backend.monocular_map_start import baseline, is_monocular_map_start, rescale_about_first_keyframe
from zenslam.backend.point_culling import PointCullingConfig, count_visibility, cull_recent_points
from zenslam.backend.point_fusion import FusionConfig, fuse_with_neighbours
from zenslam.backend.schur_ba import SchurBundleAdjuster
from zenslam.backend.triangulation import FeatureNodes, TriangulationConfig, create_new_points
from zenslam.camera import PinholeCalibration
from zenslam.errors import ConfigError
from zenslam.geometry import transform_points
from zenslam.map_rules_config import MapRulesConfig
from zenslam.schemas.codec import KeyframeMessage
from zenslam.schemas.map_update import KeyframeCorrection, MapUpdate, MapUpdateKind

logger = logging.getLogger(__name__)

TIMING_STEPS = ("insertion", "point_culling", "triangulation", "fusion", "local_ba", "keyframe_culling", "total")


@dataclass(frozen=True)
class BAWindowConfig:
    """Which keyframes and points go into local bundle adjustment (ORB-SLAM's LocalBundleAdjustment)."""

    enabled: bool = True  # run local BA at all
    # 10 + 5 rather than ORB-SLAM's larger windows: a smaller window costs less per keyframe for
    # the same accuracy on the real and synthetic sequences (benchmarks/local_ba.py).
    max_local_keyframes: int = 10  # optimised poses: the new keyframe and its best connected ones
    max_fixed_keyframes: int = 5  # other keyframes seeing local points, held fixed, most points first
    min_keyframes: int = 3  # BA runs once the map holds this many keyframes (ORB-SLAM: more than 2)
    # Local BA at most once per this much data time (s, between keyframe stamps; 0 = on every
    # keyframe). A keyframe sooner after the last BA is still inserted, triangulated, fused and
    # culled around: ORB-SLAM's mapping thread likewise skips or aborts BA while keyframes come
    # faster than it maps, but by wall time; stamps keep lockstep deterministic. On a car at 10 Hz
    # (every KITTI frame a keyframe) 0.2 s saves much of the BA time at no loss of accuracy, while
    # rooms, with slower keyframes, lose accuracy (benchmarks/local_mapping.md).
    min_interval_s: float = 0.0
    # Stereo/RGB-D observations deeper than this many baselines get their right-image u's sigma
    # multiplied by ``far_right_sigma_scale`` (a threshold of 0 = never): a disparity of a few
    # pixels carries a depth bias of a fraction of a pixel that a window of stereo factors turns
    # into scale drift, while dropping them (monocular) lets the scale drift the other way where
    # most of the scene is far. See benchmarks/backend_quality.py.
    stereo_max_depth_baselines: float = 20.0  # baselines (stereo cameras; not RGB-D, see below)
    far_right_sigma_scale: float = 4.0  # unitless multiplier; inf = far observations monocular
    # RGB-D depth noise sigma_z = rgbd_depth_sigma_at_1m * z^2 (the quadratic model of structured-light
    # and ToF sensors; Kinect v1 ~1.5 mm at 1 m): the virtual right u = u - bf / depth then differs
    # from u by a disparity of sigma bf * this (px) whatever the keypoint's level, and shares u's
    # keypoint error. 0 = ORB-SLAM's model: right u an independent measurement with the keypoint's
    # sigma, which leaves a far RGB-D point's depth to the parallax between keyframes (noisier than
    # the sensor), so BA can scale the map.
    rgbd_depth_sigma_at_1m: float = 0.0015  # metres of depth noise at 1 m depth (m / m^2)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.min_interval_s) and self.min_interval_s >= 0):
            raise ConfigError(f"local_mapping.ba_window.min_interval_s={self.min_interval_s} must be a finite time >= 0 s")


@dataclass(frozen=True)
class LocalMappingConfig:
    """Settings of the backend's local mapping, one section per step."""

    map_rules: MapRulesConfig = field(default_factory=MapRulesConfig)  # copy of the run's ``map`` section (covisibility edges)
    essential_min_weight: int = 100  # shared points for a covisibility edge of the essential graph
    min_keyframes_per_point: int = 2  # a point losing observations (BA outliers, culled keyframe) below this goes
    # ORB-SLAM's CheckNewKeyFrames: while more keyframes wait in the inbox, a keyframe is inserted,
    # culled and triangulated only; fusion, local BA and keyframe culling run on the last queued one.
    defer_when_queued: bool = True
    # Associations sent with a keyframe whose point reprojects behind the camera or with a squared
    # error above this (px^2 / level sigma^2 on u, v; 400 = 20 sigma) are dropped at insertion. In
    # pipelined and live runs the frontend matches against positions that lag the backend's, and
    # points a BA has moved since can be tens to hundreds of pixels off; such associations would
    # start the next BA far from its minimum. The gate is wide because a tight one also drops
    # stale-but-right associations (backend_quality --update-lag measures both).
    max_association_chi2: float = 400.0
    # A keyframe whose fusion and local BA are deferred is first placed on the map by a pose-only
    # optimisation (``keyframe_placement``): its BA would have moved it there.
    placement: PlacementConfig = field(default_factory=PlacementConfig)
    point_culling: PointCullingConfig = field(default_factory=PointCullingConfig)
    triangulation: TriangulationConfig = field(default_factory=TriangulationConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    ba_window: BAWindowConfig = field(default_factory=BAWindowConfig)
    keyframe_culling: KeyframeCullingConfig = field(default_factory=KeyframeCullingConfig)


class BundleAdjuster(Protocol):
    """What local mapping needs from local BA (``schur_ba.SchurBundleAdjuster``, ``local_ba.LocalBundleAdjuster``)."""

    def optimize(self, problem: BAProblem) -> BAResult: ...


def bundle_adjuster(config: LocalBAConfig) -> BundleAdjuster:
    """The local BA solver that ``config.method`` names."""
    if config.method == "batch_lm":
        from zenslam.backend.local_ba import LocalBundleAdjuster  # gtsam: loaded only when chosen

        return LocalBundleAdjuster(config)
    return SchurBundleAdjuster(config)


@dataclass(frozen=True)
class LocalMappingStats:
    """Counts of what one ``process`` call did."""

    associations_dropped: int = 0  # keyframe associations naming removed points, one point twice, or far off
    points_received: int = 0  # new points created by the frontend at this keyframe
    points_created: int = 0  # triangulated here
    points_culled: int = 0  # recent points culled
    fusion_matches: int = 0  # observations added or points merged by fusion
    points_fused: int = 0  # points merged away by fusion
    ba_outliers: int = 0  # observations dropped by local BA
    points_removed_after_ba: int = 0  # points dropped by BA or left with too few observations
    keyframes_culled: int = 0
    deferred: int = 0  # 1 when fusion, local BA and keyframe culling waited for queued keyframes
    placed: int = 0  # 1 when the (deferred) keyframe was placed on the map before its insertion
    ba_waited: int = 0  # 1 when local BA waited for ``ba_window.min_interval_s`` to pass


@dataclass(frozen=True)
class _BegunWork:
    """What ``LocalMapper.begin`` did on a keyframe, for ``finish`` to complete and report."""

    deferred: bool  # fusion, local BA and keyframe culling wait for queued keyframes
    timings: dict[str, float]  # per step so far, milliseconds
    counts: dict[str, int]  # LocalMappingStats fields so far
    seconds: float  # time taken so far


def new_backend_map(config: LocalMappingConfig) -> BackendMap:
    """An empty map with the covisibility and essential-graph thresholds of ``config``."""
    return BackendMap(config.map_rules.min_covisibility_weight, config.essential_min_weight)


class LocalMapper:
    """The backend's map and the local mapping steps run on it for each keyframe."""

    def __init__(
        self, bmap: BackendMap, config: LocalMappingConfig, bundle_adjuster: BundleAdjuster, feature_nodes: FeatureNodes | None = None
    ) -> None:
        self.map = bmap  # lent by its owner, the backend node; loop closing works on the same map
        self.config = config
        self.bundle_adjuster = bundle_adjuster
        # The vocabulary nodes of a keyframe's features (place recognition's), which new points'
        # matching keeps to; None (no vocabulary): every pair in the epipolar band is compared.
        self.feature_nodes = feature_nodes
        self.recent_points: list[int] = []  # ids on ORB-SLAM's recently-added list
        self.last_timings_ms: dict[str, float] = {}  # per step of the last call, milliseconds
        self.last_stats = LocalMappingStats()
        self.last_ba_stats: dict = {}  # the bundle adjuster's stats of the last call
        self._last_ba_stamp_ns: int | None = None  # stamp of the keyframe local BA last ran on
        self.totals: Counter[str] = Counter()  # LocalMappingStats fields summed over all calls
        self._begun: tuple[int, int] = (-1, 0)  # (id, stamp) of the keyframe ``begin`` took
        self._begun_work = _BegunWork(False, {}, {}, 0.0)  # and what was done on it so far

    def process(self, keyframe: KeyframeMessage, queued: int = 0) -> MapUpdate:
        """Run local mapping on one keyframe; returns what changed in the map, in one update.

        ``queued`` is the number of keyframes still waiting behind this one (0 in lockstep); with
        ``defer_when_queued`` a backlog skips fusion, local BA and keyframe culling, as ORB-SLAM does.
        """
        self._map_keyframe(keyframe, queued)
        return self._refine_window("keyframe")

    def begin(self, keyframe: KeyframeMessage, queued: int = 0) -> MapUpdate:
        """The first half of ``process``: insertion, point culling, triangulation and fusion; returns
        the keyframe's answer. ``finish`` follows before the next keyframe."""
        self._map_keyframe(keyframe, queued)
        kf_id, stamp_ns = self._begun
        return map_update_from_changes(self.map, kf_id, stamp_ns, self.map.take_changes())

    def finish(self) -> MapUpdate:
        """The second half: local BA and keyframe culling on the keyframe ``begin`` took; returns
        their changes as a correction (an empty one when neither changed anything)."""
        return self._refine_window("correction")

    def _map_keyframe(self, keyframe: KeyframeMessage, queued: int) -> None:
        """Insertion, recent-point culling, triangulation and fusion; the rest waits in ``_begun_work``."""
        deferred = self.config.defer_when_queued and queued > 0
        timings: dict[str, float] = {}
        started = time.perf_counter()
        counts: dict[str, int] = {}
        with _timed(timings, "insertion"):
            counts.update(self._insert(keyframe, place=deferred and self.config.placement.enabled))
        kf_id = int(keyframe.id)
        monocular = keyframe.sensor == "mono"
        with _timed(timings, "point_culling"):
            serial = self.map.keyframe(kf_id).serial
            self.recent_points, culled = cull_recent_points(
                self.map, self.recent_points, serial, monocular, self.config.point_culling
            )
        with _timed(timings, "triangulation"):
            created = create_new_points(self.map, kf_id, self.config.triangulation, self.feature_nodes)
            self.recent_points.extend(created)
        with _timed(timings, "fusion"):
            if not deferred:
                before = len(self.map.changes.removed_points)
                counts["fusion_matches"] = fuse_with_neighbours(self.map, kf_id, self.config.fusion)
                counts["points_fused"] = len(self.map.changes.removed_points) - before
        counts.update(points_created=len(created), points_culled=len(culled), deferred=int(deferred))
        self._begun = (kf_id, int(keyframe.stamp_ns))
        self._begun_work = _BegunWork(deferred, timings, counts, time.perf_counter() - started)

    def _refine_window(self, kind: MapUpdateKind) -> MapUpdate:
        """Local BA and keyframe culling on the keyframe ``_map_keyframe`` took; the changes since
        the last update taken, as an update of ``kind``."""
        kf_id, stamp_ns = self._begun
        work = self._begun_work
        deferred, timings, counts = work.deferred, work.timings, work.counts
        started = time.perf_counter()
        culled_kfs: list[int] = []
        ba_due = self._local_ba_due(stamp_ns)
        with _timed(timings, "local_ba"):
            if not deferred and ba_due:
                ba_counts = self._local_ba(kf_id)
                counts.update(ba_counts)
                if ba_counts:  # a window was optimised (none while the map is too small)
                    self._last_ba_stamp_ns = stamp_ns
        with _timed(timings, "keyframe_culling"):
            if not deferred:
                culled_kfs, touched = cull_redundant_keyframes(self.map, kf_id, self.config.keyframe_culling)
                self.map.remove_weak_points(touched, self.config.min_keyframes_per_point)
        update = map_update_from_changes(self.map, kf_id, stamp_ns, self.map.take_changes(), kind=kind)
        timings["total"] = (work.seconds + time.perf_counter() - started) * 1e3
        counts["keyframes_culled"] = len(culled_kfs)
        counts["ba_waited"] = int(not deferred and not ba_due)
        self.last_stats = LocalMappingStats(**counts)
        self.totals.update(counts)
        self.last_timings_ms = timings
        logger.debug("keyframe %d: %s, %.1f ms", kf_id, self.last_stats, timings["total"])
        return update

    # ---- steps ---------------------------------------------------------------------------------------
    def _insert(self, msg: KeyframeMessage, place: bool = False) -> dict[str, int]:
        """Add the keyframe, its associations and its new points; count visibility of recent points.
        With ``place``, the keyframe and its new points are first placed on the map (``keyframe_placement``)."""
        kf = BackendKeyframe.from_message(msg)
        requested = np.asarray(msg.map_point_ids, dtype=np.int64)
        new_ids = {int(p) for p in np.asarray(msg.new_point_ids).tolist()}
        keypoint_of_new: dict[int, int] = {}
        seen: set[int] = set()
        dropped = 0
        associated = np.flatnonzero(requested >= 0)
        kept, live_ids = [], []
        resolve = self.map.resolve
        for keypoint, point_id in zip(associated.tolist(), requested[associated].tolist()):
            if point_id in new_ids:
                keypoint_of_new.setdefault(point_id, keypoint)
                continue
            live = resolve(point_id)
            if live < 0 or live in seen:
                dropped += 1
                continue
            seen.add(live)
            kept.append(keypoint)
            live_ids.append(live)
        kf.map_point_ids[kept] = live_ids
        new_world = np.asarray(msg.new_points_world, dtype=float).reshape(-1, 3)
        correction = placement(self.map, kf, self.config.placement) if place else None
        if correction is not None:
            kf.T_world_cam = correction @ kf.T_world_cam
            new_world = transform_points(correction, new_world)
        dropped += self._drop_far_associations(kf)
        self.map.add_keyframe(kf)
        received, rows, keypoints = [], [], []
        for row, point_id in enumerate(np.asarray(msg.new_point_ids).tolist()):
            keypoint = keypoint_of_new.get(int(point_id))
            if keypoint is None:
                logger.warning("keyframe %d: new point %d is at no keypoint; ignored", kf.id, point_id)
                continue
            received.append(int(point_id))
            rows.append(row)
            keypoints.append(keypoint)
        self.map.add_observed_points(received, new_world[rows], kf.id, keypoints)
        self.map.refresh_points()
        count_visibility(self.map, kf.id, self.recent_points, self.config.point_culling)
        self.recent_points.extend(received)
        return {"associations_dropped": dropped, "points_received": len(received), "placed": int(correction is not None)}

    def _drop_far_associations(self, kf: BackendKeyframe) -> int:
        """Unset the associations of ``kf`` (not yet in the map) to known points that reproject behind
        it or beyond ``max_association_chi2``; returns how many."""
        keypoints = np.flatnonzero(kf.map_point_ids >= 0)
        if len(keypoints) == 0:
            return 0
        p_world = self.map.positions(kf.map_point_ids[keypoints])
        px, _, z = kf.project(p_world)
        chi2 = np.sum((px - kf.keypoints_px[keypoints]) ** 2, axis=1) / kf.level_sigma2[kf.levels[keypoints]]
        far = (z <= 0) | ~(chi2 <= self.config.max_association_chi2)
        kf.map_point_ids[keypoints[far]] = -1
        return int(np.count_nonzero(far))

    def _local_ba_due(self, stamp_ns: int) -> bool:
        """Whether local BA runs on a keyframe stamped ``stamp_ns``: ``ba_window.min_interval_s`` after
        the last one ran (always with an interval of 0, before the first, and when stamps restart)."""
        interval_ns = round(self.config.ba_window.min_interval_s * 1e9)
        last = self._last_ba_stamp_ns
        return interval_ns == 0 or last is None or not last <= stamp_ns < last + interval_ns

    def _local_ba(self, kf_id: int) -> dict[str, int]:
        """Build the BA window around ``kf_id``, optimise it and apply the result to the map."""
        cfg = self.config.ba_window
        self.last_ba_stats = {}
        if cfg.enabled and is_monocular_map_start(self.map, kf_id):
            return self._map_start_ba(kf_id)
        if not cfg.enabled or len(self.map.keyframes) < cfg.min_keyframes:
            return {}
        window = local_ba_window(self.map, kf_id, cfg)
        if window is None:
            return {}
        problem, obs_point_ids, obs_kf_ids = window
        result = self.bundle_adjuster.optimize(problem)
        self.last_ba_stats = dict(result.stats)
        return apply_ba_result(self.map, problem, result, obs_point_ids, obs_kf_ids, self.config.min_keyframes_per_point)

    def _map_start_ba(self, kf_id: int) -> dict[str, int]:
        """BA of a monocular map's two keyframes (the first fixed) and all points, then the map scaled
        back to the keyframes' distance before it (``monocular_map_start``)."""
        kf_ids = sorted(self.map.keyframes)
        point_ids = sorted(p for p, point in self.map.points.items() if point.observations)
        if not point_ids:
            return {}
        is_fixed = np.array([k == self.map.first_keyframe_id for k in kf_ids], dtype=bool)
        calibration = self.map.keyframes[kf_id].calibration
        published = baseline(self.map)
        problem, obs_point_ids, obs_kf_ids = ba_problem(self.map, kf_ids, point_ids, is_fixed, calibration, self.config.ba_window)
        result = self.bundle_adjuster.optimize(problem)
        self.last_ba_stats = dict(result.stats)
        counts = apply_ba_result(self.map, problem, result, obs_point_ids, obs_kf_ids, self.config.min_keyframes_per_point)
        optimised = baseline(self.map)
        if optimised > 0:
            rescale_about_first_keyframe(self.map, published / optimised)
        logger.info("monocular map start: BA of %d points, baseline %.4f -> %.4f", len(point_ids), published, optimised)
        return counts


@contextmanager
def _timed(timings: dict[str, float], name: str) -> Iterator[None]:
    start = time.perf_counter()
    try:
        yield
    finally:
        timings[name] = (time.perf_counter() - start) * 1e3


def local_ba_window(
    bmap: BackendMap, kf_id: int, config: BAWindowConfig
) -> tuple[BAProblem, np.ndarray, np.ndarray] | None:
    """ORB-SLAM's local BA window around ``kf_id``: the problem, and each observation's point and keyframe id.

    Local keyframes: ``kf_id`` and its best connected keyframes (up to ``max_local_keyframes``);
    local points: those they observe; fixed keyframes: the others observing local points, most
    such points first (up to ``max_fixed_keyframes``). The first keyframe is fixed whenever it
    is in the window (gauge); if no keyframe is fixed, the oldest local one is.
    """
    local = [kf_id] + bmap.covisibility.connected(kf_id)[: max(config.max_local_keyframes - 1, 0)]
    local_set = set(local)
    ids, rows = (np.concatenate(parts) for parts in zip(*(bmap.keyframe_points(k) for k in local)))
    if len(ids) == 0:
        return None
    point_ids = np.unique(ids).tolist()
    seen_by = _local_points_seen(bmap, rows, local_set)
    fixed = sorted(seen_by, key=lambda k: (-seen_by[k], k))[: config.max_fixed_keyframes]
    first = bmap.first_keyframe_id
    if first is not None and first in seen_by and first not in fixed:
        fixed.append(first)
    kf_ids = local + fixed
    is_fixed = np.array([k in fixed or k == first for k in kf_ids], dtype=bool)
    if not is_fixed.any():
        is_fixed[int(np.argmin([bmap.keyframes[k].serial for k in kf_ids]))] = True
    return ba_problem(bmap, kf_ids, point_ids, is_fixed, bmap.keyframes[kf_id].calibration, config)


def _local_points_seen(bmap: BackendMap, local_rows: np.ndarray, local: set[int]) -> dict[int, int]:
    """Keyframe id -> how many of the points at ``local_rows`` (store rows) it observes, for every
    keyframe outside ``local`` observing one. Those keyframes share a point with a local keyframe, so
    they are among its covisible ones; each counts its associations, which mirror the observations."""
    is_local = np.zeros(bmap.point_store.n_rows + 1, dtype=bool)  # the last entry: row -1, no point
    is_local[local_rows] = True
    others = sorted(set().union(*(bmap.covisibility.weights(k) for k in local)) - local)
    counts = {k: int(np.count_nonzero(is_local[bmap.keyframes[k].map_point_rows])) for k in others}
    return {k: n for k, n in counts.items() if n}


def ba_problem(
    bmap: BackendMap,
    kf_ids: list[int],
    point_ids: list[int],
    is_fixed: np.ndarray,
    calibration: PinholeCalibration,
    config: BAWindowConfig,
) -> tuple[BAProblem, np.ndarray, np.ndarray]:
    """The BA problem over keyframes ``kf_ids`` (held where ``is_fixed``) and the sorted ``point_ids``
    with every observation of those points by those keyframes, the observation model of ``config``;
    also each observation's point id and keyframe id. Every array is a copy: the problem shares no
    memory with the map, so it can be optimised while the map changes."""
    obs_kf_arr, obs_pt_arr, obs_kp_arr = _window_observations(bmap, kf_ids, np.asarray(point_ids, dtype=np.int64))
    px, right_u, inv_sigma2, far, disparity_sigma = _observation_arrays(bmap, kf_ids, obs_kf_arr, obs_kp_arr, config)
    if np.isinf(config.far_right_sigma_scale):
        right_u[far] = np.nan
        right_scale = np.ones(len(obs_kf_arr))
    else:
        right_scale = np.where(far, config.far_right_sigma_scale, 1.0)
    ids = np.asarray(point_ids, dtype=np.int64)
    problem = BAProblem(
        calibration=calibration,
        keyframe_ids=np.asarray(kf_ids, dtype=np.int64),
        T_world_cam=np.stack([bmap.keyframes[k].T_world_cam for k in kf_ids]),
        fixed=np.array(is_fixed, dtype=bool),
        point_ids=ids,
        p_world=bmap.positions(ids),
        obs_keyframe=obs_kf_arr,
        obs_point=obs_pt_arr,
        obs_px=px,
        obs_right_u=right_u,
        obs_inv_sigma2=inv_sigma2,
        obs_right_sigma_scale=right_scale,
        obs_disparity_sigma=disparity_sigma,
    )
    return problem, ids[obs_pt_arr], np.asarray(kf_ids, dtype=np.int64)[obs_kf_arr]


def _window_observations(bmap: BackendMap, kf_ids: list[int], point_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Observations of the sorted ``point_ids`` by the window's keyframes, read from the keyframes'
    associations (the map mirrors them): keyframe row, point row, keypoint (each (O,) int64), sorted
    by point row, then keyframe id."""
    kf_rows, pt_rows, keypoints, kf_order = [], [], [], []
    for row, k in enumerate(kf_ids):
        associated = bmap.keyframes[k].map_point_ids
        kps = np.flatnonzero(associated >= 0)
        at = np.searchsorted(point_ids, associated[kps])
        local = at < len(point_ids)
        local[local] = point_ids[at[local]] == associated[kps[local]]
        kf_rows.append(np.full(int(local.sum()), row, dtype=np.int64))
        pt_rows.append(at[local])
        keypoints.append(kps[local])
        kf_order.append(np.full(int(local.sum()), k, dtype=np.int64))
    kf_row, pt_row, keypoint, kf_id = (np.concatenate(a).astype(np.int64) for a in (kf_rows, pt_rows, keypoints, kf_order))
    order = np.lexsort((kf_id, pt_row))
    return kf_row[order], pt_row[order], keypoint[order]


def _observation_arrays(bmap: BackendMap, kf_ids: list[int], obs_kf: np.ndarray, obs_kp: np.ndarray, config: BAWindowConfig):
    """Pixels (O, 2), right u (O,) (NaN mono), 1/sigma^2 (O,) of observations, gathered from the
    window's keypoints stacked; which stereo-camera ones are deeper than ``stereo_max_depth_baselines``
    (O,) bool (none when 0); the disparity sigma (O,) px of RGB-D ones (0 elsewhere, or everywhere
    when ``rgbd_depth_sigma_at_1m`` is 0)."""
    kfs = [bmap.keyframes[k] for k in kf_ids]
    at = np.cumsum([0, *(kf.n_keypoints for kf in kfs)])[:-1][obs_kf] + obs_kp  # into the stacked keypoints
    px = np.concatenate([kf.keypoints_px for kf in kfs])[at]
    right = np.concatenate([kf.right_u for kf in kfs])[at]
    stereo = right >= 0
    inv_sigma2 = 1.0 / np.concatenate([kf.level_sigma2[kf.levels] for kf in kfs])[at]
    # Per keyframe: RGB-D's disparity sigma (sigma_z = c z^2 is a constant sigma of bf / z: bf * c
    # px), else a stereo camera's depth beyond which observations are far.
    rgbd = [kf.sensor == "rgbd" and config.rgbd_depth_sigma_at_1m > 0 for kf in kfs]
    disparity = np.array([kf.calibration.bf * config.rgbd_depth_sigma_at_1m if r else 0.0 for kf, r in zip(kfs, rgbd)])
    max_baselines = config.stereo_max_depth_baselines
    far_depth = np.array([
        max_baselines * kf.calibration.baseline_m if not r and max_baselines > 0 and kf.calibration.baseline_m else np.inf
        for kf, r in zip(kfs, rgbd)
    ])  # fmt: skip
    disparity_sigma = np.where(stereo & np.array(rgbd)[obs_kf], disparity[obs_kf], 0.0)
    far = stereo & (np.concatenate([kf.depth_m for kf in kfs])[at] > far_depth[obs_kf])
    right_u = np.where(stereo, right, np.nan)
    return px, right_u, inv_sigma2, far, disparity_sigma


def apply_ba_result(
    bmap: BackendMap,
    problem: BAProblem,
    result: BAResult,
    obs_point_ids: np.ndarray,
    obs_kf_ids: np.ndarray,
    min_keyframes_per_point: int,
) -> dict[str, int]:
    """Write optimised poses and points into the map, drop outlier observations (both sides) and the
    points the optimiser removed or left with fewer than ``min_keyframes_per_point`` observers."""
    for row in np.flatnonzero(~problem.fixed).tolist():
        bmap.set_keyframe_pose(int(problem.keyframe_ids[row]), result.T_world_cam[row])
    removed = {int(p) for p in np.asarray(result.removed_point_ids).tolist()}
    moved = np.flatnonzero(np.any(result.p_world != problem.p_world, axis=1) & ~np.isin(problem.point_ids, result.removed_point_ids))
    bmap.set_point_positions(problem.point_ids[moved].tolist(), result.p_world[moved])
    touched: list[int] = []
    outliers = np.flatnonzero(~np.asarray(result.inlier_obs, dtype=bool))
    for o in outliers.tolist():
        point_id, kf_id = int(obs_point_ids[o]), int(obs_kf_ids[o])
        if point_id not in removed and kf_id in bmap.points[point_id].observations:
            bmap.remove_observation(point_id, kf_id)
            touched.append(point_id)
    for point_id in sorted(removed):
        if point_id in bmap.points:
            bmap.remove_point(point_id)
    weak = bmap.remove_weak_points(touched, min_keyframes_per_point)
    bmap.refresh_points()
    return {"ba_outliers": len(outliers), "points_removed_after_ba": len(removed) + len(weak)}


def map_update_from_changes(
    bmap: BackendMap, kf_id: int, stamp_ns: int, changes: MapChanges, kind: MapUpdateKind = "keyframe"
) -> MapUpdate:
    """The replacement-semantics update of ``changes``, of ``kind``; backend points born and removed in
    the same step never reach the frontend, so they are not listed as removed."""
    kf_ids = sorted(changes.keyframes & bmap.keyframes.keys())
    point_ids = sorted(changes.points & bmap.points.keys())
    rows, store = bmap.point_rows(point_ids), bmap.point_store
    return MapUpdate(
        keyframe_id=kf_id,
        stamp_ns=int(stamp_ns),
        keyframes=tuple(
            KeyframeCorrection(k, bmap.keyframes[k].T_world_cam.copy(), bmap.keyframes[k].map_point_ids.copy())
            for k in kf_ids
        ),
        point_ids=np.asarray(point_ids, dtype=np.int64),
        p_world=store.p_world[rows],
        descriptors=store.descriptor[rows],
        normals=store.normal[rows],
        min_distance_m=store.min_distance_m[rows],
        max_distance_m=store.max_distance_m[rows],
        removed_point_ids=np.asarray(sorted(changes.removed_points - changes.created_points), dtype=np.int64),
        removed_keyframe_ids=np.asarray(sorted(changes.removed_keyframes), dtype=np.int64),
        kind=kind,
    )
