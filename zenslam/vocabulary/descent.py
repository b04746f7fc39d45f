"""The vocabulary tree's descent, compiled: each descriptor's leaf and its node at one level.

``Vocabulary.transform`` states the rule (DBoW2's ``transform``): from the root, each descriptor
goes to its nearest child by Hamming distance (the first on a tie) until it reaches a leaf. This
kernel descends one descriptor at a time instead of numpy's level-by-level arrays; the distances
are integers, so the path is the same on any CPU.
"""

from __future__ import annotations

import numpy as np

from zenslam.compiled import kernel
from zenslam.descriptor_words import popcount


@kernel
def descend(words, inner_row, child_nodes, child_words, child_penalty, node_depth, height, node_level):
    """(leaf, node at ``node_level``) of each descriptor ((N, 4) uint64 ``words``).

    Inner node j has its children in row ``inner_row[j]`` (-1 for a leaf) of ``child_nodes``,
    ``child_words`` (their descriptors) and ``child_penalty`` (0, or more than any distance for a
    padding slot). A descriptor whose leaf is shallower than ``node_level`` takes its leaf there;
    ``node_level`` 0 is the root, above the tree's height the leaf.
    """
    n, width = words.shape[0], child_nodes.shape[1]
    leaves = np.empty(n, np.int64)
    at_level = np.empty(n, np.int64)
    for i in range(n):
        current, at = 0, 0
        for level in range(1, height + 1):
            row = inner_row[current]
            if row < 0:
                break
            best, best_distance = 0, np.int64(0)
            for slot in range(width):
                d = np.int64(child_penalty[row, slot])
                for w in range(4):
                    d += popcount(child_words[row, slot, w] ^ words[i, w])
                if slot == 0 or d < best_distance:
                    best, best_distance = slot, d
            current = child_nodes[row, best]
            if level == node_level:
                at = current
        leaves[i] = current
        if node_level > height or (node_level > 0 and node_depth[current] < node_level):
            at = current
        at_level[i] = at
    return leaves, at_level
