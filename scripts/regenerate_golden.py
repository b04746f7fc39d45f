"""Regenerate the golden recording the replay tests compare against: run this when a behaviour change is intended.

    python scripts/regenerate_golden.py

renders the first ``--frames`` frames of the synthetic loop at a reduced resolution into a
temporary frames-only MCAP, runs ``zenslam run mcap:<that file> --lockstep`` on it (rerun off, the
recorder's Foxglove camera images as JPEG, to keep the file small) and copies the run's
``run.mcap`` and ``config.yaml`` to ``recordings/golden/<name>/``. The committed config's
``source.spec`` names the golden recording itself: its sensor/frame channel is the input.
Commit both files together with the change that made them differ, and say why in the message.
The run uses the code it is run with: run it on a clean checkout of the commit (uncommitted
changes in the working tree would end up in the golden).
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
GOLDEN_ROOT = REPO_ROOT / "recordings" / "golden"


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--name", default="synthetic_loop", help="folder under recordings/golden (default synthetic_loop)")
    parser.add_argument("--frames", type=int, default=20, help="frames of the loop to record (default 20)")
    parser.add_argument("--width", type=int, default=256, help="image width, pixels (default 256; the scene's is 640)")
    parser.add_argument("--height", type=int, default=192, help="image height, pixels (default 192)")
    parser.add_argument("--output", type=Path, default=GOLDEN_ROOT, help="folder of the golden recordings")
    return parser.parse_args(argv)


def render_input(path: Path, frames: int, width: int, height: int) -> str:
    """The loop scene's first ``frames`` stereo frames at ``width`` x ``height`` (same field of view) into ``path``."""
    from zenslam.service.sources.mcap_source import write_frames
    from zenslam.service.sources.synthetic import SyntheticSource, scene_config
    from zenslam.trajectory import Trajectory

    default = scene_config("loop")
    scale = width / default.width
    scene = scene_config(
        "loop", width=width, height=height, fx=default.fx * scale, fy=default.fy * scale,
        cx=(width - 1) / 2.0, cy=(height - 1) / 2.0,
    )  # fmt: skip
    source = SyntheticSource(scene)
    n = min(frames, len(source))
    selected = (source.frame(i) for i in range(n))
    truth = source.ground_truth()  # kept in the recording, so replays of the golden are scored
    last_stamp_ns = int(source.stamps_ns()[n - 1])
    kept = truth.stamps_ns <= last_stamp_ns
    ground_truth = Trajectory(truth.stamps_ns[kept], truth.T_world_cam[kept])
    write_frames(path, selected, source.calibration, source.sensor, source.name, ground_truth=ground_truth)
    return source.name


def golden_config(input_spec: str):
    """The golden run's configuration: lockstep, rerun off, JPEG viewer images."""
    from zenslam.runtime.rerun_config import RerunConfig
    from zenslam.service.run_config import RecorderConfig, RunConfig, SourceConfig

    return RunConfig(
        source=SourceConfig(spec=input_spec),
        rerun=RerunConfig(enabled=False),
        recorder=RecorderConfig(image_format="jpeg", jpeg_quality=30),
    )


def main(argv: list[str] | None = None) -> int:
    from zenslam.service.run_config import load_run_config, run_config_to_yaml

    args = parse_args(argv)
    destination = args.output / args.name
    with tempfile.TemporaryDirectory(prefix="zenslam-golden-") as tmp:
        tmp_dir = Path(tmp)
        source_name = render_input(tmp_dir / "input.mcap", args.frames, args.width, args.height)
        config_path = tmp_dir / "golden.yaml"
        config_path.write_text(run_config_to_yaml(golden_config(f"mcap:{tmp_dir / 'input.mcap'}")))
        command = [sys.executable, "-m", "zenslam.service.cli", "run", "--config", str(config_path),
                   "--output", str(tmp_dir), "--run-id", f"golden-{args.name}", "--no-progress"]  # fmt: skip
        result = subprocess.run(command, cwd=REPO_ROOT, capture_output=True, text=True)
        print(result.stdout, end="")
        if result.returncode != 0:
            print(result.stderr[-4000:], file=sys.stderr)
            return result.returncode
        run_dir = tmp_dir / f"golden-{args.name}"
        destination.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(run_dir / "run.mcap", destination / "run.mcap")
        recorded = load_run_config(run_dir / "config.yaml")
        golden = (destination / "run.mcap").resolve()
        spec = f"mcap:{golden.relative_to(REPO_ROOT) if golden.is_relative_to(REPO_ROOT) else golden}"
        config = dataclasses.replace(recorded, source=dataclasses.replace(recorded.source, spec=spec))
        (destination / "config.yaml").write_text(run_config_to_yaml(config))
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO_ROOT, capture_output=True, text=True).stdout.strip()
    size_mb = (destination / "run.mcap").stat().st_size / 1e6
    print(f"golden {args.name}: {args.frames} frames of {source_name!r} at {args.width}x{args.height}, "
          f"{size_mb:.2f} MB, at commit {commit or 'unknown'} -> {destination}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
