"""The ``recorder`` section of a run's YAML: what the recorder process writes to ``<run>/run.mcap``."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from zenslam.errors import ConfigError
from zenslam.service.mcap_io import ChunkCompression

RECORDING_NAME = "run.mcap"  # the recorder's file in the run folder


@dataclass(frozen=True)
class RecorderConfig:
    """The recorder process (the ``recorder`` section): every bus message to ``<run>/run.mcap``."""

    enabled: bool = True  # start the recorder with ``zenslam run``
    # How sensor/frame's images are stored; lossless either way. PNG: about half the bytes of raw for
    # some CPU per image (benchmarks/footprint.md); raw: no CPU.
    frame_images: Literal["png", "raw"] = "png"
    # The /camera/* Foxglove images drawn by viewers; sensor/frame is always recorded losslessly.
    # frame: they are the frames' own PNG images, stored once (sensor/frame refers to them; needs
    # frame_images png). png or jpeg: separate copies beside the frames' images; JPEG costs less CPU
    # and fewer bytes than PNG (benchmarks/footprint.md).
    image_format: Literal["frame", "png", "jpeg"] = "frame"
    jpeg_quality: int = 75  # JPEG quality 1-100 (image_format jpeg); as rerun.jpeg_quality, a viewer's image
    png_compression: int = 1  # zlib level 0-9 of every PNG (frame_images, image_format png); 1 is fast, higher levels gain little (benchmarks/footprint.md)
    # /map/points clouds (the whole map each) at most this far apart in sensor time; the final map is
    # always written. 0: one after every keyframe and map update.
    map_points_period_s: float = 1.0  # seconds
    # Uncompressed bytes per chunk; a killed recorder loses the open chunk (``zenslam recover`` keeps the rest).
    # The writer holds the open chunk and its compressed copy in memory; 2 MiB is about six stereo VGA
    # frames (PNG). Chunks that span several map updates let zstd find what consecutive updates repeat.
    chunk_size: int = 2 * 1024 * 1024  # bytes
    # MCAP chunk compression: zstd, lz4 or none. The images are PNG already, which neither shrinks;
    # on map updates zstd stores less than lz4, for about the same CPU (benchmarks/footprint.md).
    chunk_compression: ChunkCompression = "zstd"
    # Messages waiting for the writer thread; when full, publishers block (lossless: nothing is dropped).
    queue: int = 64  # messages
    quiet_s: float = 0.3  # seconds without a message that count as drained, at the end
    # Added to the recorder process's nice value (0-19, POSIX niceness) in pipelined and live runs:
    # recording (decoding every message, PNG-encoding every image: a large share of a live run's
    # CPU) yields the CPU to tracking, which must keep up with its camera, and catches up
    # from its queue while tracking waits; a recorder ``queue`` messages behind blocks the publishers,
    # so nothing is left out. What it holds unwritten (the open chunk, and that backlog) is what a
    # crash of the recorder loses: in lockstep it keeps its priority and pace, and loses one chunk
    # at most (benchmarks/stage_priorities.md). Scheduling only: the recording is the same.
    nice: int = 19  # niceness increment

    def __post_init__(self) -> None:
        if self.image_format == "frame" and self.frame_images != "png":
            raise ConfigError(
                f"recorder.image_format=frame stores the frames' own PNG images for viewers, but recorder.frame_images="
                f"{self.frame_images}; set frame_images to png, or image_format to jpeg or png for separate copies"
            )
        if not 1 <= self.jpeg_quality <= 100:
            raise ConfigError(f"recorder.jpeg_quality={self.jpeg_quality} must be between 1 and 100")
        if not 0 <= self.png_compression <= 9:
            raise ConfigError(f"recorder.png_compression={self.png_compression} must be a zlib level between 0 and 9")
        if self.chunk_size < 1024:
            raise ConfigError(f"recorder.chunk_size={self.chunk_size} must be at least 1024 bytes")
        if self.queue < 1:
            raise ConfigError(f"recorder.queue={self.queue} must be at least 1 message")
        if not (math.isfinite(self.map_points_period_s) and self.map_points_period_s >= 0):
            raise ConfigError(f"recorder.map_points_period_s={self.map_points_period_s} must be >= 0 seconds (0: every map change)")
        if not 0 <= self.nice <= 19:
            raise ConfigError(f"recorder.nice={self.nice} must be within 0..19 (a niceness increment; 0 leaves it as is)")
        if not self.quiet_s >= 0:
            raise ConfigError(f"recorder.quiet_s={self.quiet_s} must be >= 0 seconds")
