"""What a run's figures depend on besides its input and configuration: the interpreter, the machine
and the versions of the libraries that compute them (metrics.json's ``run.environment``).

Lockstep output has the same bits on any x86-64 CPU (``cpu_kernels``), but only for the same library
versions, and the figures can move with them: when the synthetic scenes were rendered through
OpenCV's ``warpPerspective``, which OpenCV 5.0 rounds differently from 4.14, that alone changed the
synthetic loop's map enough that the figure-eight's first frame no longer relocalised into it
(benchmarks/saved_maps.md); their texture sampling is now exact IEEE arithmetic
(``sources/synthetic/tile_raster``), the same on every install. A figure read from a run
folder still names the versions that made it.
"""

from __future__ import annotations

import os
import platform
from importlib import metadata

# Distributions whose versions can change a run's output or its speed, as pip names them. OpenCV
# ships under four names; whichever is installed is listed.
DISTRIBUTIONS = (
    "zenslam",
    "numpy",
    "opencv-python-headless",
    "opencv-python",
    "opencv-contrib-python-headless",
    "opencv-contrib-python",
    "gtsam",
    "eclipse-zenoh",
    "mcap",
    "rerun-sdk",
    "evo",
)


def library_versions(names: tuple[str, ...] = DISTRIBUTIONS) -> dict[str, str]:
    """Installed version of each of ``names`` (distribution name -> version), absent ones left out."""
    versions = {}
    for name in names:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return versions


def describe() -> dict[str, object]:
    """The interpreter, the machine and the library versions, as JSON-ready values."""
    return {
        "python": platform.python_version(),
        "machine": platform.machine(),
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
        "libraries": library_versions(),
    }
