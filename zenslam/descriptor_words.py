"""Hamming distances of 256-bit ORB descriptors inside compiled kernels, as four 64-bit words each.

A kernel takes descriptors as (N, 4) uint64 (``words``: a (N, 32) uint8 array viewed so) and sums
the set bits of the XOR of two rows: exact integer arithmetic, the same on every CPU.
"""

from __future__ import annotations

import numpy as np

from zenslam.compiled import kernel


def words(descriptors: np.ndarray) -> np.ndarray:
    """(N, 32) uint8 descriptors as (N, 4) uint64 words (a view when already contiguous uint8)."""
    return np.ascontiguousarray(descriptors, dtype=np.uint8).reshape(-1, 32).view(np.uint64)


@kernel
def popcount(word):
    """Set bits of a uint64 (SWAR: exact integer arithmetic)."""
    word = word - ((word >> np.uint64(1)) & np.uint64(0x5555555555555555))
    word = (word & np.uint64(0x3333333333333333)) + ((word >> np.uint64(2)) & np.uint64(0x3333333333333333))
    word = (word + (word >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return np.int64((word * np.uint64(0x0101010101010101)) >> np.uint64(56))


@kernel
def distance(a_words, i, b_words, j):
    """Hamming distance (int64) between row ``i`` of ``a_words`` and row ``j`` of ``b_words`` ((N, 4) uint64)."""
    d = np.int64(0)
    for w in range(4):
        d += popcount(a_words[i, w] ^ b_words[j, w])
    return d
