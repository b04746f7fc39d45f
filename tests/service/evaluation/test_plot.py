"""Top-view plots: a valid PNG, the plane choice, and no pyplot state left behind."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from zenslam.errors import TrajectoryError
from zenslam.geometry import make_T
from zenslam.service.evaluation.metrics import EvaluationConfig, evaluate
from zenslam.service.evaluation.plot import choose_plane, ground_plane, plot_plane, save_evaluation_plot, save_top_view
from zenslam.trajectory import Trajectory

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def square_loop(n: int = 40) -> np.ndarray:
    """Positions on a 10 m loop in the x-z plane with 0.2 m of height change along y."""
    angle = np.linspace(0.0, 2.0 * np.pi, n)
    return np.column_stack([10 * np.cos(angle), 0.1 * np.sin(3 * angle), 10 * np.sin(angle)])


def test_choose_plane_drops_the_flattest_axis() -> None:
    p = square_loop()
    assert choose_plane(p) == (0, 2)  # KITTI-like: y is down
    assert choose_plane(p[:, [0, 2, 1]]) == (0, 1)  # z-up worlds (EuRoC, TUM)
    assert choose_plane(np.zeros((5, 3))) == (0, 2)  # a tie drops y


def yawed(yaw_rad: float, p_world: np.ndarray) -> np.ndarray:
    """An upright camera of a y-down world (KITTI's) at ``p_world``, heading ``yaw_rad`` about y."""
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    return make_T(np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]), p_world)


def kitti_like_drive(n: int = 51) -> np.ndarray:
    """T_world_cam of a car driving 60 m along z with a gentle turn (1 m in x) and 1.2 m of climb in y
    (KITTI 06's first 51 frames): y varies more than x, but x-z is the ground."""
    t = np.linspace(0.0, 1.0, n)
    p = np.column_stack([1.0 * t**2, -1.2 * t, 60.0 * t])
    return np.stack([yawed(0.03 * ti, pi) for ti, pi in zip(t, p)])


def test_auto_plane_of_a_kitti_like_drive_is_xz() -> None:
    T = kitti_like_drive()
    assert choose_plane(T[:, :3, 3]) == (1, 2)  # extents alone would draw the side view
    assert ground_plane(T) == (0, 2)
    assert plot_plane("auto", T) == "xz"
    assert plot_plane("yz", T) == "yz"  # an explicit plane is kept


def test_ground_plane_of_z_up_worlds_and_unclear_poses() -> None:
    # z-up world (EuRoC, TUM, the synthetic scenes): an upright camera looking along +x has y = -z_world.
    R_world_cam = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    loop = square_loop()[:, [0, 2, 1]]
    T = np.stack([make_T(R_world_cam, p) for p in loop])
    assert ground_plane(T) == (0, 1)
    assert plot_plane("auto", T) == "xy"
    # Image-down between two axes (45 degrees of roll): no ground plane, the extents decide.
    c = np.sqrt(0.5)
    rolled = np.stack([make_T(np.array([[1.0, 0.0, 0.0], [0.0, c, -c], [0.0, c, c]]), p) for p in square_loop()])
    assert ground_plane(rolled) is None
    assert plot_plane("auto", rolled) == "xz"


def test_save_top_view_writes_a_png(tmp_path: Path) -> None:
    p = square_loop()
    path = save_top_view(tmp_path / "sub" / "top.png", p, p + 0.05, title="test")
    data = path.read_bytes()
    assert data.startswith(PNG_SIGNATURE) and len(data) > 1000
    save_top_view(tmp_path / "xy.png", p, p, plane="xy")
    assert (tmp_path / "xy.png").read_bytes().startswith(PNG_SIGNATURE)


def test_no_pyplot_figures_left_open(tmp_path: Path) -> None:
    pyplot = sys.modules.get("matplotlib.pyplot")
    before = pyplot.get_fignums() if pyplot else []
    save_top_view(tmp_path / "top.png", square_loop(), square_loop())
    pyplot = sys.modules.get("matplotlib.pyplot")
    assert (pyplot.get_fignums() if pyplot else []) == before


def test_save_evaluation_plot(tmp_path: Path) -> None:
    p = square_loop()
    gt = Trajectory(
        stamps_ns=np.arange(len(p), dtype=np.int64) * 100_000_000,
        T_world_cam=np.stack([make_T(np.eye(3), x) for x in p]),
    )
    path = save_evaluation_plot(tmp_path / "trajectory_top.png", evaluate(gt, gt, EvaluationConfig()))
    assert path.read_bytes().startswith(PNG_SIGNATURE)


def test_unwritable_plot_path_is_an_error(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with pytest.raises(TrajectoryError, match="cannot write plot"):
        save_top_view(blocker / "top.png", square_loop(), square_loop())
