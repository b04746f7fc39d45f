"""Configuration of a synthetic scene: trajectory, sensor, camera, textures, IMU and photometric effects."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Literal

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.errors import ConfigError
from zenslam.config import from_mapping, to_mapping

TrajectoryKind = Literal["loop", "figure_eight", "still", "corridor"]
World = Literal["room", "corridor"]

SCENE_NAMES: tuple[str, ...] = ("loop", "figure_eight", "still", "corridor", "corridor_aliased")


@dataclass(frozen=True)
class PhotometricConfig:
    """Image degradations applied after rendering; every effect is off at its default."""

    noise_sigma: float = 0.0  # grey levels (0-255 scale): std of per-pixel Gaussian noise; 0 = off
    defocus_sigma_px: float = 0.0  # pixels: std of a Gaussian defocus blur; 0 = off
    motion_blur_exposure_s: float = 0.0  # seconds: blur along the image motion during this exposure; 0 = off
    gain_amplitude: float = 0.0  # fraction: gain = 1 + amplitude * sin(2 pi t / gain_period_s); 0 = off
    gain_period_s: float = 10.0  # seconds: period of the exposure (gain) change

    def __post_init__(self) -> None:
        problems = [
            f"{name}={getattr(self, name)} must be >= 0"
            for name in ("noise_sigma", "defocus_sigma_px", "motion_blur_exposure_s", "gain_amplitude")
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0)
        ]
        if not (math.isfinite(self.gain_period_s) and self.gain_period_s > 0):
            problems.append(f"gain_period_s={self.gain_period_s} must be a positive number of seconds")
        if self.gain_amplitude >= 1.0:
            problems.append(f"gain_amplitude={self.gain_amplitude} must be < 1 (the gain would reach zero)")
        if problems:
            raise ConfigError("invalid photometric configuration: " + "; ".join(problems))

    @property
    def enabled(self) -> bool:
        """True when any effect changes the rendered image."""
        return any(
            v > 0 for v in (self.noise_sigma, self.defocus_sigma_px, self.motion_blur_exposure_s, self.gain_amplitude)
        )


@dataclass(frozen=True)
class TextureConfig:
    """How surfaces are textured; at the defaults every surface is textured all over at full contrast."""

    coverage: float = 1.0  # fraction in (0, 1]: share of each surface under textured panels on a plain background
    contrast: float = 1.0  # fraction in (0, 1]: contrast of the panels relative to the full procedural texture
    wall_repeat_m: float = 0.0  # metres: wall textures repeat every this many metres along the wall; 0 = never

    def __post_init__(self) -> None:
        problems = [
            f"{name}={getattr(self, name)} must be a fraction in (0, 1]"
            for name in ("coverage", "contrast")
            if not (math.isfinite(getattr(self, name)) and 0.0 < getattr(self, name) <= 1.0)
        ]
        if not (math.isfinite(self.wall_repeat_m) and self.wall_repeat_m >= 0):
            problems.append(f"wall_repeat_m={self.wall_repeat_m} must be >= 0 metres (0 = never repeat)")
        if problems:
            raise ConfigError("invalid texture configuration: " + "; ".join(problems))

    @property
    def sparse(self) -> bool:
        """True when surfaces carry panels on a plain background, or panels of reduced contrast."""
        return self.coverage < 1.0 or self.contrast < 1.0

    @property
    def default(self) -> bool:
        """True when textures are the plain procedural ones (all over, full contrast, nothing repeated)."""
        return not self.sparse and self.wall_repeat_m == 0.0


@dataclass(frozen=True)
class SceneConfig:
    """A synthetic sequence: a textured room or corridor seen along an analytic trajectory, with exact truth."""

    trajectory: TrajectoryKind = "loop"  # camera path: closed loop, figure-eight laps, still camera (room); corridor laps
    sensor: SensorKind = "stereo"  # which images each frame carries: mono (left), stereo (left+right), rgbd
    seed: int = 0  # seeds the textures and every noise draw; same seed -> byte-identical output
    duration_s: float = 30.0  # seconds of sequence; frames run from t=0 to t=duration_s inclusive
    frame_rate_hz: float = 20.0  # camera frames per second
    laps: int = 1  # laps of the closed path within duration_s (loop, figure_eight)
    start_stamp_ns: int = 0  # nanoseconds: stamp of the first frame and IMU sample
    width: int = 640  # pixels
    height: int = 480  # pixels
    fx: float = 460.0  # pixels
    fy: float = 460.0  # pixels
    cx: float = 319.5  # pixels
    cy: float = 239.5  # pixels
    baseline_m: float = 0.10  # metres: right camera = left shifted along +x (virtual baseline for rgbd)
    near_m: float = 0.05  # metres: near clipping distance of the renderer
    texels_per_m: float = 256.0  # texture resolution on every surface, texels per metre
    tile_m: float = 2.0  # metres: surfaces are split into tiles of at most this size (culling, mip choice)
    imu_rate_hz: float = 200.0  # IMU samples per second
    cam_imu_translation_m: tuple[float, float, float] = (0.04, -0.015, 0.01)  # metres: IMU origin in the camera frame
    cam_imu_rotvec_rad: tuple[float, float, float] = (0.01, -0.02, 0.015)  # radians: rotation vector of R_cam_imu
    gyro_noise_std_rad_s: float = 0.0  # rad/s: std of white noise added to each gyro sample
    accel_noise_std_m_s2: float = 0.0  # m/s^2: std of white noise added to each accelerometer sample
    gyro_bias_rad_s: tuple[float, float, float] = (0.0, 0.0, 0.0)  # rad/s: constant gyro bias (IMU frame)
    accel_bias_m_s2: tuple[float, float, float] = (0.0, 0.0, 0.0)  # m/s^2: constant accelerometer bias (IMU frame)
    depth_noise_per_m: float = 0.0  # 1/m: RGB-D depth noise std = this * depth^2 (a Kinect's ~0.0014); 0 = off
    depth_range_m: float = 0.0  # metres: RGB-D depth beyond this reads 0 (no measurement), as a sensor's range; 0 = unlimited
    texture: TextureConfig = field(default_factory=TextureConfig)  # surface textures (all over, full contrast)
    photometric: PhotometricConfig = field(default_factory=PhotometricConfig)  # image degradations (off)

    def __post_init__(self) -> None:
        problems = []
        positive = ("duration_s", "frame_rate_hz", "near_m", "texels_per_m", "tile_m", "imu_rate_hz")
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                problems.append(f"{name}={value} must be positive")
        if self.laps < 1:
            problems.append(f"laps={self.laps} must be at least 1")
        for name in ("gyro_noise_std_rad_s", "accel_noise_std_m_s2", "depth_noise_per_m", "depth_range_m"):
            if not getattr(self, name) >= 0:
                problems.append(f"{name}={getattr(self, name)} must be >= 0")
        if problems:
            raise ConfigError("invalid synthetic scene configuration: " + "; ".join(problems))
        self.calibration()  # raises CalibrationError naming bad intrinsics

    @property
    def world(self) -> World:
        """The geometry the trajectory runs in: the corridor ring for corridor laps, else the room."""
        return "corridor" if self.trajectory == "corridor" else "room"

    @property
    def scene_name(self) -> str:
        """The scene's name in source specs: the trajectory's, ``corridor_aliased`` for a corridor with repeated walls."""
        if self.trajectory == "corridor" and self.texture.wall_repeat_m > 0:
            return "corridor_aliased"
        return self.trajectory

    def calibration(self) -> PinholeCalibration:
        """The rectified left-camera calibration; baseline set for stereo and rgbd (virtual for rgbd)."""
        baseline = None if self.sensor == "mono" else self.baseline_m
        return PinholeCalibration(self.fx, self.fy, self.cx, self.cy, self.width, self.height, baseline)

    def frame_count(self) -> int:
        """Frames from t=0 to t=duration_s inclusive (a closed loop's last frame repeats its first pose)."""
        return int(math.floor(self.duration_s * self.frame_rate_hz + 1e-9)) + 1


def _preset(name: str) -> dict[str, Any]:
    """Defaults of a named scene; a closed loop takes 30 s, a figure-eight two 30 s laps, the corridor
    two 45 s laps of 68 m at 10 Hz (the aliased corridor's wall textures repeat every 6 m)."""
    # The corridor scenes test loop closing, so odometry must drift there, which it hardly does on densely
    # textured surfaces with exact images and depth: textured panels cover 10% of each surface at 35%
    # contrast, images carry noise of 4 grey levels, and RGB-D depth noise grows with depth squared as a
    # low-cost depth camera's does (std 0.008 z^2: 3 cm at 2 m).
    corridor: dict[str, Any] = {
        "trajectory": "corridor",
        "duration_s": 90.0,
        "laps": 2,
        "frame_rate_hz": 10.0,
        "texture": {"coverage": 0.10, "contrast": 0.35},
        "photometric": {"noise_sigma": 4.0},
        "depth_noise_per_m": 0.008,
    }
    presets: dict[str, dict[str, Any]] = {
        "loop": {"trajectory": "loop", "duration_s": 30.0, "laps": 1, "frame_rate_hz": 10.0},
        "figure_eight": {"trajectory": "figure_eight", "duration_s": 60.0, "laps": 2},
        "still": {"trajectory": "still", "duration_s": 5.0, "laps": 1},
        "corridor": corridor,
        "corridor_aliased": {**corridor, "texture": {**corridor["texture"], "wall_repeat_m": 6.0}},
    }
    if name not in presets:
        raise ConfigError(f"unknown synthetic scene {name!r}: choose one of {list(SCENE_NAMES)}")
    return dict(presets[name])


def scene_config(name: str, **overrides: Any) -> SceneConfig:
    """The named preset (one of SCENE_NAMES) with ``overrides`` (field names of SceneConfig).

    Overrides are checked like YAML keys: unknown names or wrong types raise ConfigError.
    """
    mapping = _preset(name)
    for key, value in overrides.items():
        mapping[key] = to_mapping(value) if dataclasses.is_dataclass(value) else value
    return from_mapping(SceneConfig, mapping)
