"""Loop closing as ORB-SLAM2's ``LoopClosing``: place recognition, verification, correction, on the backend map.

``LoopCloser`` is lent the backend node's map and place recognition (the keyframe database, where
the node has indexed the keyframe already). For each keyframe local mapping has inserted, it
detects consistent candidates, verifies them (``loop_verification``) and, for an accepted loop,
corrects the map (ORB-SLAM's ``CorrectLoop``):

0. two checks before anything in the map changes: the drift budget (``drift_budget``, 5% for
   stereo / RGB-D maps, ``drift_budget_monocular``, 10%, for monocular ones: a loop may move the
   current keyframe by at most that fraction of the keyframes' path from the loop keyframe; a wrong
   place verification let through asks for far more than drift makes, and on a long path the chain
   alone would absorb it), then the essential graph optimised with the current keyframe's covisible
   neighbourhood tied to the loop keyframe; if its robust kernel rejects every such edge, the loop
   is rejected; either way nothing in the map changes;
1. the neighbourhood is moved rigidly (with scale for monocular) to where the loop puts the
   current keyframe, with the points they observe;
2. the loop's points replace the current neighbourhood's duplicates (matched points first, then
   every loop point projected into every neighbourhood keyframe);
3. the essential graph (spanning tree, strong covisibility, loop edges, and the new links the
   fusion made across the loop) is optimised with the loop keyframe fixed, and every other point
   follows its reference keyframe; should the robust kernel now reject every new link, the loop
   is rejected after all and the map is put back as it was before step 1 (``BackendMap.checkpoint``);
4. the loop edge is recorded in the essential graph, so neither end is ever culled.

Global bundle adjustment after the loop is the node's business (it decides when it runs and when
its result is applied); this module only says that one is due.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field

import numpy as np

from zenslam.backend.loop_closing_config import LoopClosingConfig
from zenslam.backend.loop_detection import Detection, LoopDetector
from zenslam.backend.loop_verification import LoopMatch, Rejection, verify_candidates
from zenslam.backend.map import BackendMap
from zenslam.backend.place_recognition import PlaceRecognition
from zenslam.backend.point_fusion import FusionConfig, fuse_into_keyframe
from zenslam.backend.pose_graph import correct_points_after_pose_graph, correction_and_path, optimize_essential_graph
from zenslam.geometry import invert_T, transform_points

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class LoopOutcome:
    """What loop closing did for one keyframe."""

    detection: Detection
    rejections: tuple[Rejection, ...] = ()
    loop: LoopMatch | None = None  # the accepted loop, already applied to the map
    fused_points: int = 0
    loop_connections: int = 0  # new essential-graph edges across the loop
    pose_graph_stats: dict = field(default_factory=dict)

    @property
    def accepted(self) -> bool:
        return self.loop is not None


class LoopCloser:
    """Loop detector and correction over the map and place recognition lent by the backend node."""

    def __init__(self, bmap: BackendMap, places: PlaceRecognition, config: LoopClosingConfig) -> None:
        self.map = bmap
        self.places = places
        self.config = config
        self.detector = LoopDetector(config.detection)
        self.loops: list[LoopMatch] = []

    def process(self, kf_id: int) -> LoopOutcome:
        """Detect, verify and, when accepted, correct a loop at keyframe ``kf_id`` (in the database)."""
        kf = self.map.keyframe(kf_id)
        places = self.places
        detection = self.detector.detect(kf_id, kf.serial, places.bow(kf_id), places.database, self.map.covisibility, places.score)
        if not detection.consistent:
            return LoopOutcome(detection)
        with_scale = kf.sensor == "mono"
        T_before = kf.T_world_cam.copy()
        match, rejections = verify_candidates(
            self.map, kf_id, list(detection.consistent), places.feature_vectors, with_scale,
            self.config.verification, seed=self.config.seed * 1_000_003 + kf_id,
        )
        if match is None:
            return LoopOutcome(detection, tuple(rejections))
        over_budget = self.drift_budget_exceeded(match, with_scale)
        if over_budget is not None:
            logger.warning("keyframe %d: loop to %d rejected: %s", kf_id, match.loop_keyframe_id, over_budget)
            return LoopOutcome(detection, (*rejections, Rejection(match.loop_keyframe_id, over_budget, match)))
        fused, connections, stats = self.correct(match, with_scale)
        if stats.get("loop_rejected"):
            logger.warning("keyframe %d: loop to %d rejected by the pose graph (its edges disagree with the map)", kf_id, match.loop_keyframe_id)
            rejection = Rejection(match.loop_keyframe_id, "pose graph: every loop edge down-weighted", match)
            return LoopOutcome(detection, (*rejections, rejection), None, fused, connections, stats)
        self.map.essential_graph.add_loop_edge(kf_id, match.loop_keyframe_id)
        self.detector.loop_closed(kf.serial)
        self.loops.append(match)
        logger.info(
            "loop closed: keyframe %d -> %d (%d inliers, %d points fused, keyframe moved %.3f m)",
            kf_id, match.loop_keyframe_id, match.inliers, fused, float(np.linalg.norm(kf.T_world_cam[:3, 3] - T_before[:3, 3])),
        )
        return LoopOutcome(detection, tuple(rejections), match, fused, connections, stats)

    def drift_budget_exceeded(self, match: LoopMatch, with_scale: bool = False) -> str | None:
        """Why ``match`` moves the current keyframe further than the drift budget allows
        (``drift_budget``, or ``drift_budget_monocular`` for a Sim(3) map), or None."""
        budget = self.config.drift_budget_monocular if with_scale else self.config.drift_budget
        if budget is None:
            return None
        poses = {k: kf.T_world_cam for k, kf in self.map.keyframes.items()}
        moved, path = correction_and_path(poses, match.loop_keyframe_id, match.keyframe_id, match.T_world_cur_corrected)
        if moved <= budget * path:
            return None
        share = 100 * moved / max(path, 1e-12)
        return f"drift budget: the loop moves the keyframe {moved:.3f} m, {share:.1f}% of the {path:.2f} m path (budget {100 * budget:g}%)"

    # ---- correction ----------------------------------------------------------------------------------
    def correct(self, match: LoopMatch, with_scale: bool) -> tuple[int, int, dict]:
        """Correct the map for a verified ``match`` (ORB-SLAM's CorrectLoop, steps 0-3 above): points
        fused, loop connections, pose-graph stats. When the pose graph rejects the loop
        (``stats["loop_rejected"]``), before or after fusion, the map is left as it was."""
        bmap = self.map
        cur = match.keyframe_id
        poses_before = {k: kf.T_world_cam.copy() for k, kf in bmap.keyframes.items()}
        neighbourhood = [cur] + bmap.covisibility.connected(cur)
        correction = match.T_world_cur_corrected @ invert_T(poses_before[cur])  # world -> corrected world
        corrected = {k: correction @ poses_before[k] for k in neighbourhood}
        # The robust check first, with the neighbourhood tied to the loop keyframe, before anything in
        # the map changes: most wrong loops stop here, before points are fused (and put back).
        ties = [(min(k, match.loop_keyframe_id), max(k, match.loop_keyframe_id)) for k in neighbourhood]
        gate = self._optimize(poses_before, corrected, ties, match, with_scale)
        if gate.stats.get("loop_rejected"):
            return 0, 0, dict(gate.stats)
        neighbours_before = {k: set(bmap.covisibility.connected(k)) for k in neighbourhood}
        # The optimisation after fusion judges the loop again, on the links fusion made: should it
        # reject the loop then, the map goes back to this checkpoint (fused points and all).
        touched = {p for k in neighbourhood for p in bmap.keyframe_point_ids(k).tolist()}
        touched |= {*match.loop_point_ids.tolist(), *match.matched_point_ids.tolist()}
        checkpoint = bmap.checkpoint(touched, neighbourhood)
        self._move_neighbourhood(corrected, correction)
        fused = self._fuse_loop_points(match, neighbourhood)
        # ORB-SLAM's loop connections; when fusion linked nothing new, the ties of the check hold the loop.
        connections = self._loop_connections(neighbourhood, neighbours_before) or ties
        result = self._optimize(poses_before, corrected, connections, match, with_scale)
        if result.stats.get("loop_rejected"):
            bmap.restore(checkpoint)
            return 0, 0, dict(result.stats)
        correct_points_after_pose_graph(bmap, result)  # from the initial values: the corrected neighbourhood
        bmap.refresh_points()
        return fused, len(connections), dict(result.stats)

    def _optimize(self, poses_before, corrected, loop_edges, match: LoopMatch, with_scale: bool):
        """The essential graph's optimisation with ``loop_edges`` as the new loop edges, the loop keyframe fixed."""
        return optimize_essential_graph(
            poses_before=poses_before,
            corrected=corrected,
            edges=self.map.essential_graph.edges(),
            new_loop_edges=loop_edges,
            fixed={match.loop_keyframe_id},
            with_scale=with_scale,
            config=self.config.pose_graph,
        )

    def _move_neighbourhood(self, corrected: dict[int, np.ndarray], correction: np.ndarray) -> None:
        """Set the neighbourhood's ``corrected`` poses and apply ``correction`` to the points they observe (each once)."""
        bmap = self.map
        point_ids = sorted({int(p) for k in corrected for p in bmap.keyframe_point_ids(k).tolist()})
        if point_ids:
            p_world = np.array([bmap.points[p].p_world for p in point_ids])
            bmap.set_point_positions(point_ids, transform_points(correction, p_world))
        for k, T in corrected.items():
            bmap.set_keyframe_pose(k, T)

    def _fuse_loop_points(self, match: LoopMatch, neighbourhood: list[int]) -> int:
        """The loop's points take the place of the current keyframe's matched ones, then every loop
        point is projected into every neighbourhood keyframe and fused (ORB-SLAM's SearchAndFuse)."""
        bmap = self.map
        cur = bmap.keyframe(match.keyframe_id)
        fused = 0
        for keypoint, loop_point in zip(match.matched_keypoints.tolist(), match.matched_point_ids.tolist()):
            if loop_point not in bmap.points or match.keyframe_id in bmap.points[loop_point].observations:
                continue
            there = int(cur.map_point_ids[keypoint])
            if there >= 0:
                bmap.replace_point(there, loop_point)
            else:
                bmap.add_observation(loop_point, match.keyframe_id, keypoint)
            fused += 1
        bmap.refresh_points()
        fusion = dataclasses.replace(FusionConfig(), search_radius_px=self.config.fusion_radius_px)
        loop_points = [p for p in match.loop_point_ids.tolist() if p in bmap.points]
        for k in neighbourhood:
            fused += fuse_into_keyframe(bmap, k, loop_points, fusion)
        return fused

    def _loop_connections(self, neighbourhood: list[int], before: dict[int, set[int]]) -> list[tuple[int, int]]:
        """Covisibility links the fusion made from the neighbourhood to keyframes outside it (a < b)."""
        inside = set(neighbourhood)
        pairs = set()
        for k in neighbourhood:
            for other in self.map.covisibility.connected(k):
                if other not in inside and other not in before[k]:
                    pairs.add((min(k, other), max(k, other)))
        return sorted(pairs)
