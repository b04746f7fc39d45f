"""Bag-of-words vectors of one image: the weighted words (BowVector) and the direct index (FeatureVector)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)  # arrays: compare fields explicitly
class BowVector:
    """The words of one image with their TF-IDF weights, L1-normalised (weights sum to 1).

    ``word_ids`` (W,) int64 ascending, unique; ``weights`` (W,) float64, all > 0.
    """

    word_ids: np.ndarray
    weights: np.ndarray

    def __len__(self) -> int:
        return int(self.word_ids.shape[0])

    @staticmethod
    def empty() -> BowVector:
        return BowVector(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.float64))


@dataclass(frozen=True, eq=False)
class FeatureVector:
    """DBoW2's direct index: the descriptors of one image grouped by the vocabulary node they fall under.

    ``node_ids`` (M,) int64 ascending, unique; ``features[i]`` the ascending (int64) indices of the
    descriptors under node ``node_ids[i]``. Descriptors whose word is stopped (weight 0) are in none.
    """

    node_ids: np.ndarray
    features: tuple[np.ndarray, ...]

    def __len__(self) -> int:
        return int(self.node_ids.shape[0])

    @staticmethod
    def empty() -> FeatureVector:
        return FeatureVector(np.zeros(0, dtype=np.int64), ())

    def node_of_features(self, n_features: int) -> np.ndarray:
        """(n_features,) int64: the node each of the image's ``n_features`` descriptors is under, -1
        for those in none (a stopped word)."""
        nodes = np.full(n_features, -1, dtype=np.int64)
        if len(self.features):
            nodes[np.concatenate(self.features)] = np.repeat(self.node_ids, [len(f) for f in self.features])
        return nodes


def l1_score(a: BowVector, b: BowVector) -> float:
    """DBoW2's L1 score of two L1-normalised vectors: 1 - 0.5 * |a - b|_1, in [0, 1] (1: same words, same weights).

    Computed over the shared words only, as DBoW2 does: |a - b|_1 = 2 - sum over shared words of
    (|a_i| + |b_i| - |a_i - b_i|).
    """
    _, ia, ib = np.intersect1d(a.word_ids, b.word_ids, assume_unique=True, return_indices=True)
    if ia.size == 0:
        return 0.0
    va, vb = a.weights[ia], b.weights[ib]
    return float(0.5 * np.sum(np.abs(va) + np.abs(vb) - np.abs(va - vb)))
