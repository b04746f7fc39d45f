"""Binary descriptor distances: Hamming distance between 256-bit ORB descriptors (32 uint8 each)."""

from __future__ import annotations

import numpy as np


def hamming_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """All pairwise Hamming distances between descriptors a (N, 32) and b (M, 32) -> (N, M) int32."""
    a = np.ascontiguousarray(a, dtype=np.uint8)
    b = np.ascontiguousarray(b, dtype=np.uint8)
    a64 = a.view(np.uint64)  # (N, 4): 4 x 64 bits per descriptor
    b64 = b.view(np.uint64)
    xor = a64[:, None, :] ^ b64[None, :, :]
    return np.bitwise_count(xor).sum(axis=2, dtype=np.int32)


def hamming_distance_pairs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise Hamming distances between a (N, 32) and b (N, 32) -> (N,) int32."""
    a64 = np.ascontiguousarray(a, dtype=np.uint8).view(np.uint64)
    b64 = np.ascontiguousarray(b, dtype=np.uint8).view(np.uint64)
    return np.bitwise_count(a64 ^ b64).sum(axis=1, dtype=np.int32)
