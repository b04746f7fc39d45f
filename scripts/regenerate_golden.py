"""Regenerate the golden recording the replay tests compare against: run this when a behaviour change is intended.

    python scripts/regenerate_golden.py

renders the synthetic loop scene driven twice round a short lap (``--laps`` laps in ``--duration``
seconds at ``--rate`` frames per second, at a reduced resolution) into a temporary frames-only
MCAP, runs ``zenslam run mcap:<that file> --lockstep`` on it (rerun off, the recorder's Foxglove
camera images as JPEG, to keep the file small; loop detection allowed from 5 keyframes on, and a
wider robust kernel in the pose graph, so the short second lap closes a loop and a global BA runs)
and copies the run's ``run.mcap`` and ``config.yaml`` to ``recordings/golden/<name>/``. The committed config's
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
    parser.add_argument("--duration", type=float, default=20.0, help="seconds of the scene (default 20)")
    parser.add_argument("--laps", type=int, default=2, help="laps of the loop within --duration (default 2)")
    parser.add_argument("--rate", type=float, default=5.0, help="frames per second (default 5: 101 frames)")
    parser.add_argument("--width", type=int, default=192, help="image width, pixels (default 192; the scene's is 640)")
    parser.add_argument("--height", type=int, default=144, help="image height, pixels (default 144)")
    parser.add_argument("--output", type=Path, default=GOLDEN_ROOT, help="folder of the golden recordings")
    return parser.parse_args(argv)


def render_input(path: Path, args: argparse.Namespace) -> tuple[str, int]:
    """The loop scene's stereo frames at ``args.width`` x ``args.height`` (same field of view), ``args.laps``
    laps in ``args.duration`` seconds at ``args.rate`` Hz, into ``path``; the source's name and frame count."""
    from zenslam.service.sources.mcap_source import write_frames
    from zenslam.service.sources.synthetic import SyntheticSource, scene_config

    default = scene_config("loop")
    scale = args.width / default.width
    scene = scene_config(
        "loop", width=args.width, height=args.height, fx=default.fx * scale, fy=default.fy * scale,
        cx=(args.width - 1) / 2.0, cy=(args.height - 1) / 2.0,
        duration_s=args.duration, laps=args.laps, frame_rate_hz=args.rate,
    )  # fmt: skip
    source = SyntheticSource(scene)
    frames = (source.frame(i) for i in range(len(source)))
    # The ground truth is kept in the recording, so replays of the golden are scored.
    write_frames(path, frames, source.calibration, source.sensor, source.name, ground_truth=source.ground_truth())
    return source.name, len(source)


def golden_config(input_spec: str):
    """The golden run's configuration: lockstep, rerun off, JPEG viewer images, loop closing within a short run."""
    from zenslam.backend.config import BackendConfig
    from zenslam.backend.loop_closing_config import LoopClosingConfig, LoopDetectionConfig
    from zenslam.backend.pose_graph import PoseGraphConfig
    from zenslam.runtime.rerun_config import RerunConfig
    from zenslam.service.run_config import RecorderConfig, RunConfig, SourceConfig

    loop_closing = LoopClosingConfig(
        detection=LoopDetectionConfig(min_keyframes=5, keyframes_after_loop=5),
        # The 5 Hz lap drifts more per keyframe than the default kernel allows a loop to correct.
        pose_graph=PoseGraphConfig(cauchy_k=10.0),
    )
    return RunConfig(
        source=SourceConfig(spec=input_spec),
        backend=BackendConfig(loop_closing=loop_closing),
        rerun=RerunConfig(enabled=False),
        recorder=RecorderConfig(image_format="jpeg", jpeg_quality=30),
    )


def main(argv: list[str] | None = None) -> int:
    from zenslam.service.run_config import load_run_config, run_config_to_yaml

    args = parse_args(argv)
    destination = args.output / args.name
    with tempfile.TemporaryDirectory(prefix="zenslam-golden-") as tmp:
        tmp_dir = Path(tmp)
        source_name, frames = render_input(tmp_dir / "input.mcap", args)
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
    print(f"golden {args.name}: {frames} frames of {source_name!r} at {args.width}x{args.height}, "
          f"{size_mb:.2f} MB, at commit {commit or 'unknown'} -> {destination}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
