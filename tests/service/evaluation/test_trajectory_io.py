"""Reading and writing TUM, KITTI and EuRoC trajectory files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from zenslam.errors import TimestampError, TrajectoryError
from zenslam.geometry import make_T, so3_exp
from zenslam.service.evaluation.trajectory_io import (
    detect_format,
    read_euroc,
    read_kitti,
    read_trajectory,
    read_tum,
    write_euroc,
    write_kitti,
    write_trajectory,
    write_tum,
)
from zenslam.trajectory import Trajectory

POSE_TOL = 1e-8  # the writers keep 9 decimals (TUM, EuRoC) or 13 significant digits (KITTI)
EUROC_FIRST_STAMP_NS = 1403715274312143104  # first line of groundtruth_cam0.csv


def random_trajectory(rng: np.random.Generator, n: int = 20, start_ns: int = 1_403_715_274_312_143_104) -> Trajectory:
    """Poses with arbitrary rotations and ns stamps that float64 seconds could not hold."""
    steps = rng.integers(40_000_001, 60_000_001, size=n)
    stamps = start_ns + np.cumsum(steps)
    poses = np.stack([make_T(so3_exp(rng.normal(0.0, 1.0, 3)), rng.normal(0.0, 20.0, 3)) for _ in range(n)])
    return Trajectory(stamps_ns=stamps.astype(np.int64), T_world_cam=poses)


@pytest.mark.parametrize("fmt", ["tum", "euroc"])
def test_stamped_formats_round_trip_exact_ns(tmp_path: Path, fmt: str) -> None:
    original = random_trajectory(np.random.default_rng(1))
    path = write_trajectory(tmp_path / f"traj.{fmt}", original, fmt)
    back = read_trajectory(path, fmt)
    np.testing.assert_array_equal(back.stamps_ns, original.stamps_ns)
    assert back.stamps_ns.dtype == np.int64
    np.testing.assert_allclose(back.T_world_cam, original.T_world_cam, atol=POSE_TOL)


def test_kitti_round_trip_stamps_by_index(tmp_path: Path) -> None:
    original = random_trajectory(np.random.default_rng(2))
    back = read_kitti(write_kitti(tmp_path / "poses.txt", original))
    np.testing.assert_array_equal(back.stamps_ns, np.arange(len(original)))
    np.testing.assert_allclose(back.T_world_cam, original.T_world_cam, atol=POSE_TOL)


def test_kitti_stamps_from_times_file(tmp_path: Path) -> None:
    original = random_trajectory(np.random.default_rng(3), n=3)
    write_kitti(tmp_path / "poses.txt", original)
    (tmp_path / "times.txt").write_text("0.000000e+00\n1.044989e-01\n2.077935e-01\n")
    back = read_trajectory(tmp_path / "poses.txt", times_path=tmp_path / "times.txt")
    np.testing.assert_array_equal(back.stamps_ns, [0, 104_498_900, 207_793_500])


def test_kitti_times_count_must_match(tmp_path: Path) -> None:
    write_kitti(tmp_path / "poses.txt", random_trajectory(np.random.default_rng(4), n=3))
    (tmp_path / "times.txt").write_text("0.0\n0.1\n")
    with pytest.raises(TrajectoryError, match="times.txt has 2 stamps"):
        read_kitti(tmp_path / "poses.txt", times_path=tmp_path / "times.txt")


def test_tum_writes_nine_decimals_of_seconds(tmp_path: Path) -> None:
    stamps = np.array([1_403_715_274_312_143_104, 1_403_715_274_362_142_976])
    traj = Trajectory(stamps_ns=stamps, T_world_cam=np.stack([np.eye(4)] * 2))
    lines = write_tum(tmp_path / "t.txt", traj).read_text().splitlines()
    assert lines[0].startswith("#")
    assert lines[1].split()[0] == "1403715274.312143104"
    assert lines[1].split()[1:] == ["0.000000000"] * 3 + ["0.000000000"] * 3 + ["1.000000000"]


def test_tum_reads_quaternion_xyzw_and_comments(tmp_path: Path) -> None:
    # 90 degrees about z: (qx, qy, qz, qw) = (0, 0, sin 45, cos 45).
    s = np.sqrt(0.5)
    path = tmp_path / "t.txt"
    path.write_text(f"# stamp tx ty tz qx qy qz qw\n\n1.5 1 2 3 0 0 {s} {s}\n2.0 0 0 0 0 0 0 1\n")
    traj = read_tum(path)
    np.testing.assert_array_equal(traj.stamps_ns, [1_500_000_000, 2_000_000_000])
    np.testing.assert_allclose(traj.T_world_cam[0][:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)
    np.testing.assert_allclose(traj.positions[0], [1, 2, 3])


def test_euroc_state_groundtruth_extra_columns_ignored(tmp_path: Path) -> None:
    path = tmp_path / "data.csv"
    header = "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []"
    extra = ",".join(["0.1"] * 9)  # velocity and biases
    path.write_text(f"{header}, v...\n1403715271696231936,1,2,3,1,0,0,0,{extra}\n1403715271701231872,1,2,3,0,1,0,0,{extra}\n")
    traj = read_euroc(path)
    np.testing.assert_array_equal(traj.stamps_ns, [1403715271696231936, 1403715271701231872])
    np.testing.assert_allclose(traj.T_world_cam[1][:3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-12)


def test_detect_format_by_extension_content_and_override(tmp_path: Path) -> None:
    traj = random_trajectory(np.random.default_rng(5), n=3)
    tum = write_tum(tmp_path / "a.txt", traj)
    kitti = write_kitti(tmp_path / "b.txt", traj)
    euroc = write_euroc(tmp_path / "c.data", traj)
    assert detect_format(tum) == "tum"
    assert detect_format(kitti) == "kitti"
    assert detect_format(euroc) == "euroc"  # commas
    assert detect_format(tmp_path / "absent.csv") == "euroc"  # extension, no read
    assert detect_format(tum, "kitti") == "kitti"
    with pytest.raises(TrajectoryError, match="unknown trajectory format 'g2o'"):
        detect_format(tum, "g2o")
    odd = tmp_path / "odd.txt"
    odd.write_text("1 2 3 4 5\n")
    with pytest.raises(TrajectoryError, match=r"odd.txt:1: .*5 values"):
        detect_format(odd)


def test_missing_file_names_the_path(tmp_path: Path) -> None:
    with pytest.raises(TrajectoryError, match="nowhere.txt does not exist"):
        read_tum(tmp_path / "nowhere.txt")


def test_malformed_line_names_file_and_line(tmp_path: Path) -> None:
    path = tmp_path / "bad.txt"
    path.write_text("# header\n1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 1\n")
    with pytest.raises(TrajectoryError, match=r"bad.txt:3: expected .* got 7"):
        read_tum(path)
    path.write_text("1.0 0 0 0 0 0 0 1\n2.0 0 zero 0 0 0 0 1\n")
    with pytest.raises(TrajectoryError, match=r"bad.txt:2: not a number"):
        read_tum(path)
    path.write_text("1.0 0 0 0 0 0 0 0\n")
    with pytest.raises(TrajectoryError, match=r"bad.txt:1: quaternion .* norm 0.000"):
        read_tum(path)
    path.write_text("abc,0,0,0,1,0,0,0\n")
    with pytest.raises(TimestampError, match=r"bad.txt:1: cannot parse the stamp 'abc'"):
        read_euroc(path)


def test_non_increasing_stamps_name_file_and_line(tmp_path: Path) -> None:
    path = tmp_path / "dup.csv"
    path.write_text("#t,x,y,z,qw,qx,qy,qz\n10,0,0,0,1,0,0,0\n20,0,0,0,1,0,0,0\n20,0,0,0,1,0,0,0\n")
    with pytest.raises(TimestampError, match=r"dup.csv:4: stamp 20 ns does not increase on line 3"):
        read_euroc(path)


def test_empty_file_is_an_error(tmp_path: Path) -> None:
    path = tmp_path / "empty.txt"
    path.write_text("# only a comment\n")
    with pytest.raises(TrajectoryError, match="empty.txt holds no poses"):
        read_trajectory(path, "tum")


def test_real_euroc_groundtruth_parses_exact_ns(euroc_micro: Path) -> None:
    traj = read_trajectory(euroc_micro / "groundtruth_cam0.csv")
    assert len(traj) == 74
    assert int(traj.stamps_ns[0]) == EUROC_FIRST_STAMP_NS  # float64 would give ...143104 +- 128
    np.testing.assert_allclose(traj.positions[0], [0.8687393558, 2.2070275302, 0.9257726725])
    R = traj.T_world_cam[:, :3, :3]
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-9)


def test_real_kitti_poses_and_times(kitti_root: Path) -> None:
    traj = read_trajectory(kitti_root / "poses" / "06.txt", times_path=kitti_root / "sequences" / "06" / "times.txt")
    assert len(traj) == 51
    assert traj.stamps_ns[0] == 0 and traj.stamps_ns[1] == 104_498_900
    np.testing.assert_allclose(traj.positions[1], [-1.401751e-02, -2.820321e-02, 1.198998e00])
