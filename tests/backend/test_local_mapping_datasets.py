"""Local mapping behind the frontend, in lockstep in one process: ATE with the backend vs the frontend alone.

Each frame is tracked by ``FrontendPipeline``; a keyframe goes through the bus codec to
``LocalMapper.process`` (gtsam local BA) and its map update back to the pipeline before the next
frame, as ``zenslam run --lockstep`` orders them. Thresholds (the figures behind them come from
``benchmarks/backend_quality.py``): KITTI 06 clip ATE <= 3.0 cm; on the synthetic scenes' first 80
frames the backend keeps at most a per-scene share of the frontend's ATE (the frontend alone culls
no points; the gap grows with the path: ``benchmarks/backend_quality.py`` runs the whole scenes).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from zenslam.backend.local_mapping import LocalMapper, bundle_adjuster, new_backend_map
from zenslam.frontend.node import keyframe_message
from zenslam.frontend.pipeline import FrontendConfig, FrontendPipeline
from zenslam.schemas import codec
from zenslam.service.evaluation.metrics import EvaluationConfig, evaluate
from zenslam.backend.config import BackendConfig
from zenslam.trajectory import Trajectory


def run_lockstep(source, with_backend: bool, max_frames: int | None = None) -> tuple[float | None, list[str], LocalMapper]:
    """(ATE rmse in metres of the per-frame poses, None when none was tracked; the frame states; the mapper)
    of one run; monocular runs are compared after a Sim(3) alignment."""
    config = BackendConfig()
    mapper = LocalMapper(new_backend_map(config.local_mapping), config.local_mapping, bundle_adjuster(config.local_ba))
    pipeline = FrontendPipeline(FrontendConfig(), source.calibration, source.sensor)
    stamps, poses, states = [], [], []
    for frame in source:
        if max_frames is not None and frame.index >= max_frames:
            break
        out = pipeline.step(frame.index, frame.stamp_ns, frame.left, right=frame.right, depth_m=frame.depth_m)
        states.append(out.state)
        if out.T_world_cam is not None:
            stamps.append(out.stamp_ns)
            poses.append(out.T_world_cam)
        for keyframe in out.keyframes_made if with_backend else []:
            message = keyframe_message(keyframe, source.calibration, source.sensor)
            update = mapper.process(codec.decode_keyframe(codec.encode_keyframe(message)))
            pipeline.apply_map_update(codec.decode_map_update(codec.encode_map_update(update)))
    if not poses:
        return None, states, mapper
    estimate = Trajectory(np.asarray(stamps, np.int64), np.stack(poses))
    alignment = "sim3" if source.sensor == "mono" else "se3"
    return evaluate(estimate, source.ground_truth(), EvaluationConfig(alignment=alignment)).ate.rmse_m, states, mapper


@pytest.mark.slow(16)
@pytest.mark.dataset
@pytest.mark.extended
def test_kitti_06_clip_with_the_backend_is_within_3_cm(kitti_root: Path) -> None:
    from zenslam.service.sources.kitti import KittiSource

    source = KittiSource(kitti_root / "sequences" / "06")
    ate_m, states, mapper = run_lockstep(source, with_backend=True)
    assert states == ["ok"] * 51
    assert ate_m <= 0.03, f"ATE {ate_m * 100:.2f} cm with the backend"
    assert len(mapper.map.keyframes) >= 3 and mapper.totals["points_created"] > 0


@pytest.mark.slow(40)
@pytest.mark.dataset
@pytest.mark.extended
def test_kitti_06_clip_monocular_starts_within_10_frames_and_stays_within_5_cm(kitti_root: Path) -> None:
    from zenslam.service.sources.kitti import KittiSource
    from zenslam.service.sources.sensor_selection import as_sensor

    source = as_sensor(KittiSource(kitti_root / "sequences" / "06"), "mono")
    ate_m, states, mapper = run_lockstep(source, with_backend=True)
    started = states.index("ok")
    assert started < 10 and states[started:] == ["ok"] * (51 - started), states
    assert ate_m <= 0.05, f"ATE {ate_m * 100:.2f} cm after Sim(3) alignment"
    assert mapper.totals["points_created"] > 0


@pytest.mark.dataset
@pytest.mark.extended
def test_euroc_micro_monocular_never_starts_a_map(euroc_micro: Path) -> None:
    """A nearly still camera gives no parallax: no map, every frame initialising (ORB-SLAM3 does not start
    either). The first 50 frames (5 s) here; ``zenslam run`` on the whole clip says the same."""
    from zenslam.service.sources.euroc import EurocSource
    from zenslam.service.sources.sensor_selection import as_sensor

    ate_m, states, mapper = run_lockstep(as_sensor(EurocSource(euroc_micro), "mono"), with_backend=True, max_frames=50)
    assert ate_m is None and set(states) == {"initializing"} and not mapper.map.keyframes


@pytest.mark.extended
@pytest.mark.slow(25)
# The most ATE the backend may keep of the frontend's alone. The figure-eight's RGB-D depths are
# near exact, so the frontend alone (no local BA, and no point culling: the backend owns that) is
# already close; the loop's stereo depths leave the backend more to gain.
@pytest.mark.parametrize(("scene", "sensor", "max_ratio"), [("loop", "stereo", 0.6), ("figure_eight", "rgbd", 0.95)])
def test_the_backend_beats_the_frontend_alone_on_synthetic_scenes(scene: str, sensor: str, max_ratio: float) -> None:
    from zenslam.service.sources.synthetic import SyntheticSource, scene_config

    source = SyntheticSource(scene_config(scene, sensor=sensor))
    frontend_m, _, _ = run_lockstep(source, with_backend=False, max_frames=FRAMES)
    backend_m, states, _ = run_lockstep(source, with_backend=True, max_frames=FRAMES)
    assert states == ["ok"] * FRAMES
    assert backend_m < max_ratio * frontend_m, f"ATE {backend_m * 100:.2f} cm with the backend, {frontend_m * 100:.2f} cm without"


FRAMES = 80  # the loop's first 8 s (10 Hz), the figure-eight's first 4 s (20 Hz)
