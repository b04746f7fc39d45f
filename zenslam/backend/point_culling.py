"""Recent map point culling (ORB-SLAM's ``LocalMapping::MapPointCulling``) and the counts it relies on.

A point stays on the recent list for a few keyframes after its creation. While there it is culled
when it is found in under a quarter of the keyframes that should see it, or when two keyframes
later it is still observed too little (ORB-SLAM's ``Observations() <= cnThObs``, where a stereo
observation counts twice: 2 for monocular maps, 3 for stereo/RGB-D).

The frontend counts visibility per *frame*; those counts do not cross the bus, so the backend
estimates the found ratio per *keyframe*: each new keyframe whose frustum holds a recent point
makes it visible once more, and found once more when the keyframe observes it.
"""

from __future__ import annotations

from dataclasses import dataclass

from zenslam.backend.map import BackendMap, frustum_projection


@dataclass(frozen=True)
class PointCullingConfig:
    """ORB-SLAM's recent-point culling rules."""

    min_found_ratio: float = 0.25  # found / visible below this -> culled
    max_weak_observations_mono: int = 2  # culled with this many observations or fewer (monocular)
    max_weak_observations_stereo: int = 3  # same for stereo/RGB-D; a stereo observation counts 2
    check_after_keyframes: int = 2  # keyframes after creation when the observation rule applies
    recent_keyframes: int = 3  # keyframes after creation when the point leaves the recent list
    min_view_cos: float = 0.5  # frustum test: cosine of the largest viewing-angle change


def count_visibility(bmap: BackendMap, kf_id: int, point_ids: list[int], config: PointCullingConfig) -> int:
    """Count keyframe ``kf_id`` as a view of each live point in ``point_ids`` whose frustum test
    passes or that it observes (visible +1), and a find when it observes it (found +1).
    Returns how many points were counted visible."""
    kf = bmap.keyframe(kf_id)
    live = bmap.points
    ids = [p for p in point_ids if p in live]
    if not ids:
        return 0
    points = list(map(live.__getitem__, ids))
    projection = frustum_projection(kf, bmap.point_geometry(ids), config.min_view_cos)
    n_visible = 0
    for pt, in_view in zip(points, projection.visible.tolist()):
        observed = kf_id in pt.observations
        if in_view or observed:
            pt.n_visible += 1
            n_visible += 1
        if observed:
            pt.n_found += 1
    return n_visible


def cull_recent_points(
    bmap: BackendMap, recent: list[int], current_serial: int, monocular: bool, config: PointCullingConfig
) -> tuple[list[int], list[int]]:
    """Apply the culling rules to the recent points; returns (still recent, culled) ids.

    ``current_serial`` is the serial of the newest keyframe; a point's age is counted from the
    serial it was created at. Culled points are removed from the map with their observations.
    """
    max_weak = config.max_weak_observations_mono if monocular else config.max_weak_observations_stereo
    keep, culled = [], []
    for point_id in recent:
        pt = bmap.points.get(point_id)
        if pt is None:
            continue
        age = current_serial - pt.created_serial
        if pt.n_found / max(pt.n_visible, 1) < config.min_found_ratio:  # ``found_ratio``, inlined
            culled.append(point_id)
        elif age >= config.check_after_keyframes and pt.weighted_observations <= max_weak:
            culled.append(point_id)
        elif age < config.recent_keyframes:
            keep.append(point_id)
    for point_id in culled:
        bmap.remove_point(point_id)
    return keep, culled
