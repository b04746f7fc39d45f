"""The numpy formulations of local mapping's two searches, as they were before their kernels
(``epipolar_search``, ``fusion_search``): the tests check that the kernels give the same answers."""

from __future__ import annotations

import numpy as np

from zenslam.backend.map import frustum_projection
from zenslam.descriptors import hamming_distance_rows
from zenslam.geometry import transform_points


def node_candidates(kf1, kf2, idx1, idx2, F12, config, nodes1, nodes2):
    """``triangulation.candidate_pairs`` with nodes, each pair under one node as a row of arrays."""
    node1, node2 = nodes1[idx1], nodes2[idx2]
    order2 = np.argsort(node2, kind="stable")
    sorted2 = node2[order2]
    first = np.searchsorted(sorted2, node1, "left")
    count = np.where(node1 >= 0, np.searchsorted(sorted2, node1, "right") - first, 0)
    r = np.repeat(np.arange(len(node1)), count)
    c = order2[np.arange(len(r)) + np.repeat(first - (np.cumsum(count) - count), count)]
    lines = np.column_stack([kf1.keypoints_px[idx1], np.ones(len(idx1))]) @ F12
    a, b, offset = (np.take(coefficient, r) for coefficient in lines.T)
    uv2 = kf2.keypoints_px[idx2]
    u2, v2 = np.take(uv2[:, 0], c), np.take(uv2[:, 1], c)
    gate2 = np.take(config.epipolar_chi2 * kf2.level_sigma2[kf2.levels[idx2]], c) * np.take(lines[:, 0] ** 2 + lines[:, 1] ** 2, r)
    signed = a * u2 + b * v2 + offset
    near = signed * signed < gate2
    r, c = r[near], c[near]
    i1, i2 = idx1[r], idx2[c]
    dist = hamming_distance_rows(kf1.descriptors, i1, kf2.descriptors, i2)
    keep = dist <= config.max_descriptor_distance
    both_mono = (kf1.right_u[i1] < 0) & (kf2.right_u[i2] < 0)
    if np.any(both_mono):
        centre1_in_2 = transform_points(kf2.T_cam_world, kf1.centre_world[None])[0]
        if centre1_in_2[2] > 1e-9:
            epipole = kf2.calibration.K @ (centre1_in_2 / centre1_in_2[2])
            d2 = np.sum((kf2.keypoints_px[idx2] - epipole[:2]) ** 2, axis=1)
            close = d2 < config.epipole_min_distance_px**2 * kf2.scale_factors[kf2.levels[idx2]]
            keep &= ~(both_mono & close[c])
    return i1[keep], i2[keep], dist[keep]


def match_projected(kf, geometry, descriptors, config):
    """``point_fusion.match_projected``: (point rows, keypoints)."""
    empty = np.zeros(0, dtype=np.int64)
    if len(descriptors) == 0 or kf.n_keypoints == 0:
        return empty, empty
    proj = frustum_projection(kf, geometry, config.min_view_cos)
    rows = np.flatnonzero(proj.visible)
    predicted = proj.level[rows]
    radius = config.search_radius_px * kf.scale_factors[predicted]
    kp_u, kp_v = kf.keypoints_px[:, 0], kf.keypoints_px[:, 1]
    order = kf.u_order()
    sorted_u = np.take(kp_u, order)
    u, v = np.take(proj.px[:, 0], rows), np.take(proj.px[:, 1], rows)
    lo = np.searchsorted(sorted_u, u - radius, side="right")
    hi = np.searchsorted(sorted_u, u + radius, side="left")
    counts = np.maximum(hi - lo, 0)
    pair = np.repeat(np.arange(len(rows)), counts)
    offsets = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    kp = np.take(order, np.repeat(lo, counts) + offsets)
    dv = np.take(kp_v, kp) - np.take(v, pair)
    level = np.take(kf.levels, kp)
    pair_level = np.take(predicted, pair)
    keep = (np.abs(dv) < np.take(radius, pair)) & (level >= pair_level - 1) & (level <= pair_level)
    pair, kp, level, dv = pair[keep], kp[keep], level[keep], dv[keep]
    du = np.take(kp_u, kp) - np.take(u, pair)
    right_u = np.take(kf.right_u, kp)
    stereo = right_u >= 0
    err2 = (du**2 + dv**2) + np.where(stereo, (np.nan_to_num(np.take(proj.right_u[rows], pair)) - right_u) ** 2, 0.0)
    inv_sigma2 = 1.0 / np.take(kf.level_sigma2, level)
    keep = np.where(stereo, err2 * inv_sigma2 <= config.chi2_stereo, err2 * inv_sigma2 <= config.chi2_mono)
    p, kp = np.take(rows, pair[keep]), kp[keep]
    if len(p) == 0:
        return empty, empty
    dist = hamming_distance_rows(descriptors, p, kf.descriptors, kp)
    order = np.lexsort((kp, dist, p))
    p, kp, dist = p[order], kp[order], dist[order]
    good = dist <= config.max_descriptor_distance
    good[1:] &= p[1:] != p[:-1]
    return p[good].astype(np.int64), kp[good].astype(np.int64)
