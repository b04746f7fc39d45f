"""Localisation mode's pose estimate: each frame's map-tracked pose fused with the odometry's prediction.

In localisation mode the map is not refined, and where the frames see it only from afar (its points
off by centimetres along their rays) the pose from the map alone moves by centimetres from frame to
frame. ORB-SLAM2 steadies it with the last frame's near visual-odometry (VO) points, taken as exact
in the world: that ties each frame to the last one as if the last one's pose were exact, so an error
the map puts in one frame (a relocalisation on a few far points) is carried on for dozens of frames.

Here the pose is a recursive estimate with a covariance instead, as a Kalman filter on SE(3):
- predicted: the frame placed by the VO points of the last frame (or of the VO anchor), whose pose
  error is carried over to the frame and added to the odometry's own (its information from the VO
  points' pixels, each point weighed by the covariance of its one stereo view; ``predict``);
- updated: the pose from the local map alone, with its information from the map inliers (pixel
  noise plus the points' covariances, scaled by ``visual_odometry.filter_map_information_scale``:
  the points share errors the covariances leave out), fused with the prediction (``fuse``), unless
  the two disagree beyond the innovation test, when the map's pose replaces the prediction.
A frame on VO keeps the prediction, whose covariance grows frame by frame; a relocalisation that
ends VO is fused with it the same way, and one without odometry starts again from the map's pose
and information alone. The tracker (``Tracker._fused_with_odometry``) decides where it applies:
localisation mode with a stereo camera whose map points carry covariances.

Covariances are 6 x 6 on xi = (omega rad, upsilon m) of the left perturbation T <- exp(xi) T of
T_cam_world, as the pose optimiser steps (``pose_optimizer.pose_information``). Plain numpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from zenslam.geometry import invert_T, se3_adjoint, se3_exp, se3_log

# Information added before inverting one that may be singular (too few observations along some
# direction): a covariance of 1e9 there, i.e. no knowledge (units of the information, 1/rad^2, 1/m^2).
_REGULARISATION = 1e-9


@dataclass(frozen=True)
class PoseEstimate:
    """A frame's pose and its covariance."""

    T_cam_world: np.ndarray  # (4, 4) maps world points into the camera frame
    covariance: np.ndarray  # (6, 6) on xi = (omega rad, upsilon m), T <- exp(xi) T

    @staticmethod
    def from_information(T_cam_world: np.ndarray, information: np.ndarray) -> PoseEstimate:
        """The pose with the covariance its observations' information (6, 6) gives it."""
        return PoseEstimate(T_cam_world, _inverse(information))


def predict(source: PoseEstimate, T_cam_world: np.ndarray, odometry_information: np.ndarray) -> PoseEstimate:
    """The frame at ``T_cam_world``, placed by odometry relative to the frame of ``source``: that
    frame's covariance carried to this one, plus the odometry's own (the inverse of its
    ``odometry_information``, 6 x 6)."""
    carry = se3_adjoint(T_cam_world @ invert_T(source.T_cam_world))
    return PoseEstimate(T_cam_world, carry @ source.covariance @ carry.T + _inverse(odometry_information))


def fuse(T_map: np.ndarray, map_information: np.ndarray, predicted: PoseEstimate, max_chi2: float = math.inf) -> PoseEstimate:
    """The information-weighted mean of the map's pose ``T_map`` (information ``map_information``,
    6 x 6) and the ``predicted`` one, linearised at ``T_map``, and its covariance. When the two
    disagree by more than ``max_chi2`` (their offset's squared Mahalanobis distance under the sum
    of their covariances: the innovation test of a Kalman filter), the map's pose alone: the
    prediction has gone wrong, and the filter starts again from the map."""
    prior_information = _inverse(predicted.covariance)
    offset = se3_log(predicted.T_cam_world @ invert_T(T_map))
    if math.isfinite(max_chi2):
        innovation = _inverse(map_information) + predicted.covariance
        if float(offset @ np.linalg.solve(innovation, offset)) > max_chi2:
            return PoseEstimate.from_information(T_map, map_information)
    information = map_information + prior_information
    xi = np.linalg.solve(information + _REGULARISATION * np.eye(6), prior_information @ offset)
    return PoseEstimate(se3_exp(xi) @ T_map, _inverse(information))


def _inverse(matrix: np.ndarray) -> np.ndarray:
    """Inverse of a symmetric positive semi-definite 6 x 6 matrix, regularised, made symmetric."""
    inverse = np.linalg.inv(np.asarray(matrix, dtype=float) + _REGULARISATION * np.eye(6))
    return 0.5 * (inverse + inverse.T)
