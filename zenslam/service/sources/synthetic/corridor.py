"""The synthetic corridor: a closed ring of corridor around a rectangular block, and the lap along its centre line.

World frame: z up, floor at z = 0, ceiling at z = ``height_m``. The corridor's centre line is a
rectangle centred on the origin whose corners are rounded by smooth 90 degree turns; a lap starts in
the middle of the bottom (-y) straight heading +x and runs counter-clockwise, the block on its left.
Each turn's curvature rises from zero and falls back smoothly (heading
psi(u) = pi/2 (u/L - sin(2 pi u/L) / (2 pi)) over the turn's length L), so the path has continuous
acceleration and jerk: exact IMU samples and no jolt in the images.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from zenslam.service.sources.synthetic.quad import Quad

_E_Z = np.array([0.0, 0.0, 1.0])
# Gauss-Legendre nodes and weights on [0, 1] for the position along a turn (the integrand is smooth
# and the turn short, so 32 nodes reach float64 precision).
_GL_X, _GL_W = np.polynomial.legendre.leggauss(32)  # on [-1, 1]
_GL_NODES, _GL_WEIGHTS = (_GL_X + 1.0) / 2.0, _GL_W / 2.0
# Exact rotations by k quarter turns (cos and sin of k pi/2 rounded would spoil the lap's closure).
_QUARTER_TURNS = np.array([[[1, 0], [0, 1]], [[0, -1], [1, 0]], [[-1, 0], [0, -1]], [[0, 1], [-1, 0]]], float)


@dataclass(frozen=True)
class CorridorLayout:
    """Dimensions of the corridor ring (metres); the defaults give a 68 m lap in a 3 m wide, 3 m high corridor."""

    straight_x_m: float = 15.0  # length of each straight along x (bottom and top), between its turns
    straight_y_m: float = 9.0  # length of each straight along y (right and left), between its turns
    turn_m: float = 5.0  # path length of each 90 degree turn
    width_m: float = 3.0  # wall to wall; the centre line runs in the middle
    height_m: float = 3.0  # floor to ceiling

    @functools.cached_property
    def turn_offset_m(self) -> float:
        """How far a turn takes the path along each of its two straights' directions, metres."""
        return float(_turn_displacement(np.array([self.turn_m]), self.turn_m)[0, 0])

    @property
    def half_size_m(self) -> tuple[float, float]:
        """Half the size of the rectangle of the straights' centre lines (x, y), metres."""
        return (self.straight_x_m / 2 + self.turn_offset_m, self.straight_y_m / 2 + self.turn_offset_m)

    @property
    def lap_m(self) -> float:
        """Path length of one lap, metres."""
        return 2.0 * (self.straight_x_m + self.straight_y_m) + 4.0 * self.turn_m


def _turn_heading(u_m: np.ndarray, turn_m: float, order: int) -> np.ndarray:
    """The ``order``-th derivative along the path (order 0: heading, 1: curvature, 2: its derivative)
    of a left turn at path length ``u_m`` into it, radians per metre^order."""
    phase = 2.0 * math.pi * u_m / turn_m
    if order == 0:
        return (math.pi / 2) * (u_m / turn_m - np.sin(phase) / (2.0 * math.pi))
    if order == 1:
        return (math.pi / 2) / turn_m * (1.0 - np.cos(phase))
    return math.pi**2 / turn_m**2 * np.sin(phase)


def _turn_displacement(u_m: np.ndarray, turn_m: float) -> np.ndarray:
    """Position (N, 2) at path length ``u_m`` into a turn that starts at the origin heading +x (metres)."""
    w = u_m[:, None] * _GL_NODES  # (N, K) quadrature points along [0, u]
    psi = _turn_heading(w, turn_m, 0)
    weights = u_m[:, None] * _GL_WEIGHTS
    return np.stack([(weights * np.cos(psi)).sum(axis=1), (weights * np.sin(psi)).sum(axis=1)], axis=-1)


@dataclass(frozen=True)
class CorridorPath:
    """The lap along the corridor's centre line as a function of path length from the lap's start."""

    layout: CorridorLayout

    def derivatives(self, arc_m: np.ndarray, order: int) -> np.ndarray:
        """The ``order``-th derivative (0..3) of the horizontal position (N, 2) with respect to path length.

        Order 0 is the position in metres, 1 the unit tangent, 2 curvature times the left normal,
        3 its derivative; laps repeat, so any path length is taken modulo ``lap_m``.
        """
        lay = self.layout
        arc = np.mod(np.asarray(arc_m, float) + lay.straight_x_m / 2, lay.lap_m)  # from the first straight's start
        straights = np.array([lay.straight_x_m, lay.straight_y_m, lay.straight_x_m, lay.straight_y_m])
        quarter_starts = np.concatenate([[0.0], np.cumsum(straights + lay.turn_m)[:3]])
        quarter = np.clip(np.searchsorted(quarter_starts, arc, side="right") - 1, 0, 3)
        u = arc - quarter_starts[quarter]  # path length into the quarter: its straight, then its turn
        in_turn = u > straights[quarter]
        u_turn = np.where(in_turn, u - straights[quarter], 0.0)
        local = np.zeros((len(arc), 2))  # in the quarter's frame (its straight runs along +x)
        if order == 0:
            local[:, 0] = np.where(in_turn, straights[quarter], u)
            local += np.where(in_turn[:, None], _turn_displacement(u_turn, lay.turn_m), 0.0)
        else:
            psi = np.where(in_turn, _turn_heading(u_turn, lay.turn_m, 0), 0.0)
            tangent = np.stack([np.cos(psi), np.sin(psi)], axis=-1)
            normal = np.stack([-np.sin(psi), np.cos(psi)], axis=-1)
            kappa = np.where(in_turn, _turn_heading(u_turn, lay.turn_m, 1), 0.0)[:, None]
            if order == 1:
                local = tangent
            elif order == 2:
                local = kappa * normal
            else:
                dkappa = np.where(in_turn, _turn_heading(u_turn, lay.turn_m, 2), 0.0)[:, None]
                local = dkappa * normal - kappa**2 * tangent
        rotated = np.einsum("nij,nj->ni", _QUARTER_TURNS[quarter], local)
        if order > 0:
            return rotated
        hx, hy = lay.half_size_m
        d = lay.turn_offset_m
        starts = np.array([[-hx + d, -hy], [hx, -hy + d], [hx - d, hy], [-hx, hy - d]])
        return starts[quarter] + rotated


def corridor_surfaces(layout: CorridorLayout) -> tuple[Quad, ...]:
    """Outer walls (facing in), the block's walls (facing out), then floor and ceiling strips over the ring.

    Wall rectangles run along the wall (axis_s horizontal) and up (axis_t = +z), so a wall texture's
    columns run along the corridor.
    """
    hx, hy = layout.half_size_m
    half_width, height = layout.width_m / 2, layout.height_m
    outer = (hx + half_width, hy + half_width)
    inner = (hx - half_width, hy - half_width)
    surfaces = [*_walls(outer, height, facing_in=True), *_walls(inner, height, facing_in=False)]
    # The ring as four strips: bottom and top span the full outer width, left and right fill between.
    strips = [
        (-outer[0], -outer[1], outer[0], -inner[1]),
        (-outer[0], inner[1], outer[0], outer[1]),
        (-outer[0], -inner[1], -inner[0], inner[1]),
        (inner[0], -inner[1], outer[0], inner[1]),
    ]
    e_x, e_y = np.eye(3)[0], np.eye(3)[1]
    for x0, y0, x1, y1 in strips:
        surfaces.append(Quad(np.array([x0, y0, 0.0]), e_x, e_y, (x1 - x0, y1 - y0)))  # floor, facing up
    for x0, y0, x1, y1 in strips:
        surfaces.append(Quad(np.array([x0, y0, height]), e_y, e_x, (y1 - y0, x1 - x0)))  # ceiling, facing down
    return tuple(surfaces)


def _walls(half_size: tuple[float, float], height: float, facing_in: bool) -> list[Quad]:
    """The four vertical sides of the rectangle [-hx, hx] x [-hy, hy], seen from inside or outside."""
    hx, hy = half_size
    corners = [np.array(c) for c in ((-hx, -hy, 0.0), (hx, -hy, 0.0), (hx, hy, 0.0), (-hx, hy, 0.0))]
    if facing_in:
        corners.reverse()  # a clockwise walk (seen from above) has normal = axis_s x z pointing inwards
    walls = []
    for a, b in zip(corners, corners[1:] + corners[:1]):
        length = float(np.linalg.norm(b - a))
        walls.append(Quad(a, (b - a) / length, _E_Z, (length, height)))
    return walls
