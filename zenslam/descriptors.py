"""Binary descriptor distances: Hamming distance between 256-bit ORB descriptors (32 uint8 each)."""

from __future__ import annotations

import numpy as np


def _sum_words(counts: np.ndarray) -> np.ndarray:
    """(..., 4) uint8 bit counts of the 64-bit words -> (...) int32 totals.

    Four explicit adds: numpy's sum over a last axis of length 4 costs several times more."""
    total = counts[..., 0].astype(np.int32)
    total += counts[..., 1]
    total += counts[..., 2]
    total += counts[..., 3]
    return total


def hamming_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """All pairwise Hamming distances between descriptors a (N, 32) and b (M, 32) -> (N, M) int32."""
    a = np.ascontiguousarray(a, dtype=np.uint8)
    b = np.ascontiguousarray(b, dtype=np.uint8)
    a64 = a.view(np.uint64)  # (N, 4): 4 x 64 bits per descriptor
    b64 = b.view(np.uint64)
    xor = a64[:, None, :] ^ b64[None, :, :]
    return _sum_words(np.bitwise_count(xor))


def hamming_distance_pairs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise Hamming distances between a (N, 32) and b (N, 32) -> (N,) int32."""
    a64 = np.ascontiguousarray(a, dtype=np.uint8).view(np.uint64)
    b64 = np.ascontiguousarray(b, dtype=np.uint8).view(np.uint64)
    return _sum_words(np.bitwise_count(a64 ^ b64))


def hamming_distance_rows(a: np.ndarray, rows_a: np.ndarray, b: np.ndarray, rows_b: np.ndarray) -> np.ndarray:
    """Hamming distances between descriptors a[rows_a] and b[rows_b] (a (N, 32), b (M, 32), rows (K,)) -> (K,) int32.

    The same as ``hamming_distance_pairs(a[rows_a], b[rows_b])`` without the two uint8 copies:
    rows are taken as four 64-bit words each."""
    a64 = np.ascontiguousarray(a, dtype=np.uint8).view(np.uint64)
    b64 = np.ascontiguousarray(b, dtype=np.uint8).view(np.uint64)
    xor = np.take(a64, rows_a, axis=0)
    xor ^= np.take(b64, rows_b, axis=0)
    return _sum_words(np.bitwise_count(xor))
