"""Synthetic descriptors and small hand-built trees with known structure, for the vocabulary tests."""

from __future__ import annotations

import numpy as np

from zenslam.vocabulary.vocabulary import Vocabulary


def random_descriptors(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.integers(0, 256, size=(n, 32), dtype=np.uint8)


def flip_bits(rng: np.random.Generator, descriptors: np.ndarray, n_bits: int) -> np.ndarray:
    """Each descriptor with exactly ``n_bits`` distinct bits flipped."""
    bits = np.unpackbits(descriptors, axis=1)
    for row in bits:
        row[rng.choice(256, size=n_bits, replace=False)] ^= 1
    return np.packbits(bits, axis=1)


def clustered_descriptors(rng: np.random.Generator, centres: np.ndarray, per_centre: int, n_bits: int):
    """(descriptors, true centre of each): ``per_centre`` copies of each centre with ``n_bits`` flipped."""
    truth = np.repeat(np.arange(centres.shape[0]), per_centre)
    return flip_bits(rng, centres[truth], n_bits), truth


def full_tree(rng: np.random.Generator, k: int, depth: int, weights: np.ndarray | None = None) -> Vocabulary:
    """A complete k-ary tree of random node descriptors, nodes numbered level by level."""
    parents = [-1]
    level = [0]
    for _ in range(depth):
        nxt = []
        for p in level:
            for _ in range(k):
                parents.append(p)
                nxt.append(len(parents) - 1)
        level = nxt
    n = len(parents)
    if weights is None:
        weights = rng.uniform(0.5, 2.0, size=n)
    return Vocabulary(k, depth, np.array(parents), random_descriptors(rng, n), weights)


def descend_one(vocabulary: Vocabulary, descriptor: np.ndarray) -> list[int]:
    """Reference: the path of nodes (root excluded) one descriptor takes, one comparison at a time."""
    children: dict[int, list[int]] = {}
    for node, parent in enumerate(vocabulary.parents.tolist()):
        if parent >= 0:
            children.setdefault(parent, []).append(node)
    path = []
    node = 0
    while node in children:
        best, best_d = None, 1 << 30
        for child in children[node]:
            d = int(np.unpackbits(vocabulary.descriptors[child] ^ descriptor).sum())
            if d < best_d:
                best, best_d = child, d
        node = best
        path.append(node)
    return path
