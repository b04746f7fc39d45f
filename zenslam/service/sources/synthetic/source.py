"""SyntheticSource: the textured room or corridor seen along an analytic trajectory, rendered lazily frame by frame.

World frame z up (floor z = 0, gravity (0, 0, -9.81) m/s^2); camera frame x right, y down, z forward.
Ground truth is the exact pose of the left camera; the right camera is the left one shifted by the
baseline along its +x axis; RGB-D depth is registered to the left image. Output is a pure function
of the configuration: the same SceneConfig gives byte-identical images and IMU samples.
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Iterator

import numpy as np

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.errors import ConfigError
from zenslam.geometry import invert_T, make_T
from zenslam.service.sources.frame import ImuSamples, SensorFrame
from zenslam.service.sources.synthetic.config import SceneConfig
from zenslam.service.sources.synthetic.imu import synthesize_imu
from zenslam.service.sources.synthetic.photometric import apply_photometric
from zenslam.service.sources.synthetic.renderer import Renderer, Rendering
from zenslam.service.sources.synthetic.scene import Scene, build_scene
from zenslam.service.sources.synthetic.trajectories import AnalyticTrajectory, make_trajectory
from zenslam.trajectory import Trajectory

logger = logging.getLogger(__name__)


class SyntheticSource:
    """A Source (see zenslam.service.sources.frame) over a synthetic scene with exact truth and IMU."""

    def __init__(self, config: SceneConfig, scene: Scene | None = None):
        """``scene`` reuses geometry and textures built for another source with the same seed,
        texels_per_m and tile_m (they take most of the start-up time); None builds them on first use."""
        if scene is not None:
            built = (scene.seed, scene.texels_per_m, scene.tile_m, scene.world, scene.texture)
            wanted = (config.seed, config.texels_per_m, config.tile_m, config.world, config.texture)
            if built != wanted:
                raise ConfigError(
                    f"the scene passed in was built with seed={scene.seed}, texels_per_m={scene.texels_per_m}, "
                    f"tile_m={scene.tile_m}, world={scene.world}, texture={scene.texture} but the config asks for "
                    f"seed={config.seed}, texels_per_m={config.texels_per_m}, tile_m={config.tile_m}, "
                    f"world={config.world}, texture={config.texture}; pass scene=None to build a new one"
                )
        self._config = config
        self._prebuilt_scene = scene
        self._trajectory = make_trajectory(config)
        count = config.frame_count()
        self._stamps_ns = config.start_stamp_ns + np.round(np.arange(count) * (1e9 / config.frame_rate_hz)).astype(
            np.int64
        )
        self._T_cam_right = make_T(np.eye(3), [config.baseline_m, 0.0, 0.0])

    @property
    def config(self) -> SceneConfig:
        return self._config

    @property
    def name(self) -> str:
        return f"synthetic:{self._config.scene_name}"

    @property
    def sensor(self) -> SensorKind:
        return self._config.sensor

    @property
    def calibration(self) -> PinholeCalibration:
        return self._config.calibration()

    @property
    def trajectory(self) -> AnalyticTrajectory:
        """The analytic camera path (evaluate it at any time in seconds from the first frame)."""
        return self._trajectory

    @functools.cached_property
    def scene(self) -> Scene:
        """Geometry and textures, generated on first use (a fraction of a second at default resolution)."""
        if self._prebuilt_scene is not None:
            return self._prebuilt_scene
        start = time.perf_counter()
        c = self._config
        scene = build_scene(c.seed, c.texels_per_m, c.tile_m, c.world, c.texture)
        logger.debug("built synthetic scene: %d tiles in %.2f s", len(scene.tiles), time.perf_counter() - start)
        return scene

    @functools.cached_property
    def _renderer(self) -> Renderer:
        return Renderer(self.scene.tiles, self.calibration, self._config.near_m)

    def __len__(self) -> int:
        return len(self._stamps_ns)

    def __iter__(self) -> Iterator[SensorFrame]:
        for index in range(len(self)):
            yield self.frame(index)

    def stamps_ns(self) -> np.ndarray:
        return self._stamps_ns.copy()

    def times_s(self) -> np.ndarray:
        """Frame times in seconds from the first frame (the trajectory's time argument)."""
        return (self._stamps_ns - self._config.start_stamp_ns) / 1e9

    def ground_truth(self) -> Trajectory:
        """Exact poses T_world_cam of the left camera at every frame stamp."""
        return Trajectory(self.stamps_ns(), self._trajectory.T_world_cam(self.times_s()))

    def imu(self) -> ImuSamples:
        """IMU samples at ``imu_rate_hz`` over the whole sequence (noise and bias from the config)."""
        return synthesize_imu(self._trajectory, self._config)

    def render(self, T_world_cam: np.ndarray) -> Rendering:
        """The noise-free view (grey and inverse depth) of a camera with this calibration at ``T_world_cam``."""
        return self._renderer.render(T_world_cam)

    def frame(self, index: int) -> SensorFrame:
        """Render frame ``index`` (0-based): left image, plus right image (stereo) or depth (rgbd)."""
        if not 0 <= index < len(self):
            raise ConfigError(f"synthetic frame index {index} is out of range: the sequence has {len(self)} frames")
        t_s = float(self.times_s()[index])
        T_world_cam = self._trajectory.T_world_cam(np.array([t_s]))[0]
        left = self.render(T_world_cam)
        flow = self._blur_flow_px(T_world_cam, t_s, left)
        grey_left = self._degrade(left.grey, index, 0, t_s, flow)
        stamp = int(self._stamps_ns[index])
        if self.sensor == "stereo":
            right = self.render(T_world_cam @ self._T_cam_right)
            return SensorFrame(index, stamp, grey_left, right=self._degrade(right.grey, index, 1, t_s, flow))
        if self.sensor == "rgbd":
            return SensorFrame(index, stamp, grey_left, depth_m=left.depth_m())
        return SensorFrame(index, stamp, grey_left)

    def _degrade(self, grey: np.ndarray, index: int, camera: int, t_s: float, flow: tuple[float, float]) -> np.ndarray:
        rng = np.random.default_rng([self._config.seed, 0xF4A3E, index, camera])
        return apply_photometric(grey, self._config.photometric, t_s, flow, rng)

    def _blur_flow_px(self, T_world_cam: np.ndarray, t_s: float, view: Rendering) -> tuple[float, float]:
        """Image motion (pixels) of the principal point's scene point during the exposure; (0, 0) when off."""
        exposure = self._config.photometric.motion_blur_exposure_s
        cal = self.calibration
        centre_inv_depth = float(view.inv_depth[int(round(cal.cy)), int(round(cal.cx))])
        if exposure <= 0 or centre_inv_depth <= 0:
            return (0.0, 0.0)
        p_world = T_world_cam[:3, :3] @ np.array([0.0, 0.0, 1.0 / centre_inv_depth]) + T_world_cam[:3, 3]
        ends = []
        for T in self._trajectory.T_world_cam(np.array([t_s - exposure / 2, t_s + exposure / 2])):
            p_cam = invert_T(T)[:3, :3] @ p_world + invert_T(T)[:3, 3]
            ends.append(cal.K[:2, :2] @ (p_cam[:2] / p_cam[2]))
        dx, dy = ends[1] - ends[0]
        return (float(dx), float(dy))
