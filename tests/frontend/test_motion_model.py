"""Constant-velocity motion model."""

from __future__ import annotations

import numpy as np

from zenslam.frontend.motion_model import ConstantVelocityModel
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
