"""``zenslam run`` with saved maps: ``--save-map``, ``--map`` and ``--localization`` resolved into the stages' configuration.

``--map FILE`` is checked before any stage starts: the file's format version, its camera against
the source's and its vocabulary against the run's (``backend.map_file`` documents the format).
The backend then starts from the map, the frontend starts lost and relocalises into it, and the
frontend's keyframe and point ids start past the map's (its header's ``next_ids``), so nothing
the run makes collides with a saved id. ``--localization`` adds ORB-SLAM's localisation mode.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

from zenslam.backend.map_file import MapHeader, check_compatible, read_header
from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.errors import ConfigError
from zenslam.frontend.config import entering_map
from zenslam.service.run_config import RunConfig

logger = logging.getLogger(__name__)


def with_map_options(config: RunConfig, load: Path | None, save: Path | None, localization: bool) -> RunConfig:
    """``config`` with the saved-map options: paths made absolute (the stages run elsewhere), the
    frontend told to start in the map (and its id spaces moved past the map's), localisation mode."""
    backend, frontend = config.backend, config.frontend
    if localization and not (load or backend.map_file):
        raise ConfigError("--localization tracks against a saved map: give it with --map FILE")
    if save is not None:
        backend = dataclasses.replace(backend, save_map=str(Path(save).expanduser().resolve()))
    if load is not None:
        backend = dataclasses.replace(backend, map_file=str(Path(load).expanduser().resolve()))
    if backend.map_file:
        header = read_header(backend.map_file)
        frontend = entering_map(frontend, header.next_keyframe_id, header.next_frontend_point_id)
    if localization:
        frontend = dataclasses.replace(frontend, tracking=dataclasses.replace(frontend.tracking, localization=True))
    return dataclasses.replace(config, backend=backend, frontend=frontend)


def check_map_fits(config: RunConfig, calibration: PinholeCalibration | None, sensor: SensorKind | None) -> MapHeader | None:
    """The header of the run's saved map (None without one), after checking that it was made with
    this camera and the run's vocabularies (MapFileError naming both otherwise). A camera not known
    before the first frame (None: frames from the bus) is checked by the backend at its first keyframe."""
    if not config.backend.map_file:
        return None
    from zenslam.vocabulary import load_vocabulary

    header = read_header(config.backend.map_file)
    paths = {config.backend.vocabulary or None, config.frontend.vocabulary or None}
    for path in sorted(paths, key=str):
        vocabulary = load_vocabulary(path)
        check_compatible(header, calibration, sensor, vocabulary.content_id, vocabulary.source)
    logger.info(
        "starting from the map %s: %d keyframes, %d points (%s)",
        header.path, header.counts.get("keyframes", 0), header.counts.get("points", 0), header.camera_text(),
    )  # fmt: skip
    return header
