"""Top-view PNG of an aligned estimate against ground truth, drawn without pyplot's global state."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Literal

import numpy as np

from zenslam.errors import TrajectoryError
from zenslam.service.evaluation.metrics import Evaluation

logger = logging.getLogger(__name__)

Plane = Literal["auto", "xy", "xz", "yz"]
PLANES: tuple[Plane, ...] = ("auto", "xy", "xz", "yz")

_AXIS_NAMES = "xyz"
_UPRIGHT_COS = np.cos(np.radians(30.0))  # image-down within 30 degrees of a world axis: that axis is vertical


def ground_plane(T_world_cam: np.ndarray) -> tuple[int, int] | None:
    """The world plane (two axis indices, ascending) perpendicular to the vertical of camera poses (N, 4, 4),
    or None when the poses do not show one.

    Cameras on cars, robots, hand-held rigs and drones' forward cameras are held upright, so their
    image-down direction (camera y) is the world's down: the world axis it follows is vertical,
    whichever convention the world frame has (KITTI's y down, z up elsewhere). Cameras whose
    down directions disagree, or point between axes (a nadir camera's y is horizontal), show none.
    """
    down = np.asarray(T_world_cam, dtype=float).reshape(-1, 4, 4)[:, :3, 1].mean(axis=0)
    norm = float(np.linalg.norm(down))
    if norm < 0.5:  # the cameras disagree on which way is down
        return None
    vertical = int(np.argmax(np.abs(down)))
    if abs(down[vertical]) / norm < _UPRIGHT_COS:
        return None
    return tuple(a for a in range(3) if a != vertical)  # type: ignore[return-value]


def choose_plane(p_world: np.ndarray) -> tuple[int, int]:
    """The two world axes (indices, ascending) spanning the widest view of positions (N, 3).

    The axis of smallest extent is dropped; ties drop y, the down axis of camera-frame worlds such
    as KITTI's, giving their x-z top view.
    """
    extent = np.ptp(np.asarray(p_world, dtype=float).reshape(-1, 3), axis=0)
    dropped = min((1, 2, 0), key=lambda axis: extent[axis])
    return tuple(a for a in range(3) if a != dropped)  # type: ignore[return-value]


def plot_plane(plane: Plane, T_world_cam: np.ndarray) -> Plane:
    """The plane to draw poses (N, 4, 4) in: ``plane`` itself unless ``auto``, which takes the ground plane
    the poses show (``ground_plane``), else the two axes of largest extent (``choose_plane``)."""
    if plane != "auto":
        return plane
    axes = ground_plane(T_world_cam) or choose_plane(np.asarray(T_world_cam, dtype=float).reshape(-1, 4, 4)[:, :3, 3])
    return "".join(_AXIS_NAMES[a] for a in axes)  # type: ignore[return-value]


def save_top_view(
    path: str | Path,
    p_world_gt: np.ndarray,
    p_world_est: np.ndarray,
    *,
    plane: Plane = "auto",
    title: str = "",
) -> Path:
    """Draw ground-truth and estimated positions (N, 3 and M, 3, metres, same world frame) to a PNG.

    ``plane`` names the two world axes drawn; ``auto`` uses ``choose_plane(p_world_gt)`` (positions alone
    show no ground plane: ``save_evaluation_plot`` finds it from the poses).
    """
    path = Path(path)
    p_gt = np.asarray(p_world_gt, dtype=float).reshape(-1, 3)
    p_est = np.asarray(p_world_est, dtype=float).reshape(-1, 3)
    a, b = choose_plane(p_gt) if plane == "auto" else (_AXIS_NAMES.index(plane[0]), _AXIS_NAMES.index(plane[1]))
    # matplotlib is imported here, when a plot is drawn: see metrics.py on evo.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.4, 6.4), dpi=100)
    FigureCanvasAgg(fig)  # this figure renders with Agg, whatever pyplot's backend is
    ax = fig.add_subplot()
    ax.plot(p_gt[:, a], p_gt[:, b], color="0.2", linewidth=1.5, label="ground truth")
    ax.plot(p_est[:, a], p_est[:, b], color="tab:orange", linewidth=1.2, label="estimate (aligned)")
    ax.plot(p_gt[:1, a], p_gt[:1, b], "o", color="0.2", markersize=5, label="start")
    ax.set_xlabel(f"{_AXIS_NAMES[a]} [m]")
    ax.set_ylabel(f"{_AXIS_NAMES[b]} [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, linewidth=0.5, alpha=0.5)
    ax.legend(loc="best")
    if title:
        ax.set_title(title, fontsize=10)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, format="png")
    except OSError as exc:
        raise TrajectoryError(f"cannot write plot {path}: {exc}; check the output folder") from exc
    logger.debug("wrote %s", path)
    return path


def save_evaluation_plot(path: str | Path, evaluation: Evaluation, *, plane: Plane = "auto") -> Path:
    """Top view of an evaluation's matched ground truth and aligned estimate, titled with the ATE; ``auto``
    draws the ground-truth poses' ground plane (``plot_plane``)."""
    ate = evaluation.ate
    title = f"ATE rmse {ate.rmse_m:.4f} m ({ate.alignment} alignment, {ate.matched_poses} poses)"
    return save_top_view(
        path, evaluation.p_world_gt, evaluation.p_world_est_aligned,
        plane=plot_plane(plane, evaluation.T_world_cam_gt), title=title,
    )
