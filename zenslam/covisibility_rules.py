"""ORB-SLAM's covisibility rules, shared by the frontend (keyframes by slot) and the backend (by id).

A keyframe's covisibility weights map each other keyframe it shares map points with to the number
shared. The rules: keyframes rank strongest first, ties to the smaller key (slot or id, both grow
with insertion), so every ranking is deterministic; a keyframe's own connections
(``KeyFrame::UpdateConnections``) are the keyframes sharing at least ``min_weight`` points, or the
single strongest one when none does; a new keyframe's spanning-tree parent is the one it shares
most points with. Each stage keeps its own graph (``frontend/slot_graph.py``,
``backend/covisibility.py``) and applies these.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import TypeVar

K = TypeVar("K", bound=int)


def ranked(weights: Mapping[K, int], keys: Iterable[K] | None = None) -> list[K]:
    """``keys`` (default: every key of ``weights``) strongest first, ties by the smaller key."""
    return sorted(weights if keys is None else keys, key=lambda k: (-weights[k], k))


def strongest(weights: Mapping[K, int], keys: Iterable[K] | None = None) -> K | None:
    """The first of ``ranked(weights, keys)`` without sorting them all; None when there is none."""
    return min(weights if keys is None else keys, key=lambda k: (-weights[k], k), default=None)


def fallback_connection(weights: Mapping[K, int], min_weight: int) -> K | None:
    """The single connection of a keyframe none of whose weights reaches ``min_weight``: its strongest
    pair (ORB-SLAM then links both ends); None when a weight reaches it, or there is no pair."""
    if any(w >= min_weight for w in weights.values()):
        return None
    return strongest(weights)


def ordered_connections(weights: Mapping[K, int], min_weight: int) -> list[K]:
    """A keyframe's own ordered connections: the keys with weight >= ``min_weight``, ranked, or the
    single strongest one when none reaches it (empty without any pair)."""
    order = ranked(weights)
    return [k for k in order if weights[k] >= min_weight] or order[:1]


def spanning_parent(weights: Mapping[K, int], candidates: Iterable[K] | None = None) -> K | None:
    """The spanning-tree parent of a new keyframe: among ``candidates`` (default: every key of
    ``weights``) the one sharing most points with it, ties by the smaller key; None when it shares
    none with any of them (each stage decides what a keyframe without a parent becomes)."""
    shared = [k for k in (weights if candidates is None else candidates) if weights.get(k, 0) > 0]
    return strongest(weights, shared)
