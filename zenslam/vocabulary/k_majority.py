"""k-majority clustering of binary descriptors, run on many independent groups at once.

k-means for 256-bit strings: Hamming distance, and each centre is the bitwise majority of its
members (a bit is set when at least half of them have it, as DBoW2's FORB::meanValue); k-means++
seeding (each new centre drawn with probability proportional to the squared distance to the nearest
centre already chosen). One level of a vocabulary tree clusters every node of the level above, up
to tens of thousands of groups, so every step runs on all groups together: descriptors are sorted
by group, centres are a (groups, k) table, and a group stops iterating once its assignment is
stable (DBoW2's criterion), or after ``max_iterations``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zenslam.vocabulary.hamming import ABSENT, first_nearest

_CHUNK_ROWS = 1 << 16  # descriptors per vectorised block: bounds the temporaries to ~20-30 MB
_LARGE_GROUP = 4096  # descriptors from which a group's distances are computed without gathering its centres
_MAX_RUN = 255  # members summed in one 8-bit lane before the lanes are widened
_LANE_ONES = np.uint64(0x0101010101010101)


@dataclass(frozen=True, eq=False)
class Clustering:
    """The result for G groups: ``centres`` (G, k, 32) uint8, ``present`` (G, k) bool (a centre that
    was seeded and has members), ``labels`` (M,) int64 in [0, k): each descriptor's centre within its
    group, the nearest one (the first on a tie), ``iterations`` the assignment passes made."""

    centres: np.ndarray
    present: np.ndarray
    labels: np.ndarray
    iterations: int


def k_majority(
    descriptors: np.ndarray, group_starts: np.ndarray, k: int, rng: np.random.Generator, max_iterations: int
) -> Clustering:
    """Cluster each group of ``descriptors`` ((M, 32) uint8, sorted so that group g is rows
    ``group_starts[g]:group_starts[g+1]``, every group non-empty) into at most ``k`` clusters."""
    d8 = np.ascontiguousarray(descriptors, dtype=np.uint8)
    d64 = d8.view(np.uint64)
    starts = np.asarray(group_starts, dtype=np.int64)
    sizes = np.diff(starts)
    group_of = np.repeat(np.arange(sizes.size), sizes)
    centres, penalty = _seed(d64, starts, group_of, k, rng)
    rows = np.arange(d64.shape[0])
    labels = _assign(d64, rows, group_of, centres, penalty)
    active = np.ones(sizes.size, dtype=bool)
    iterations = 1
    while iterations < max_iterations:
        rows = np.flatnonzero(active[group_of])
        if rows.size == 0:
            break
        _update_centres(d8, rows, group_of[rows] * k + labels[rows], centres.reshape(-1, 4))
        new = _assign(d64, rows, group_of, centres, penalty)
        changed = new != labels[rows]
        labels[rows] = new
        iterations += 1
        active[:] = False
        active[group_of[rows[changed]]] = True
    counts = np.bincount(group_of * k + labels, minlength=sizes.size * k).reshape(-1, k)
    present = (penalty == 0) & (counts > 0)
    return Clustering(centres.view(np.uint8).reshape(-1, k, 32), present, labels, iterations)


def _distances(d64: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Row-wise Hamming distances between (n, 4) uint64 descriptors and (n, 4) uint64 centres, int64."""
    counts = np.bitwise_count(centres ^ d64)
    # Two words add up to at most 128, safe in uint8; the total (up to 256) is not.
    return (counts[:, 0] + counts[:, 1]).astype(np.int64) + (counts[:, 2] + counts[:, 3])


def _seed(
    d64: np.ndarray, starts: np.ndarray, group_of: np.ndarray, k: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """k-means++ seeds of every group: (G, k, 4) uint64 centres and the (G, k) int32 absent-slot penalty.

    A group whose points all coincide with its centres stops early; its remaining slots stay absent.
    Each draw is exact integer arithmetic on one cumulative sum over all groups, so the seeds do not
    depend on floating-point summation order.
    """
    n_groups = starts.size - 1
    sizes = np.diff(starts)
    centres = np.zeros((n_groups, k, 4), dtype=np.uint64)
    penalty = np.full((n_groups, k), ABSENT, dtype=np.int32)
    first = starts[:-1] + np.minimum((rng.random(n_groups) * sizes).astype(np.int64), sizes - 1)
    centres[:, 0] = d64[first]
    penalty[:, 0] = 0
    nearest = _distances(d64, centres[group_of, 0])
    for slot in range(1, k):
        draw = 1.0 - rng.random(n_groups)  # in (0, 1]
        weight = nearest * nearest
        cumulative = np.cumsum(weight)
        before = np.concatenate(([0], cumulative))[starts[:-1]]
        total = cumulative[starts[1:] - 1] - before
        seeded = np.flatnonzero(total > 0)
        if seeded.size == 0:
            break
        target = before[seeded] + np.clip(np.ceil(draw[seeded] * total[seeded]).astype(np.int64), 1, total[seeded])
        chosen = np.searchsorted(cumulative, target, side="left")  # first point whose cumulative weight reaches it
        centres[seeded, slot] = d64[chosen]
        penalty[seeded, slot] = 0
        in_seeded = np.flatnonzero(penalty[group_of, slot] == 0)
        nearest[in_seeded] = np.minimum(nearest[in_seeded], _distances(d64[in_seeded], centres[group_of[in_seeded], slot]))
    return centres, penalty


def _assign(
    d64: np.ndarray, rows: np.ndarray, group_of: np.ndarray, centres: np.ndarray, penalty: np.ndarray
) -> np.ndarray:
    """Index of the nearest centre of its group (the first on a tie) for each of ``rows`` (ascending).

    Groups are contiguous in ``rows``. Distances are computed one centre slot and one 64-bit word
    at a time over word-major blocks of descriptors, which keeps the temporaries in cache; a large
    group's centre is a scalar there, the small groups' centres are gathered per row.
    """
    out = np.empty(rows.size, dtype=np.int64)
    slots = np.ascontiguousarray(centres.transpose(1, 2, 0))  # (k, 4, G)
    slot_penalty = np.ascontiguousarray(penalty.T)  # (k, G)
    g = group_of[rows]
    new_run = np.concatenate(([True], g[1:] != g[:-1]))
    run = np.flatnonzero(new_run)
    run_end = np.append(run[1:], rows.size)
    large = (run_end - run) >= _LARGE_GROUP
    for start, end, group in zip(run[large], run_end[large], g[run[large]]):
        for a in range(start, end, _CHUNK_ROWS):
            r = rows[a : min(a + _CHUNK_ROWS, end)]
            out[a : a + r.size] = first_nearest(np.ascontiguousarray(d64[r].T), slots[:, :, group], slot_penalty[:, group])
    small = np.flatnonzero(~large[np.cumsum(new_run) - 1])
    for a in range(0, small.size, _CHUNK_ROWS):
        at = small[a : a + _CHUNK_ROWS]
        gs = g[at]
        out[at] = first_nearest(np.ascontiguousarray(d64[rows[at]].T), slots[:, :, gs], slot_penalty[:, gs])
    return out


def _update_centres(descriptors: np.ndarray, rows: np.ndarray, labels: np.ndarray, centres64: np.ndarray) -> None:
    """Set each labelled cluster's centre (a row of ``centres64``, (G*k, 4) uint64) to the bitwise
    majority of its members among ``rows``; centres of clusters without members are left as they are.

    The bits are counted eight lanes per 64-bit word: bit plane b of every byte ((x >> b) & 0x01..01)
    summed over at most 255 members cannot carry into the next byte. Members are sorted by label and
    cut into runs of at most 255; runs of one cluster are then added up in int32.
    """
    by_label = np.argsort(labels, kind="stable")
    order, sorted_labels = rows[by_label], labels[by_label]
    seg = np.flatnonzero(np.concatenate(([True], sorted_labels[1:] != sorted_labels[:-1])))
    seg_size = np.diff(np.append(seg, sorted_labels.size))
    runs_per_seg = -(-seg_size // _MAX_RUN)
    first_run = np.concatenate(([0], np.cumsum(runs_per_seg)))[:-1]
    run_start = np.repeat(seg, runs_per_seg) + _MAX_RUN * (np.arange(runs_per_seg.sum()) - np.repeat(first_run, runs_per_seg))
    d64 = descriptors.view(np.uint64)
    run_sums = np.empty((run_start.size, 8, 4), dtype=np.uint64)
    for a in range(0, run_start.size, _CHUNK_ROWS // 16):
        starts = run_start[a : a + _CHUNK_ROWS // 16]
        stop = run_start[a + starts.size] if a + starts.size < run_start.size else order.size
        block = d64[order[starts[0] : stop]]
        local = starts - starts[0]
        for b in range(8):
            run_sums[a : a + starts.size, b] = np.add.reduceat((block >> np.uint64(b)) & _LANE_ONES, local, axis=0)
    counts = run_sums.view(np.uint8).reshape(-1, 8, 32).astype(np.int32)  # (runs, bit, byte)
    if run_start.size != seg.size:
        counts = np.add.reduceat(counts, first_run, axis=0)
    majority = 2 * counts >= seg_size[:, None, None]
    centre_bytes = np.zeros((seg.size, 32), dtype=np.uint8)
    for b in range(8):
        centre_bytes |= majority[:, b, :].astype(np.uint8) << np.uint8(b)
    centres64[sorted_labels[seg]] = centre_bytes.view(np.uint64)
