"""The ``source`` section of a run's YAML: what the source process plays and how."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.errors import ConfigError
from zenslam.service.sources.faults import FrameFault, check_faults


# Where ``zenslam publish`` listens and ``zenoh:`` sources connect by default: zenoh's own default
# port, so a camera driver talking to a zenoh router on this machine is found the same way.
DEFAULT_BUS_INPUT = "tcp/127.0.0.1:7447"


@dataclass(frozen=True)
class SourceConfig:
    """What the source process plays and how (the ``source`` section)."""

    spec: str = "synthetic"  # kitti:<root>/sequences/NN | euroc:<folder> | tum:<folder> | synthetic[:<scene>[/<sensor>][,laps=N][,seed=N]] | zenoh:<key>
    # Play the source as this sensor (None: its own): mono runs a stereo or RGB-D dataset on its left
    # images; a synthetic scene renders any of mono, stereo, rgbd (``zenslam run --sensor``).
    sensor: SensorKind | None = None
    rate: float = 1.0  # live mode: playback speed as a multiple of the recorded rate; 0 = as fast as possible
    max_frames: int | None = None  # frames; stop after this many (None: the whole sequence)
    depth_encoding: Literal["float32_m", "uint16_mm"] = "float32_m"  # how RGB-D depth travels on the bus
    # Lockstep: seconds without the frontend's answer to a frame after which the source checks that the
    # frontend still runs (then waits on, with a warning) or fails the run (it is gone).
    answer_timeout_s: float = 120.0
    # Lockstep: frames sent whose frontend/state has not arrived. 2 reads and sends frame i+1 while
    # frame i is tracked, taking the source's reading/decoding off the serial path; the frontend
    # still takes every frame in order, so lockstep outputs are the same at any window. 1 = strict.
    frames_in_flight: int = 2  # frames
    calibration: PinholeCalibration | None = None  # rectified intrinsics overriding the source's own (None: keep)
    # A frame that cannot be read or decoded, or whose stamp does not increase: False = skip it with
    # one warning and count it (metrics.json ``skipped_frames``); True = end the run with an error
    # naming the frame (``zenslam run --strict``).
    strict: bool = False
    # Injected faults, e.g. ``[{kind: drop, first_frame: 10, last_frame: 12}]``: kinds black, drop,
    # corrupt, stamp_backwards, stamp_repeat over frame indices (inclusive); see sources/faults.py.
    faults: tuple[FrameFault, ...] = ()
    # Bus sources (``zenoh:<prefix>``, frames another program publishes; see sources/zenoh_family.py):
    # zenoh endpoints the source process connects to, to reach the publisher (``zenslam run --connect``;
    # ``zenslam publish`` listens on the first by default; a bus.zenoh_config_file replaces them).
    connect: tuple[str, ...] = (DEFAULT_BUS_INPUT,)
    idle_timeout_s: float = 5.0  # seconds without a message, after the first frame, that end the stream (0: never)
    first_frame_timeout_s: float = 60.0  # seconds to wait for the first message before failing (0: forever)
    calibration_timeout_s: float = 10.0  # seconds from the first image to the first complete frame before failing
    pair_tolerance_ms: float = 0.5  # largest stamp difference of a stereo (or image/depth) pair, milliseconds
    pending: int = 4  # newest messages kept per key while tracking is busy, messages
    max_message_bytes: int = 64 * 2**20  # larger payloads are rejected unread, bytes
    ros_domain: int = 0  # ``ros2:<namespace>`` sources: the ROS domain id (``zenslam run --ros-domain``)

    def __post_init__(self) -> None:
        check_faults(self.faults)
        if self.sensor not in (None, "mono", "stereo", "rgbd"):
            raise ConfigError(f"source.sensor={self.sensor!r} must be mono, stereo, rgbd, or null for the source's own")
        if not (math.isfinite(self.rate) and self.rate >= 0):
            raise ConfigError(f"source.rate={self.rate} must be >= 0 (1 = recorded rate, 0 = as fast as possible)")
        if self.frames_in_flight < 1:
            raise ConfigError(
                f"source.frames_in_flight={self.frames_in_flight} must be at least 1 frame (1: send a frame only after "
                "the previous one's state arrived)"
            )
        if self.max_frames is not None and self.max_frames < 1:
            raise ConfigError(f"source.max_frames={self.max_frames} must be >= 1, or null for all frames")
        for name in ("idle_timeout_s", "first_frame_timeout_s", "pair_tolerance_ms"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise ConfigError(f"source.{name}={getattr(self, name)} must be a number >= 0")
        if not self.calibration_timeout_s > 0 or self.pending < 1 or self.max_message_bytes < 1:
            raise ConfigError(
                f"source.calibration_timeout_s={self.calibration_timeout_s}, source.pending={self.pending} and "
                f"source.max_message_bytes={self.max_message_bytes} must be positive"
            )
        if not self.answer_timeout_s > 0:
            raise ConfigError(f"source.answer_timeout_s={self.answer_timeout_s} must be a positive number of seconds")
