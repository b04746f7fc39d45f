"""Constant-velocity motion model."""

from __future__ import annotations

import numpy as np

from zenslam.frontend.motion_model import ConstantVelocityModel, se3_power
from zenslam.geometry import invert_T, make_T, so3_exp


def test_constant_velocity_prediction_repeats_the_last_motion() -> None:
    step = make_T(so3_exp(np.array([0.01, -0.02, 0.03])), np.array([0.1, 0.0, 0.9]))  # T_world_cam k -> k+1
    T_world_cam = [np.eye(4)]
    for _ in range(3):
        T_world_cam.append(T_world_cam[-1] @ step)
    model = ConstantVelocityModel()
    assert model.predict(invert_T(T_world_cam[1])) is None
    model.update(invert_T(T_world_cam[0]), invert_T(T_world_cam[1]))
    predicted = model.predict(invert_T(T_world_cam[1]))
    assert np.allclose(predicted, invert_T(T_world_cam[2]), atol=1e-12)
    model.update(invert_T(T_world_cam[1]), invert_T(T_world_cam[2]))
    assert np.allclose(model.predict(invert_T(T_world_cam[2])), invert_T(T_world_cam[3]), atol=1e-12)
    assert np.allclose(model.velocity, invert_T(step), atol=1e-12)
    model.reset()
    assert not model.has_velocity and model.predict(np.eye(4)) is None


def test_se3_power_matches_repeated_products_and_roots() -> None:
    step = make_T(so3_exp(np.array([0.02, -0.3, 0.05])), np.array([0.4, -0.1, 1.2]))
    assert np.allclose(se3_power(step, 3.0), step @ step @ step, atol=1e-12)
    root = se3_power(step, 0.5)
    assert np.allclose(root @ root, step, atol=1e-12)
    assert np.allclose(se3_power(step, 1.0), step, atol=1e-12)
    tiny = make_T(so3_exp(np.array([1e-10, 0.0, 0.0])), np.array([0.0, 0.0, 0.1]))
    assert np.allclose(se3_power(tiny, 4.0), tiny @ tiny @ tiny @ tiny, atol=1e-12)


def test_skipped_frames_scale_the_prediction_and_the_velocity() -> None:
    """A live run skips frames: k frame indices apart, the per-frame motion applies k times."""
    step = make_T(so3_exp(np.array([0.01, -0.02, 0.03])), np.array([0.1, 0.0, 0.9]))  # T_world_cam k -> k+1
    T_world_cam = [np.eye(4)]
    for _ in range(8):
        T_world_cam.append(T_world_cam[-1] @ step)
    model = ConstantVelocityModel()
    model.update(invert_T(T_world_cam[0]), invert_T(T_world_cam[1]))
    # Frames 2 and 3 skipped: frame 4 is 3 indices after frame 1.
    assert np.allclose(model.predict(invert_T(T_world_cam[1]), frames=3), invert_T(T_world_cam[4]), atol=1e-12)
    # A velocity measured across a 3-frame gap (frame 4 -> 7) is per frame again.
    model.update(invert_T(T_world_cam[4]), invert_T(T_world_cam[7]), frames=3)
    assert np.allclose(model.velocity, invert_T(step), atol=1e-12)
    assert np.allclose(model.predict(invert_T(T_world_cam[7])), invert_T(T_world_cam[8]), atol=1e-12)
    # Without the gap the old model would be off by two frames of motion (1.8 m).
    wrong = model.velocity @ invert_T(T_world_cam[1])
    assert np.linalg.norm(invert_T(wrong)[:3, 3] - T_world_cam[4][:3, 3]) > 1.5


def test_a_gap_of_one_is_the_plain_product() -> None:
    """Lockstep (consecutive frames) keeps ORB-SLAM's formula bit for bit."""
    rng = np.random.default_rng(3)
    A = make_T(so3_exp(rng.normal(0, 0.2, 3)), rng.normal(0, 1, 3))
    B = make_T(so3_exp(rng.normal(0, 0.2, 3)), rng.normal(0, 1, 3))
    model = ConstantVelocityModel()
    model.update(A, B)
    assert np.array_equal(model.velocity, B @ invert_T(A))
    assert np.array_equal(model.predict(B), (B @ invert_T(A)) @ B)


def test_gaps_hidden_from_the_indices_are_read_from_the_stamps() -> None:
    """A bus source numbers only the frames it passes on: the stamps tell how many frames a gap spans."""
    model = ConstantVelocityModel()
    assert model.frames_between(1, 300_000_000) == 1  # no interval known yet: the indices decide
    rng = np.random.default_rng(5)
    for _ in range(9):  # a 10 Hz camera with +-5 ms of stamp jitter
        model.update(np.eye(4), np.eye(4), 1, int(100_000_000 + rng.integers(-5_000_000, 5_000_000)))
    assert model.frames_between(1, 104_000_000) == 1
    assert model.frames_between(1, 312_000_000) == 3  # two frames dropped before numbering
    assert model.frames_between(4, 312_000_000) == 4  # the indices never count fewer frames than they show
    assert model.frames_between(1, 0) == 1  # stamps that do not advance say nothing
    model.update(np.eye(4), np.eye(4), 3, 300_000_000)  # a velocity across a gap measures the interval per frame
    assert model.frames_between(1, 205_000_000) == 2
