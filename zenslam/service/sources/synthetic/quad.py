"""A textured surface's rectangle: origin and two in-plane unit axes in the world frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class Quad:
    """A planar rectangle {origin + s * axis_s + t * axis_t : 0 <= s <= size_s, 0 <= t <= size_t} (metres).

    Its visible side faces ``normal = axis_s x axis_t``; axes are unit vectors in the world frame.
    """

    origin_world: np.ndarray  # (3,) metres
    axis_s: np.ndarray  # (3,) unit
    axis_t: np.ndarray  # (3,) unit
    size_m: tuple[float, float]

    @property
    def normal(self) -> np.ndarray:
        """Unit normal of the visible side, world frame."""
        return np.cross(self.axis_s, self.axis_t)

    def corners_world(self) -> np.ndarray:
        """The 4 corners (4, 3) in metres, in order around the rectangle."""
        s, t = self.size_m
        a, b = self.axis_s * s, self.axis_t * t
        o = self.origin_world
        return np.stack([o, o + a, o + a + b, o + b])

    def point(self, s_m: np.ndarray, t_m: np.ndarray) -> np.ndarray:
        """World points (N, 3) at plane coordinates s, t (metres)."""
        return self.origin_world + np.outer(s_m, self.axis_s) + np.outer(t_m, self.axis_t)
