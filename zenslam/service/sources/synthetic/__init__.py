"""Synthetic scenes: a textured room or corridor along analytic trajectories, with exact ground truth, stereo, depth and IMU."""

from zenslam.service.sources.synthetic.config import (
    SCENE_NAMES,
    PhotometricConfig,
    SceneConfig,
    TextureConfig,
    scene_config,
)
from zenslam.service.sources.synthetic.source import SyntheticSource

__all__ = ["SCENE_NAMES", "PhotometricConfig", "SceneConfig", "SyntheticSource", "TextureConfig", "scene_config"]
