"""The GTSAM side of the essential-graph optimisation (``zenslam.backend.pose_graph`` describes it).

Kept apart so that the configuration and the result types load without gtsam.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import gtsam
import numpy as np

from zenslam.backend import gtsam_keys
from zenslam.backend.essential_graph import EssentialEdge
from zenslam.backend.pose_graph_types import PoseGraphConfig, PoseGraphError, PoseGraphResult, similarity_parts

logger = logging.getLogger(__name__)


def solve(
    poses_before: dict[int, np.ndarray],
    corrected: dict[int, np.ndarray],
    edges: list[EssentialEdge],
    new_loop_edges: list[tuple[int, int]],
    fixed: set[int],
    with_scale: bool,
    config: PoseGraphConfig,
) -> PoseGraphResult:
    """``pose_graph.optimize_essential_graph`` on checked input."""
    start = time.perf_counter()
    kf_ids = sorted(poses_before)
    before = _values_of({k: poses_before[k] for k in kf_ids}, with_scale)
    initial_matrices = {k: np.asarray(corrected.get(k, poses_before[k]), dtype=float).copy() for k in kf_ids}
    initial = {**before, **_values_of({k: corrected[k] for k in sorted(corrected)}, with_scale)}
    built = _build_graph(before, initial, edges, new_loop_edges, set(fixed), with_scale, config)
    free = [k for k in kf_ids if k not in fixed]
    values_corrected = _values(free, initial, with_scale)
    if config.robust == "gnc":
        result, weights = _optimize_gnc(built, values_corrected, config)
    else:
        result, weights = _optimize_lm(built.graph, values_corrected, config), None
    new_weights = _loop_weights(built, result, weights, config, built.new_loop)
    rejected = bool(new_weights) and max(new_weights.values()) < config.reject_below_weight
    if rejected:
        result = _values(free, before, with_scale)
    at = result.atSimilarity3 if with_scale else result.atPose3
    T_out, s_out = {}, {}
    for k in kf_ids:
        if k in fixed and not with_scale:  # held: the input, bit for bit
            T_out[k], s_out[k] = np.array(poses_before[k] if rejected else initial_matrices[k], dtype=float), 1.0
        else:
            T_out[k], s_out[k] = _matrix((before if rejected else initial)[k] if k in fixed else at(gtsam_keys.pose_key(k)), with_scale)
    loop_weights = _loop_weights(built, result, weights, config)
    stats = {
        "time_ms": 1e3 * (time.perf_counter() - start),
        "n_keyframes": len(kf_ids),
        "n_edges": int(built.graph.size()),
        "n_loop_edges": len(built.loops),
        "robust": config.robust,
        "loop_rejected": rejected,
        "initial_error": float(built.graph.error(values_corrected)),
        "final_error": float(built.graph.error(result)),
        "loop_inliers": int(sum(w > 0.5 for w in loop_weights.values())),
    }
    logger.debug("essential graph: %s", stats)
    return PoseGraphResult(T_out, s_out, initial_matrices, loop_weights, stats)


def _values_of(poses: dict[int, np.ndarray], with_scale: bool) -> dict:
    """The gtsam variables (Pose3, or Similarity3) of similarity matrices by keyframe id."""
    ids = list(poses)
    if not ids:
        return {}
    R, c, s = similarity_parts(np.stack([poses[k] for k in ids]))
    if with_scale:
        return {k: gtsam.Similarity3(gtsam.Rot3(R[i]), c[i] / s[i], float(s[i])) for i, k in enumerate(ids)}
    off = np.flatnonzero(np.abs(s - 1.0) > 1e-9)
    if len(off):
        raise PoseGraphError(
            f"a rigid pose graph got keyframe {ids[off[0]]} with scale {s[off[0]]}; use with_scale=True for Sim(3)"
        )
    return {k: gtsam.Pose3(gtsam.Rot3(R[i]), c[i]) for i, k in enumerate(ids)}


def _matrix(value, with_scale: bool) -> tuple[np.ndarray, float]:
    """Rigid T_world_cam (4, 4) and scale of a Pose3 / Similarity3 variable."""
    T = np.eye(4)
    if with_scale:
        s = float(value.scale())
        T[:3, :3], T[:3, 3] = value.rotation().matrix(), s * np.asarray(value.translation())
        return T, s
    return value.matrix(), 1.0


@dataclass
class _Graph:
    """The factor graph and what the result needs to read it."""

    graph: gtsam.NonlinearFactorGraph
    # per loop edge: (a, b) with a < b, its index in the graph, the same factor without the kernel
    loops: list[tuple[tuple[int, int], int, gtsam.NonlinearFactor]] = field(default_factory=list)
    new_loop: set[tuple[int, int]] = field(default_factory=set)  # the new loop edges among them


def _values(free: list[int], poses: dict, with_scale: bool) -> gtsam.Values:
    values = gtsam.Values()
    for k in free:
        values.insert(gtsam_keys.pose_key(k), poses[k])
    return values


def _noise(with_scale: bool, config: PoseGraphConfig, factor: float = 1.0) -> gtsam.noiseModel.Base:
    sigmas = [config.sigma_rotation_rad] * 3 + [config.sigma_translation_m] * 3
    if with_scale:
        sigmas.append(config.sigma_log_scale)  # Similarity3 tangent: rotation, translation, log scale
    return gtsam.noiseModel.Diagonal.Sigmas(factor * np.array(sigmas))


def covisibility_sigma_factor(edges: list[EssentialEdge], config: PoseGraphConfig, with_scale: bool) -> float:
    """What the covisibility edges' sigmas are multiplied by: sqrt(covisibility / other edges), at
    least 1, where the graph's setting (``covisibility_information``, or ``..._monocular`` for a
    Sim(3) graph) is "shared"; 1 where it is "full"."""
    setting = config.covisibility_information_monocular if with_scale else config.covisibility_information
    if setting == "full":
        return 1.0
    n_covisibility = sum(1 for edge in edges if edge[2] == "covisibility")
    return float(np.sqrt(max(1.0, n_covisibility / max(1, len(edges) - n_covisibility))))


def _build_graph(before, initial, edges, new_loop_edges, fixed, with_scale, config) -> _Graph:
    """Between factors (priors where one end is fixed), in a fixed order: essential edges, then new loop edges."""
    plain = _noise(with_scale, config)
    covisible = _noise(with_scale, config, covisibility_sigma_factor(edges, config, with_scale))
    robust = plain
    if config.robust == "cauchy":
        robust = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(config.cauchy_k), plain)
    new_pairs = {(min(a, b), max(a, b)) for a, b in new_loop_edges}
    measured: list[tuple[int, int, object, str]] = []  # a, b, relative pose a -> b, edge kind
    for a, b, kind in sorted(edges):
        if (min(a, b), max(a, b)) not in new_pairs:
            measured.append((a, b, before[a].between(before[b]), kind))
    for a, b in sorted(new_pairs):
        measured.append((a, b, initial[a].between(initial[b]), "loop"))
    noise = {"loop": robust, "covisibility": covisible, "spanning_tree": plain}
    out = _Graph(gtsam.NonlinearFactorGraph())
    for a, b, z, kind in measured:
        is_loop = kind == "loop"
        if a in fixed and b in fixed:
            continue
        if is_loop:
            pair = (min(a, b), max(a, b))
            out.loops.append((pair, out.graph.size(), _edge_factor(a, b, z, plain, initial, fixed, with_scale)))
            if pair in new_pairs:
                out.new_loop.add(pair)
        out.graph.add(_edge_factor(a, b, z, noise[kind], initial, fixed, with_scale))
    return out


def _edge_factor(a: int, b: int, z, noise, initial: dict, fixed: set[int], with_scale: bool) -> gtsam.NonlinearFactor:
    """The factor of relative pose z from a to b: a between factor, or a prior on the free end."""
    if a in fixed:  # T_b = T_a z
        prior = gtsam.PriorFactorSimilarity3 if with_scale else gtsam.PriorFactorPose3
        return prior(gtsam_keys.pose_key(b), initial[a].compose(z), noise)
    if b in fixed:  # T_a = T_b z^-1
        prior = gtsam.PriorFactorSimilarity3 if with_scale else gtsam.PriorFactorPose3
        return prior(gtsam_keys.pose_key(a), initial[b].compose(z.inverse()), noise)
    between = gtsam.BetweenFactorSimilarity3 if with_scale else gtsam.BetweenFactorPose3
    return between(gtsam_keys.pose_key(a), gtsam_keys.pose_key(b), z, noise)


def _lm_params(config: PoseGraphConfig) -> gtsam.LevenbergMarquardtParams:
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(config.iterations)
    params.setRelativeErrorTol(config.relative_error_tolerance)
    return params


def _optimize_lm(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, config: PoseGraphConfig) -> gtsam.Values:
    if graph.size() == 0:
        return values
    return gtsam.LevenbergMarquardtOptimizer(graph, values, _lm_params(config)).optimize()


def _optimize_gnc(built: _Graph, values: gtsam.Values, config: PoseGraphConfig) -> tuple[gtsam.Values, np.ndarray]:
    """GNC over the graph (built without kernels): non-loop factors are known inliers."""
    if built.graph.size() == 0:
        return values, np.ones(0)
    params = gtsam.GncLMParams(_lm_params(config))
    params.setLossType(gtsam.GncLossType.TLS if config.gnc_loss == "tls" else gtsam.GncLossType.GM)
    loops = {index for _, index, _ in built.loops}
    params.setKnownInliers([i for i in range(built.graph.size()) if i not in loops])
    optimizer = gtsam.GncLMOptimizer(built.graph, values, params)
    optimizer.setInlierCostThresholdsAtProbability(config.gnc_inlier_probability)
    result = optimizer.optimize()
    return result, np.asarray(optimizer.getWeights())


def _loop_weights(
    built: _Graph, result: gtsam.Values, gnc_weights, config: PoseGraphConfig, only: set | None = None
) -> dict[tuple[int, int], float]:
    """Each loop edge's final weight (of the edges ``only``, default all): GNC's, or the Cauchy weight
    1 / (1 + r^2 / k^2) at the result."""
    out = {}
    for pair, index, factor in built.loops:
        if only is not None and pair not in only:
            continue
        if gnc_weights is not None:
            out[pair] = float(gnc_weights[index])
        elif config.robust == "cauchy":
            r2 = 2.0 * factor.error(result)
            out[pair] = 1.0 / (1.0 + r2 / config.cauchy_k**2)
        else:
            out[pair] = 1.0
    return out


