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
        first = np.flatnonzero(np.concatenate(([True], node[1:] != node[:-1])))  # first row of each node
        sizes = np.diff(np.append(first, rows.size))
        group_of = np.repeat(np.arange(first.size), sizes)  # node of each row, as an index into ``first``
        splits = (
            _split_large(descriptors, rows, group_of, sizes, sizes > config.branching, config, rng),
            _split_small(descriptors, rows, group_of, (sizes > 1) & (sizes <= config.branching)),
        )
        n_children = np.bincount(np.concatenate([s.child_group for s in splits]), minlength=first.size)
        offsets = n_nodes + np.concatenate(([0], np.cumsum(n_children)))[:-1]  # id of each node's first child
        total = int(n_children.sum())
        level_parents = np.empty(total, dtype=np.int64)
        level_descriptors = np.empty((total, DESCRIPTOR_BYTES), dtype=np.uint8)
        child_of_row = np.full(rows.size, -1, dtype=np.int64)
        for split in splits:
            at = offsets[split.child_group] + split.child_rank - n_nodes
            level_parents[at] = node[first[split.child_group]]
            level_descriptors[at] = split.child_descriptors
            going_on = split.member_child >= 0
            members = split.members[going_on]
            child_of_row[members] = offsets[group_of[members]] + split.member_child[going_on]
        parents.append(level_parents)
        node_descriptors.append(level_descriptors)
        n_nodes += total
        descending = np.flatnonzero(child_of_row >= 0)
        order = np.argsort(child_of_row[descending], kind="stable")
        rows, node = rows[descending[order]], child_of_row[descending[order]]
        split_nodes = int((n_children > 0).sum())
        logger.debug("level %d: %d nodes split into %d in %.1f s", level, split_nodes, total, time.perf_counter() - level_start)
        if on_level is not None:
            on_level(level, split_nodes, int(rows.size))
    return np.concatenate(parents), np.concatenate(node_descriptors)


@dataclass(frozen=True, eq=False)
class _Split:
    """Children made for some nodes of a level.

    ``members``: the rows split; ``member_child``: the rank (among its node's children) of the child
    each goes to, -1 when its node gets none. Per child: ``child_group`` (its node, an index into
    the level's nodes), ``child_rank`` and ``child_descriptors``.
    """

    members: np.ndarray
    member_child: np.ndarray
    child_group: np.ndarray
    child_rank: np.ndarray
    child_descriptors: np.ndarray


def _split_large(
    descriptors: np.ndarray, rows: np.ndarray, group_of: np.ndarray, sizes: np.ndarray, chosen: np.ndarray,
    config: TrainingConfig, rng: np.random.Generator,
) -> _Split:
    """k-majority on the ``chosen`` nodes (more than k descriptors each): one child per non-empty cluster."""
    groups = np.flatnonzero(chosen)
    members = np.flatnonzero(chosen[group_of])
    if groups.size == 0:
        return _nothing_split()
    starts = np.concatenate(([0], np.cumsum(sizes[groups])))
    result = k_majority(descriptors[rows[members]], starts, config.branching, rng, config.max_iterations)
    logger.debug("k-majority on %d nodes of %d descriptors: %d passes", groups.size, members.size, result.iterations)
    rank = np.cumsum(result.present, axis=1) - 1  # empty clusters get no child: ranks skip them
    local_group = np.repeat(np.arange(groups.size), sizes[groups])
    g, slot = np.nonzero(result.present)
    return _Split(members, rank[local_group, result.labels], groups[g], rank[g, slot], result.centres[g, slot])


def _split_small(descriptors: np.ndarray, rows: np.ndarray, group_of: np.ndarray, chosen: np.ndarray) -> _Split:
    """One leaf child per distinct descriptor of the ``chosen`` nodes (2..k descriptors; none when all are equal)."""
    members = np.flatnonzero(chosen[group_of])
    if members.size == 0:
        return _nothing_split()
    d64 = descriptors[rows[members]].view(np.uint64)
    member_group = group_of[members]
    order = np.lexsort((d64[:, 3], d64[:, 2], d64[:, 1], d64[:, 0], member_group))  # by node, then descriptor
    sorted_d64, sorted_group = d64[order], member_group[order]
    new_group = np.concatenate(([True], sorted_group[1:] != sorted_group[:-1]))
    distinct = new_group | np.concatenate(([True], np.any(sorted_d64[1:] != sorted_d64[:-1], axis=1)))
    distinct_index = np.cumsum(distinct) - 1
    group_rank = np.cumsum(new_group) - 1
    rank = distinct_index - distinct_index[np.flatnonzero(new_group)][group_rank]
    count = np.bincount(group_rank, weights=distinct).astype(np.int64)
    keep = (count > 1)[group_rank]
    member_child = np.full(members.size, -1, dtype=np.int64)
    member_child[order[keep]] = rank[keep]
    firsts = distinct & keep
    return _Split(members, member_child, sorted_group[firsts], rank[firsts],
                  sorted_d64[firsts].view(np.uint8).reshape(-1, DESCRIPTOR_BYTES))


def _nothing_split() -> _Split:
    empty = np.zeros(0, np.int64)
    return _Split(empty, empty, empty, empty, np.zeros((0, DESCRIPTOR_BYTES), np.uint8))


def expected_nodes(branching: int, depth: int) -> int:
    """Nodes of a full tree (root included): (k**(L+1) - 1) / (k - 1)."""
    return (branching ** (depth + 1) - 1) // (branching - 1)

