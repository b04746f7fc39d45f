"""Training a vocabulary tree from images' ORB descriptors: hierarchical k-majority, then TF-IDF weights.

As DBoW2's ``TemplatedVocabulary::create``: the root's descriptors are split into k clusters, each
cluster again, down to depth L; a node with at most k descriptors gets one leaf child per
descriptor instead (distinct descriptors only here, so that no word is a copy of another), and a
node with a single distinct descriptor stays a leaf. The tree is grown one level at a time, every
node of a level clustered together (``k_majority``); nodes are numbered level by level. Each word's
weight is its idf, ln(N_images / n_i), n_i being the number of training images with a descriptor
in the word (a word in every image gets weight 0: it is stopped).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from zenslam.errors import ConfigError, VocabularyError
from zenslam.vocabulary.k_majority import k_majority
from zenslam.vocabulary.vocabulary import DESCRIPTOR_BYTES, Vocabulary

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrainingConfig:
    """How a vocabulary tree is trained; ORB-SLAM's ORBvoc.txt has k=10, L=6."""

    branching: int = 10  # k: children per node
    depth: int = 5  # L: levels below the root (up to k**L words)
    seed: int = 0  # seeds the k-means++ draws: the same descriptors and seed give the same vocabulary
    max_iterations: int = 30  # assignment passes per node; a node still changing after them keeps its last clusters

    def __post_init__(self) -> None:
        problems = []
        if not 2 <= self.branching <= 20:
            problems.append(f"branching={self.branching} must be 2 to 20 (DBoW2's text format allows up to 20)")
        if not 1 <= self.depth <= 10:
            problems.append(f"depth={self.depth} must be 1 to 10 (DBoW2's text format allows up to 10)")
        if self.max_iterations < 1:
            problems.append(f"max_iterations={self.max_iterations} must be >= 1")
        if problems:
            raise ConfigError("invalid vocabulary training configuration: " + "; ".join(problems))


LevelCallback = Callable[[int, int, int], None]  # (level, nodes split at it, descriptors still descending)


def train_vocabulary(
    images: Sequence[np.ndarray],
    config: TrainingConfig | None = None,
    on_level: LevelCallback | None = None,
    metadata: Mapping[str, str] | None = None,
) -> Vocabulary:
    """A vocabulary trained on ``images``, one (N_i, 32) uint8 descriptor array per training image.

    Every image counts as a document for the idf weights, an image without descriptors too.
    """
    config = config or TrainingConfig()
    for i, d in enumerate(images):
        if d.ndim != 2 or d.shape[1] != DESCRIPTOR_BYTES or d.dtype != np.uint8:
            raise VocabularyError(f"training image {i}: descriptors of shape {d.shape} and type {d.dtype}, expected (N, 32) uint8")
    descriptors = np.concatenate([np.asarray(d) for d in images]) if images else np.zeros((0, DESCRIPTOR_BYTES), np.uint8)
    if descriptors.shape[0] < 2:
        raise VocabularyError(f"cannot train a vocabulary from {descriptors.shape[0]} descriptors: give images with ORB features")
    start = time.perf_counter()
    parents, node_descriptors = _grow_tree(descriptors, config, on_level)
    tree = Vocabulary(config.branching, config.depth, parents, node_descriptors, np.zeros(parents.size), metadata)
    sizes = np.array([d.shape[0] for d in images], dtype=np.int64)
    image_of = np.repeat(np.arange(sizes.size), sizes)
    vocabulary = tree.with_weights(_idf(tree.words(descriptors), image_of, len(images), tree.n_words))
    logger.info(
        "trained a vocabulary of %d words (%d nodes, k=%d, L=%d) from %d descriptors of %d images in %.1f s",
        vocabulary.n_words, vocabulary.n_nodes, config.branching, config.depth, descriptors.shape[0], len(images),
        time.perf_counter() - start,
    )
    return vocabulary


def _idf(words: np.ndarray, image_of: np.ndarray, n_images: int, n_words: int) -> np.ndarray:
    """ln(n_images / images containing the word) per word; 0 for a word no image contains."""
    pairs = np.unique(image_of * n_words + words)
    containing = np.bincount(pairs % n_words, minlength=n_words)
    idf = np.zeros(n_words, dtype=np.float64)
    seen = containing > 0
    idf[seen] = np.log(n_images / containing[seen])
    return idf


def _grow_tree(
    descriptors: np.ndarray, config: TrainingConfig, on_level: LevelCallback | None
) -> tuple[np.ndarray, np.ndarray]:
    """(parents (n,) int64 with -1 for the root, node descriptors (n, 32) uint8), nodes level by level."""
    k = config.branching
    rng = np.random.default_rng(config.seed)
    parents: list[np.ndarray] = [np.array([-1], dtype=np.int64)]
    node_descriptors: list[np.ndarray] = [np.zeros((1, DESCRIPTOR_BYTES), dtype=np.uint8)]
    n_nodes = 1
    rows = np.arange(descriptors.shape[0])  # descriptors still descending, sorted by their node
    node = np.zeros(rows.size, dtype=np.int64)
    for level in range(1, config.depth + 1):
        if rows.size == 0:
            break
        level_start = time.perf_counter()
        seg = np.flatnonzero(np.concatenate(([True], node[1:] != node[:-1])))
        sizes = np.diff(np.append(seg, rows.size))
        group_of = np.repeat(np.arange(seg.size), sizes)
        child_in_group = np.full(rows.size, -1, dtype=np.int64)
        n_children = np.zeros(seg.size, dtype=np.int64)
        large = sizes > k
        placed = []  # (group of each child, its rank in the group, its descriptor)
        placed.append(_split_large(descriptors, rows, group_of, np.flatnonzero(large), seg, sizes, k, rng, config,
                                   child_in_group, n_children))
        placed.append(_split_small(descriptors, rows, group_of, np.flatnonzero(~large & (sizes > 1)), child_in_group,
                                   n_children))
        offsets = n_nodes + np.concatenate(([0], np.cumsum(n_children)))[:-1]
        total = int(n_children.sum())
        level_parents = np.empty(total, dtype=np.int64)
        level_descriptors = np.empty((total, DESCRIPTOR_BYTES), dtype=np.uint8)
        for groups, ranks, child_descriptors in placed:
            at = offsets[groups] + ranks - n_nodes
            level_parents[at] = node[seg[groups]]
            level_descriptors[at] = child_descriptors
        parents.append(level_parents)
        node_descriptors.append(level_descriptors)
        n_nodes += total
        descending = np.flatnonzero(child_in_group >= 0)
        new_node = offsets[group_of[descending]] + child_in_group[descending]
        order = np.argsort(new_node, kind="stable")
        rows, node = rows[descending[order]], new_node[order]
        logger.debug("level %d: %d nodes split into %d in %.1f s", level, int((n_children > 0).sum()), total,
                     time.perf_counter() - level_start)
        if on_level is not None:
            on_level(level, int((n_children > 0).sum()), int(rows.size))
    return np.concatenate(parents), np.concatenate(node_descriptors)


def _split_large(descriptors, rows, group_of, groups, seg, sizes, k, rng, config, child_in_group, n_children):
    """k-majority on every group of more than k descriptors; fills ``child_in_group`` and ``n_children``."""
    if groups.size == 0:
        return _nothing_placed()
    members = np.flatnonzero(np.isin(group_of, groups, assume_unique=False)) if groups.size < seg.size else np.arange(rows.size)
    starts = np.concatenate(([0], np.cumsum(sizes[groups])))
    result = k_majority(descriptors[rows[members]], starts, k, rng, config.max_iterations)
    logger.debug("k-majority on %d nodes of %d descriptors: %d passes", groups.size, members.size, result.iterations)
    rank = np.cumsum(result.present, axis=1) - 1
    local_group = np.repeat(np.arange(groups.size), sizes[groups])
    child_in_group[members] = rank[local_group, result.labels]
    n_children[groups] = result.present.sum(axis=1)
    g, slot = np.nonzero(result.present)
    return groups[g], rank[g, slot], result.centres[g, slot]


def _split_small(descriptors, rows, group_of, groups, child_in_group, n_children):
    """One leaf child per distinct descriptor of every group of 2..k descriptors (none when all are equal)."""
    if groups.size == 0:
        return _nothing_placed()
    members = np.flatnonzero(np.isin(group_of, groups))
    d64 = descriptors[rows[members]].view(np.uint64)
    member_group = group_of[members]
    order = np.lexsort((d64[:, 3], d64[:, 2], d64[:, 1], d64[:, 0], member_group))
    sorted_d64, sorted_group = d64[order], member_group[order]
    new_group = np.concatenate(([True], sorted_group[1:] != sorted_group[:-1]))
    distinct = new_group | np.concatenate(([True], np.any(sorted_d64[1:] != sorted_d64[:-1], axis=1)))
    distinct_index = np.cumsum(distinct) - 1
    first_distinct_of_group = distinct_index[np.flatnonzero(new_group)]
    group_rank = np.cumsum(new_group) - 1
    rank = distinct_index - first_distinct_of_group[group_rank]
    count = np.bincount(group_rank, weights=distinct, minlength=groups.size).astype(np.int64)
    splits = count > 1
    keep = splits[group_rank]
    child_in_group[members[order[keep]]] = rank[keep]
    n_children[groups[splits]] = count[splits]
    firsts = distinct & keep
    return sorted_group[firsts], rank[firsts], sorted_d64[firsts].view(np.uint8).reshape(-1, DESCRIPTOR_BYTES)


def _nothing_placed() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, DESCRIPTOR_BYTES), np.uint8)


def expected_nodes(branching: int, depth: int) -> int:
    """Nodes of a full tree (root included): (k**(L+1) - 1) / (k - 1)."""
    return (branching ** (depth + 1) - 1) // (branching - 1)

