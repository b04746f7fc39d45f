"""Nearest of k candidate descriptors by Hamming distance, for many descriptors at once."""

from __future__ import annotations

import numpy as np

ABSENT = 1024  # distance added for an absent candidate: more than any Hamming distance between 256-bit strings


def first_nearest(words: np.ndarray, slots: np.ndarray, slot_penalty: np.ndarray) -> np.ndarray:
    """Index of the nearest of k candidates (the first on a tie) for each of n descriptors.

    ``words`` (4, n) uint64: the descriptors word-major (row w holds bits 64w..64w+63 of every
    descriptor); ``slots`` (k, 4) uint64 candidates shared by all, or (k, 4, n) one set per
    descriptor; ``slot_penalty`` (k,) or (k, n) int: 0 for a candidate, ABSENT for an empty slot.
    One candidate and one word at a time over contiguous rows keeps the temporaries in cache.
    """
    n = words.shape[1]
    best = np.full(n, np.iinfo(np.int32).max, dtype=np.int32)
    index = np.zeros(n, dtype=np.int64)
    for j in range(slots.shape[0]):
        c0, c1, c2, c3 = (np.bitwise_count(words[w] ^ slots[j, w]) for w in range(4))
        # Two words add up to at most 128, safe in uint8; the total (up to 256) is not.
        distance = (c0 + c1).astype(np.int32) + (c2 + c3) + slot_penalty[j]
        better = distance < best
        np.copyto(best, distance, where=better)
        index[better] = j
    return index
