"""Monocular loop closing end to end: the synthetic loop seen by the left camera alone, tracked and
mapped in lockstep in one process (``FrontendPipeline`` + ``BackendNode`` through the bus codec).

With the monocular defaults (covisibility information shared in Sim(3) pose graphs, a 10% drift
budget) the true loop back to the start is accepted and corrects the keyframes to under a
centimetre; with the stereo graphs' full information it is rejected at every verification and the
keyframes stay centimetres off (benchmarks/loop_closing.md).
"""

from __future__ import annotations

import numpy as np
import pytest

from zenslam.backend.config import BackendConfig
from zenslam.backend.node import BackendNode
from zenslam.frontend.node import keyframe_message
from zenslam.frontend.pipeline import FrontendConfig, FrontendPipeline
from zenslam.schemas import codec
from zenslam.service.evaluation.metrics import EvaluationConfig, evaluate
from zenslam.service.sources.synthetic import SyntheticSource, scene_config
from zenslam.trajectory import Trajectory


@pytest.mark.slow(240)
@pytest.mark.extended
def test_the_monocular_synthetic_loop_is_closed_and_its_keyframes_land_within_a_centimetre() -> None:
    source = SyntheticSource(scene_config("loop", sensor="mono"))
    pipeline = FrontendPipeline(FrontendConfig(), source.calibration, "mono")
    backend = BackendNode.from_config(BackendConfig())
    loops: list[codec.LoopMessage] = []
    try:
        for frame in source:
            out = pipeline.step(frame.index, frame.stamp_ns, frame.left)
            for keyframe in out.keyframes_made:
                message = codec.encode_keyframe(keyframe_message(keyframe, source.calibration, "mono"))
                step = backend.step(codec.decode_keyframe(message))
                loops.extend(step.loops)
                for update in step.updates:
                    pipeline.apply_map_update(codec.decode_map_update(codec.encode_map_update(update)))
        keyframes = sorted(backend.map.keyframes.values(), key=lambda kf: kf.stamp_ns)
    finally:
        backend.close()
    accepted = [loop for loop in loops if loop.accepted]
    assert accepted, f"no loop accepted of {len(loops)} verified: {[loop.reason for loop in loops]}"
    assert accepted[0].loop_keyframe_id < 5  # the revisit of the start
    estimate = Trajectory(np.array([kf.stamp_ns for kf in keyframes], np.int64), np.stack([kf.T_world_cam for kf in keyframes]))
    ate = evaluate(estimate, source.ground_truth(), EvaluationConfig(alignment="sim3")).ate.rmse_m
    assert ate < 0.01, f"keyframes' Sim(3) ATE {ate * 100:.2f} cm after the loop"
