"""``zenslam inspect`` summarises real clips and names the problem with a bad path."""

from zenslam.service.cli import main


def test_inspect_kitti_clip(kitti_root, capsys):
    assert main(["inspect", f"kitti:{kitti_root}/sequences/06"]) == 0
    out = capsys.readouterr().out
    assert "frames:      51" in out
    assert "baseline=0.5372 m" in out
    assert "1226x370" in out
    assert "ground truth: 51 poses" in out


def test_inspect_euroc_clip(euroc_micro, capsys):
    assert main(["inspect", f"euroc:{euroc_micro}"]) == 0
    out = capsys.readouterr().out
    assert "frames:      95" in out
    assert "20.00 Hz" in out
    assert "imu:         29120 samples" in out


def test_inspect_missing_folder_fails_with_the_path(tmp_path, caplog):
    missing = tmp_path / "nowhere"
    assert main(["inspect", f"euroc:{missing}"]) == 2
    assert str(missing) in caplog.text
