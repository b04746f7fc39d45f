"""The ``rerun`` section of a run's YAML: what the stage processes log to rerun (kept apart from
``rerun_log`` so that reading a configuration does not load rerun)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from zenslam.errors import ConfigError


@dataclass(frozen=True)
class RerunConfig:
    """What the stage processes log to rerun (the ``rerun`` section): ``<run>/<stage>.rrd``, one recording per run."""

    enabled: bool = True  # every stage process writes its .rrd next to the run's config.yaml
    # frames; the frontend logs every n-th left image it tracks (keypoints and poses: every frame). Every
    # second image keeps the viewer's video smooth enough to follow and halves the images' share of frontend.rrd.
    image_every_n: int = 2
    # JPEG-compressed images: less CPU and smaller files than raw images (benchmarks/footprint.md).
    jpeg: bool = True
    # JPEG quality 1-100 (jpeg true): 50 keeps the features under the keypoints visible in smaller
    # files than higher qualities (benchmarks/footprint.md; the run's recording keeps the lossless frames).
    jpeg_quality: int = 50
    # The backend's whole map (backend/map_points, backend/covisibility) at most this far apart in
    # sensor time, and the final map; each holds every point and edge, so logging one per keyframe
    # grows the file with the square of the map. 0: after every keyframe.
    map_period_s: float = 1.0  # seconds

    def __post_init__(self) -> None:
        if not (math.isfinite(self.map_period_s) and self.map_period_s >= 0):
            raise ConfigError(f"rerun.map_period_s={self.map_period_s} must be >= 0 seconds (0: after every keyframe)")
        if self.image_every_n < 1:
            raise ConfigError(f"rerun.image_every_n={self.image_every_n} must be at least 1 frame (1: every image)")
        if not 1 <= self.jpeg_quality <= 100:
            raise ConfigError(f"rerun.jpeg_quality={self.jpeg_quality} must be between 1 and 100")
