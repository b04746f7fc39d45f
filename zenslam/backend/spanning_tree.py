"""The spanning tree of the keyframes: each keyframe's parent is the one it shared most points with.

A keyframe gets its parent once, when it is inserted (ORB-SLAM's first ``UpdateConnections``);
removing a keyframe re-attaches its children as ORB-SLAM's ``KeyFrame::SetBadFlag`` does, so the
tree stays connected and the essential graph built on it keeps every keyframe.
"""

from __future__ import annotations

from zenslam.backend.covisibility import CovisibilityGraph
from zenslam.covisibility_rules import spanning_parent


def choose_parent(kf_id: int, covisibility: CovisibilityGraph, older_ids: list[int]) -> int | None:
    """The keyframe among ``older_ids`` sharing most points with ``kf_id`` (ties: smallest id), the
    rule shared with the frontend (``covisibility_rules.spanning_parent``).

    With no shared point at all the most recent older keyframe is taken, so the backend's tree
    never splits (its essential graph must hold every keyframe); ``None`` when there is no older
    keyframe (the root).
    """
    if not older_ids:
        return None
    parent = spanning_parent(covisibility.weights(kf_id), older_ids)
    return older_ids[-1] if parent is None else parent


class SpanningTree:
    """Parent and children of every keyframe; the first keyframe is the root."""

    def __init__(self) -> None:
        self._parent: dict[int, int | None] = {}
        self._children: dict[int, set[int]] = {}

    def __contains__(self, kf_id: object) -> bool:
        return kf_id in self._parent

    def add(self, kf_id: int, parent: int | None) -> None:
        """Attach a new keyframe below ``parent`` (``None`` only for the root)."""
        if kf_id in self._parent:
            raise ValueError(f"keyframe {kf_id} is already in the spanning tree")
        if parent is None and any(p is None for p in self._parent.values()):
            raise ValueError(f"keyframe {kf_id} needs a parent: the tree already has a root")
        if parent is not None and parent not in self._parent:
            raise ValueError(f"parent {parent} of keyframe {kf_id} is not in the spanning tree")
        self._parent[kf_id] = parent
        self._children[kf_id] = set()
        if parent is not None:
            self._children[parent].add(kf_id)

    def parent(self, kf_id: int) -> int | None:
        """Parent keyframe id, ``None`` for the root."""
        return self._parent[kf_id]

    def children(self, kf_id: int) -> list[int]:
        """Children keyframe ids, increasing."""
        return sorted(self._children[kf_id])

    def keyframes(self) -> list[int]:
        """Every keyframe id in the tree, increasing."""
        return sorted(self._parent)

    def edges(self) -> list[tuple[int, int]]:
        """(child, parent) for every non-root keyframe, sorted by child id."""
        return sorted((c, p) for c, p in self._parent.items() if p is not None)

    def set_parent(self, kf_id: int, parent: int) -> None:
        """Move ``kf_id`` below ``parent`` (ORB-SLAM's ChangeParent); refuses to make a cycle."""
        node: int | None = parent
        while node is not None:
            if node == kf_id:
                raise ValueError(f"making {parent} the parent of {kf_id} would close a cycle in the spanning tree")
            node = self._parent[node]
        old = self._parent[kf_id]
        if old is not None:
            self._children[old].discard(kf_id)
        self._parent[kf_id] = parent
        self._children[parent].add(kf_id)

    def remove(self, kf_id: int, covisibility: CovisibilityGraph) -> dict[int, int]:
        """Remove a non-root keyframe and re-attach its children; returns child -> new parent.

        ORB-SLAM's ``SetBadFlag``: the candidates start as the removed keyframe's parent; each round
        the (child, candidate) pair with the highest covisibility weight among the child's
        connected keyframes is re-attached and that child becomes a candidate too. Children with no
        connection to any candidate go to the removed keyframe's parent. Call after the keyframe's
        observations have left ``covisibility``. Ties: smaller child id, then smaller candidate id.
        """
        parent = self._parent.get(kf_id, -1)
        if parent == -1:
            raise ValueError(f"keyframe {kf_id} is not in the spanning tree")
        if parent is None:
            raise ValueError(f"keyframe {kf_id} is the root of the spanning tree and cannot be removed")
        candidates = {parent}
        orphans = set(self._children[kf_id])
        moves: dict[int, int] = {}
        while orphans:
            best: tuple[tuple[int, int, int], int, int] | None = None
            for child in sorted(orphans):
                for cand in covisibility.connected(child) if child in covisibility else []:
                    if cand in candidates:
                        key = (covisibility.weight(child, cand), -child, -cand)
                        if best is None or key > best[0]:
                            best = (key, child, cand)
            if best is None:
                break
            _, child, cand = best
            moves[child] = cand
            candidates.add(child)
            orphans.discard(child)
        for child in sorted(orphans):
            moves[child] = parent
        for child, new_parent in moves.items():
            self._children[kf_id].discard(child)
            self._parent[child] = new_parent
            self._children[new_parent].add(child)
        self._children[parent].discard(kf_id)
        del self._parent[kf_id]
        del self._children[kf_id]
        return moves
