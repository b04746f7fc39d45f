"""A DBoW2 vocabulary tree of 256-bit ORB descriptors: words, TF-IDF weights, transform and L1 score.

The tree is held as flat arrays over its nodes (node 0 is the root; every other node's parent has
a smaller id), as in DBoW2's text format. Leaves are the words, numbered in node order. A
descriptor descends from the root to the nearest child (Hamming distance, the first on a tie) until
it reaches a leaf; ``transform`` does this for all descriptors at once, level by level.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from functools import cached_property

import numpy as np

from zenslam.errors import VocabularyError
from zenslam.vocabulary.bow import BowVector, FeatureVector, l1_score
from zenslam.vocabulary.hamming import ABSENT

DESCRIPTOR_BYTES = 32  # 256-bit ORB (rBRIEF) descriptors
_WORDS_CHUNK = 1 << 16  # descriptors looked up together by ``words``: bounds the temporaries for large sets


class Vocabulary:
    """A vocabulary tree with branching ``k`` and depth ``L`` (DBoW2 TF-IDF weighting, L1 scoring).

    ``parents`` (n,) int: parent node of each node, -1 for the root (node 0), smaller than the node's
    own id otherwise; ``descriptors`` (n, 32) uint8 per node (the root's is unused); ``weights``
    (n,) float64: each word's idf = ln(N_images / n_images_with_word) (0 = stopped word; inner
    nodes' weights are unused). ``metadata`` holds free text (corpus, command) that our own format
    keeps. ``source`` names where it came from, for error messages.
    """

    def __init__(
        self,
        branching: int,
        depth: int,
        parents: np.ndarray,
        descriptors: np.ndarray,
        weights: np.ndarray,
        metadata: Mapping[str, str] | None = None,
        source: str = "<in memory>",
    ) -> None:
        self._source = source
        self._branching = int(branching)
        self._depth = int(depth)
        self._parents = _frozen(np.array(parents, dtype=np.int64))
        self._descriptors = np.array(descriptors, dtype=np.uint8, order="C")
        self._weights = np.array(weights, dtype=np.float64)
        self.metadata: dict[str, str] = dict(metadata or {})
        self._check()
        self._descriptors[0] = 0  # the root's descriptor and weight are never used: kept at 0, as no file stores them
        self._weights[0] = 0.0
        self._descriptors, self._weights = _frozen(self._descriptors), _frozen(self._weights)
        self._build_tables()

    # ---- structure -------------------------------------------------------------------------------

    def _fail(self, problem: str) -> VocabularyError:
        return VocabularyError(f"vocabulary {self._source}: {problem}")

    def _check(self) -> None:
        n = self._parents.shape[0]
        if self._branching < 2 or self._depth < 1:
            raise self._fail(f"branching k={self._branching} and depth L={self._depth} must be >= 2 and >= 1")
        if self._parents.ndim != 1 or n < 2:
            raise self._fail(f"has {n} nodes: a vocabulary needs a root and at least one word")
        if self._descriptors.shape != (n, DESCRIPTOR_BYTES):
            raise self._fail(
                f"node descriptors have shape {self._descriptors.shape}, expected ({n}, {DESCRIPTOR_BYTES}): "
                "zenslam uses 256-bit ORB descriptors"
            )
        if self._weights.shape != (n,) or not np.all(np.isfinite(self._weights)) or np.any(self._weights < 0):
            raise self._fail("word weights must be one finite, non-negative number per node")
        ids = np.arange(n)
        bad = np.flatnonzero((self._parents[1:] < 0) | (self._parents[1:] >= ids[1:]))
        if self._parents[0] != -1 or bad.size:
            first = int(bad[0]) + 1 if bad.size else 0
            raise self._fail(
                f"node {first} has parent {int(self._parents[first])}: every node's parent must come before it "
                "(the root, node 0, has none): the file is corrupt"
            )

    def _build_tables(self) -> None:
        n = self._parents.shape[0]
        n_children = np.bincount(self._parents[1:], minlength=n)
        self._is_leaf = n_children == 0
        self._node_of_word = np.flatnonzero(self._is_leaf)
        self._word_of_node = np.full(n, -1, dtype=np.int64)
        self._word_of_node[self._node_of_word] = np.arange(self._node_of_word.size)
        self._node_depth = np.zeros(n, dtype=np.int64)
        for _ in range(n):  # parents come first, so this settles after (tree height) passes
            updated = self._node_depth[self._parents[1:]] + 1
            if np.array_equal(updated, self._node_depth[1:]):
                break
            self._node_depth[1:] = updated
        self._height = int(self._node_depth.max())
        # Children of each inner node in one padded row: their ids, their descriptors as 4 x 64 bits,
        # and a penalty that keeps the padding from ever being the nearest.
        inner = np.flatnonzero(~self._is_leaf)
        self._inner_row = np.full(n, -1, dtype=np.int64)
        self._inner_row[inner] = np.arange(inner.size)
        width = int(n_children.max())
        children = np.argsort(self._parents[1:], kind="stable") + 1  # grouped by parent, in node order
        child_parent = self._parents[children]
        first_child = np.concatenate(([0], np.cumsum(n_children)))[child_parent]
        slot = np.arange(children.size) - first_child
        rows = self._inner_row[child_parent]
        self._child_nodes = np.zeros((inner.size, width), dtype=np.int64)
        self._child_nodes[rows, slot] = children
        self._child_desc = np.zeros((inner.size, width, 4), dtype=np.uint64)
        self._child_desc[rows, slot] = self._descriptors[children].view(np.uint64)
        self._child_penalty = np.full((inner.size, width), ABSENT, dtype=np.int32)
        self._child_penalty[rows, slot] = 0

    # ---- properties ------------------------------------------------------------------------------

    @property
    def branching(self) -> int:
        """k: the most children a node has (as trained)."""
        return self._branching

    @property
    def depth(self) -> int:
        """L: the most levels below the root (as trained)."""
        return self._depth

    @property
    def n_words(self) -> int:
        return int(self._node_of_word.size)

    @property
    def n_nodes(self) -> int:
        """Nodes including the root."""
        return int(self._parents.shape[0])

    @property
    def weighting(self) -> str:
        return "tf-idf"

    @property
    def scoring(self) -> str:
        return "L1-norm"

    @property
    def source(self) -> str:
        return self._source

    @cached_property
    def content_id(self) -> str:
        """The vocabulary's identity: ``sha256:`` and the hex SHA-256 of its tree (branching, depth,
        parents, node descriptors) and word weights, little-endian; metadata and file name do not count.
        Saved maps record it, because their bags of words are only valid under this vocabulary."""
        digest = hashlib.sha256()
        digest.update(np.array([self._branching, self._depth], dtype="<i8").tobytes())
        digest.update(np.ascontiguousarray(self._parents, dtype="<i8").tobytes())
        digest.update(np.ascontiguousarray(self._descriptors, dtype=np.uint8).tobytes())
        digest.update(np.ascontiguousarray(self._weights, dtype="<f8").tobytes())
        return "sha256:" + digest.hexdigest()

    @property
    def parents(self) -> np.ndarray:
        """(n_nodes,) int64, -1 for the root (read-only)."""
        return self._parents

    @property
    def descriptors(self) -> np.ndarray:
        """(n_nodes, 32) uint8 node descriptors (read-only)."""
        return self._descriptors

    @property
    def weights(self) -> np.ndarray:
        """(n_nodes,) float64 node weights: the idf of each word, 0 elsewhere (read-only)."""
        return self._weights

    @property
    def is_leaf(self) -> np.ndarray:
        return self._is_leaf

    @property
    def node_depth(self) -> np.ndarray:
        """(n_nodes,) int64 level of each node below the root (root 0)."""
        return self._node_depth

    @property
    def word_weights(self) -> np.ndarray:
        """(n_words,) float64 idf of each word."""
        return self._weights[self._node_of_word]

    def word_node(self, word_ids: np.ndarray) -> np.ndarray:
        """Node id of each word id."""
        return self._node_of_word[np.asarray(word_ids, dtype=np.int64)]

    def with_weights(self, word_weights: np.ndarray, metadata: Mapping[str, str] | None = None) -> Vocabulary:
        """The same tree with new word weights ((n_words,) float64)."""
        weights = np.zeros(self.n_nodes, dtype=np.float64)
        weights[self._node_of_word] = word_weights
        return Vocabulary(
            self._branching, self._depth, self._parents, self._descriptors, weights,
            self.metadata if metadata is None else metadata, self._source,
        )

    # ---- transform and score ---------------------------------------------------------------------

    def words(self, descriptors: np.ndarray) -> np.ndarray:
        """The word id of each descriptor ((N, 32) uint8 -> (N,) int64)."""
        d64 = self._as_words64(descriptors)
        words = np.empty(d64.shape[0], dtype=np.int64)
        for a in range(0, d64.shape[0], _WORDS_CHUNK):
            leaves, _ = self._descend(d64[a : a + _WORDS_CHUNK], node_level=0)
            words[a : a + leaves.size] = self._word_of_node[leaves]
        return words

    def transform(self, descriptors: np.ndarray, levels_up: int | None = None) -> tuple[BowVector, FeatureVector]:
        """The BowVector and FeatureVector of one image's descriptors ((N, 32) uint8).

        The FeatureVector groups the descriptors by their node ``levels_up`` levels above the
        leaves, i.e. at level ``L - levels_up`` below the root (a descriptor whose word is shallower
        is grouped under its word). ``levels_up=None`` takes level 2 (100 nodes at k=10), what
        ORB-SLAM uses with L=6 and levels_up=4.
        """
        d64 = self._as_words64(descriptors)
        if levels_up is None:
            node_level = min(2, self._depth)
        else:
            if levels_up < 0:
                raise ValueError(f"levels_up={levels_up} must be >= 0")
            node_level = max(self._depth - levels_up, 0)
        if d64.shape[0] == 0:
            return BowVector.empty(), FeatureVector.empty()
        leaves, grouping_nodes = self._descend(d64, node_level)
        weights = self._weights[leaves]
        kept = np.flatnonzero(weights > 0)  # stopped words (weight 0) are in neither vector, as in DBoW2
        if kept.size == 0:
            return BowVector.empty(), FeatureVector.empty()
        word_ids, inverse = np.unique(self._word_of_node[leaves[kept]], return_inverse=True)
        sums = np.bincount(inverse, weights=weights[kept], minlength=word_ids.size)
        bow = BowVector(word_ids.astype(np.int64), sums / sums.sum())
        nodes = grouping_nodes[kept]
        order = np.argsort(nodes, kind="stable")  # stable: indices stay ascending within a node
        node_ids, starts = np.unique(nodes[order], return_index=True)
        grouped = kept[order].astype(np.int64)
        ends = np.append(starts[1:], grouped.size)
        features = tuple(grouped[a:b] for a, b in zip(starts.tolist(), ends.tolist()))
        return bow, FeatureVector(node_ids.astype(np.int64), features)

    def score(self, a: BowVector, b: BowVector) -> float:
        """DBoW2's L1 score in [0, 1]: 1 - 0.5 * |a - b|_1 (1: identical, 0: no word shared)."""
        return l1_score(a, b)

    def _as_words64(self, descriptors: np.ndarray) -> np.ndarray:
        d = np.asarray(descriptors)
        if d.ndim != 2 or d.shape[1] != DESCRIPTOR_BYTES or d.dtype != np.uint8:
            raise VocabularyError(
                f"descriptors of shape {d.shape} and type {d.dtype} cannot be looked up in vocabulary {self._source}: "
                f"it holds 256-bit ORB descriptors, (N, {DESCRIPTOR_BYTES}) uint8"
            )
        return np.ascontiguousarray(d).view(np.uint64)

    def _descend(self, d64: np.ndarray, node_level: int) -> tuple[np.ndarray, np.ndarray]:
        """(leaf node of each descriptor, its node at ``node_level`` or its leaf if that is shallower)."""
        # numba (~60 MB, most of a second at a process's start) only where descriptors are looked up
        from zenslam.compiled import kernel_array
        from zenslam.vocabulary.descent import descend

        return descend(
            kernel_array(d64, np.uint64), self._inner_row, self._child_nodes, self._child_desc, self._child_penalty,
            self._node_depth, self._height, int(node_level),
        )  # fmt: skip

    def __repr__(self) -> str:
        return (
            f"Vocabulary(k={self._branching}, L={self._depth}, words={self.n_words}, nodes={self.n_nodes}, "
            f"weighting={self.weighting}, scoring={self.scoring}, source={self._source!r})"
        )


def _frozen(array: np.ndarray) -> np.ndarray:
    array = array.view()
    array.flags.writeable = False
    return array
