"""The frontend map's covisibility graph and spanning tree over keyframe slots (insertion order).

Edge weights are shared map points, given by the map whenever a keyframe's observations change.
The ranking, ordered connections and parent choice are the rules shared with the backend
(``zenslam.covisibility_rules``); ordered connections are re-ranked lazily, once per changed
keyframe when it is next asked for, since a map update relinks many keyframes at once.
"""

from __future__ import annotations

from zenslam.covisibility_rules import ordered_connections, spanning_parent


class SlotGraph:
    """Covisibility weights and the spanning tree of keyframes addressed by slot (0, 1, 2, ...)."""

    def __init__(self, min_weight: int) -> None:
        self.min_weight = min_weight  # shared points for a covisibility edge (ORB-SLAM: 15)
        self._links: list[dict[int, int]] = []
        self._ordered: list[list[int]] = []
        self._unordered: set[int] = set()  # slots whose links changed since they were ranked
        self._parent: list[int] = []
        self._children: list[list[int]] = []

    def add(self, links: dict[int, int]) -> int:
        """Add the next slot with its ``links`` (other slot -> shared points); its spanning-tree
        parent is the slot it shares most points with (-1 when it has none). Returns the new slot."""
        slot = len(self._links)
        self._links.append({})
        self._ordered.append([])
        self._children.append([])
        self.set_links(slot, links)
        parent = spanning_parent(self._links[slot])
        parent = -1 if parent is None else parent
        self._parent.append(parent)
        if parent >= 0:
            self._children[parent].append(slot)
        return slot

    def set_links(self, slot: int, links: dict[int, int]) -> None:
        """Replace the links of ``slot`` (other slot -> shared points, none zero), both directions."""
        for other in set(self._links[slot]) | set(links):
            if other in links:
                self._links[other][slot] = links[other]
            else:
                self._links[other].pop(slot, None)
            self._unordered.add(other)
        self._links[slot] = dict(links)
        self._unordered.add(slot)

    def remove(self, slot: int) -> None:
        """Unlink ``slot``; its spanning-tree children move to its parent."""
        self.set_links(slot, {})
        parent = self._parent[slot]
        for child in self._children[slot]:
            self._parent[child] = parent
            if parent >= 0:
                self._children[parent].append(child)
        if parent >= 0:
            self._children[parent].remove(slot)
        self._children[slot] = []

    def compact(self, new_slot: list[int]) -> None:
        """Keep the slots whose ``new_slot`` entry is >= 0, renumbered to it (kept slots keep their
        relative order, so rankings tie-break as before); links to dropped slots go. A kept slot
        whose parent was dropped moves to its nearest kept ancestor (the spanning tree stays a
        forest of the kept slots), appended after that ancestor's own kept children."""
        kept = [s for s, n in enumerate(new_slot) if n >= 0]
        parents = []
        for slot in kept:
            parent = self._parent[slot]
            while parent >= 0 and new_slot[parent] < 0:  # parents have lower slots: this ends
                parent = self._parent[parent]
            parents.append(new_slot[parent] if parent >= 0 else -1)
        children: list[list[int]] = [[new_slot[c] for c in self._children[s] if new_slot[c] >= 0] for s in kept]
        for slot, parent in zip(kept, parents):
            if parent >= 0 and new_slot[self._parent[slot]] < 0:
                children[parent].append(new_slot[slot])
        self._links = [{new_slot[o]: w for o, w in self._links[s].items() if new_slot[o] >= 0} for s in kept]
        self._ordered = [[] for _ in kept]
        self._unordered = set(range(len(kept)))
        self._parent = parents
        self._children = children

    def weight(self, slot_a: int, slot_b: int) -> int:
        """Points observed by both keyframes."""
        return self._links[slot_a].get(slot_b, 0)

    def ordered(self, slot: int) -> list[int]:
        """ORB-SLAM's ordered connections of ``slot`` (slots, strongest first; ties by slot)."""
        if slot in self._unordered:
            self._unordered.discard(slot)
            self._ordered[slot] = ordered_connections(self._links[slot], self.min_weight)
        return self._ordered[slot]

    def parent(self, slot: int) -> int:
        """Spanning-tree parent, -1 for a root."""
        return self._parent[slot]

    def children(self, slot: int) -> list[int]:
        """Spanning-tree children, in the order they were attached."""
        return self._children[slot]
