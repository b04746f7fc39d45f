"""The covisibility graph: keyframes linked by the number of map points they both observe.

Weights are kept exact for every pair sharing at least one point. The *edges* are ORB-SLAM's
connections (``KeyFrame::UpdateConnections``): pairs whose weight reaches ``min_weight``, plus,
for a keyframe with no such pair, the single pair with its highest weight (added on both sides,
as ORB-SLAM's ``AddConnection`` does). Neighbour lists are ordered by decreasing weight, ties by
increasing keyframe id, so every query is deterministic: the rules shared with the frontend,
``zenslam.covisibility_rules``.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from zenslam.covisibility_rules import fallback_connection, ranked


class CovisibilityGraph:
    """Exact shared-point counts between keyframes and the ORB-SLAM edges derived from them."""

    def __init__(self, min_weight: int = 15) -> None:
        if min_weight < 1:
            raise ValueError(f"min_weight must be a positive number of shared points, got {min_weight}")
        self.min_weight = int(min_weight)  # shared points for an edge (ORB-SLAM: 15)
        self._weights: dict[int, dict[int, int]] = {}
        self._cache: dict[int, list[int]] = {}  # connected() lists, valid until the next change

    # ---- nodes and weights -------------------------------------------------------------------------
    def add_keyframe(self, kf_id: int) -> None:
        """A node without edges; adding a known keyframe is an error."""
        if kf_id in self._weights:
            raise ValueError(f"keyframe {kf_id} is already in the covisibility graph")
        self._weights[kf_id] = {}
        self._cache.clear()

    def remove_keyframe(self, kf_id: int) -> None:
        """Drop a node and every weight it has (callers normally remove its observations first)."""
        for other in self._weights.pop(kf_id):
            del self._weights[other][kf_id]
        self._cache.clear()

    def __contains__(self, kf_id: object) -> bool:
        return kf_id in self._weights

    def keyframes(self) -> list[int]:
        """All keyframe ids, increasing."""
        return sorted(self._weights)

    def change_weight(self, a: int, b: int, delta: int) -> None:
        """Add ``delta`` shared points to the pair (a, b); a weight reaching 0 removes the pair."""
        if a == b or delta == 0:
            return
        links = self._weights[a]
        new = links.get(b, 0) + delta
        if new < 0:
            raise ValueError(f"covisibility weight of keyframes {a} and {b} would become {new}")
        if new == 0:
            links.pop(b, None)
            self._weights[b].pop(a, None)
        else:
            links[b] = new
            self._weights[b][a] = new
        self._cache.clear()

    def add_observation(self, kf_id: int, other_observers: Iterable[int]) -> None:
        """``kf_id`` now sees a point the ``other_observers`` already see: +1 with each of them."""
        weights = self._weights
        links = weights[kf_id]
        for other in other_observers:  # ``change_weight(kf_id, other, 1)``, inlined: thousands a keyframe
            if other != kf_id:
                new = links.get(other, 0) + 1
                links[other] = new
                weights[other][kf_id] = new
        self._cache.clear()

    def remove_observation(self, kf_id: int, other_observers: Iterable[int]) -> None:
        """``kf_id`` no longer sees a point the ``other_observers`` still see: -1 with each of them."""
        self._decrement(kf_id, other_observers)
        self._cache.clear()

    def _decrement(self, kf_id: int, others: Iterable[int]) -> None:
        """``change_weight(kf_id, other, -1)`` for each of ``others``, inlined (thousands a keyframe);
        the caller clears the cache."""
        weights = self._weights
        links = weights[kf_id]
        for other in others:
            if other == kf_id:
                continue
            new = links.get(other, 0) - 1
            if new < 0:
                raise ValueError(f"covisibility weight of keyframes {kf_id} and {other} would become {new}")
            if new == 0:
                links.pop(other, None)
                weights[other].pop(kf_id, None)
            else:
                links[other] = new
                weights[other][kf_id] = new

    def add_shared(self, kf_id: int, counts: Mapping[int, int]) -> None:
        """``kf_id`` now shares ``counts[other]`` more points with each other keyframe (applied in
        the mapping's order; the same as that many ``add_observation`` calls)."""
        links = self._weights[kf_id]
        for other, delta in counts.items():
            if other == kf_id or delta == 0:
                continue
            new = links.get(other, 0) + delta
            if new <= 0:
                raise ValueError(f"covisibility weight of keyframes {kf_id} and {other} would become {new}")
            links[other] = new
            self._weights[other][kf_id] = new
        self._cache.clear()

    def remove_shared(self, observers: list[int]) -> None:
        """The keyframes ``observers`` (distinct) stop sharing one point: -1 for every pair of them."""
        for i, a in enumerate(observers):
            self._decrement(a, observers[i + 1 :])
        self._cache.clear()

    def weight(self, a: int, b: int) -> int:
        """Map points observed by both keyframes."""
        return self._weights.get(a, {}).get(b, 0)

    def weights(self, kf_id: int) -> dict[int, int]:
        """Every keyframe sharing points with ``kf_id`` -> number shared (a copy)."""
        return dict(self._weights[kf_id])

    def restore_weights(self, rows: Mapping[int, dict[int, int]]) -> None:
        """Put back each keyframe's weights as ``weights`` returned them; every pair changed since
        they were taken must have both ends among ``rows`` (``BackendMap.checkpoint`` sees to it)."""
        for kf_id, links in rows.items():
            self._weights[kf_id] = dict(links)
        self._cache.clear()

    # ---- edges ---------------------------------------------------------------------------------------
    def connected(self, kf_id: int) -> list[int]:
        """ORB-SLAM's ordered connected keyframes: every edge of ``kf_id``, best first."""
        cached = self._cache.get(kf_id)
        if cached is not None:
            return list(cached)
        links = self._weights[kf_id]
        linked = {k for k, w in links.items() if w >= self.min_weight}
        if not linked and links:
            linked.add(fallback_connection(links, self.min_weight))  # type: ignore[arg-type]
        for other in links:
            if other not in linked and fallback_connection(self._weights[other], self.min_weight) == kf_id:
                linked.add(other)  # the other keyframe's single fallback edge lands here
        ordered = ranked(links, linked)
        self._cache[kf_id] = ordered
        return list(ordered)

    def best_covisible(self, kf_id: int, n: int) -> list[int]:
        """Up to ``n`` connected keyframes, strongest first (ORB-SLAM's GetBestCovisibilityKeyFrames)."""
        return self.connected(kf_id)[: max(int(n), 0)]

    def covisible_by_weight(self, kf_id: int, min_weight: int) -> list[int]:
        """Keyframes sharing at least ``min_weight`` points with ``kf_id``, strongest first."""
        links = self._weights[kf_id]
        return ranked(links, (k for k, w in links.items() if w >= min_weight))

    def edges(self) -> list[tuple[int, int, int]]:
        """Every edge once as (a, b, weight) with a < b, sorted by (a, b)."""
        out = []
        for a in self.keyframes():
            out.extend((a, b, self._weights[a][b]) for b in self.connected(a) if a < b)
        return sorted(out)
