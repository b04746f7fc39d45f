"""Saved maps: the backend's map in one file (``zenslam run --save-map``), read back by ``--map``.

Format ``zenslam-map``, version 1. The file is a ZIP archive (stored, not compressed) of

- ``header.json``: UTF-8 JSON, the first member::

      {"format": "zenslam-map", "version": 1, "zenslam_version": "0.1.0",
       "camera": {"sensor": "stereo", "fx": .., "fy": .., "cx": .., "cy": .., "width": .., "height": ..,
                  "baseline_m": .. or null},
       "vocabulary": {"id": "sha256:<hex>", "words": 99944, "source": "<file it was read from>"},
       "counts": {"keyframes": K, "keypoints": N, "points": P, "observations": O, ...},
       "map": {"first_keyframe_id": .., "next_serial": ..},
       "next_ids": {"keyframe": .., "frontend_point": .., "backend_point": ..},
       "arrays": {"<name>": {"dtype": "<f8", "shape": [..]}, ...}}

- one ``<name>.npy`` per array (NumPy's .npy format, little-endian numbers, never object arrays:
  ``numpy.load(member, allow_pickle=False)`` reads each; nothing in the file is code).

Poses are ``T_world_cam`` (4 x 4, camera x right, y down, z forward, to world; metres). Ragged
data is flattened with an offsets array of count + 1 entries: item ``i`` of ``values`` is
``values[offsets[i]:offsets[i + 1]]``. The arrays (K keyframes in insertion order, N keypoints,
P points, O observations, C culled keyframes):

================================  ===========  ===================================================
``keyframe_ids``                  (K,) i8      keyframe ids
``keyframe_stamps_ns``            (K,) i8      capture stamps, nanoseconds
``keyframe_serials``              (K,) i8      insertion order in the map that made them
``keyframe_T_world_cam``          (K,4,4) f8   poses
``keyframe_keypoint_offsets``     (K+1,) i8    each keyframe's rows of the ``keypoint*`` arrays
``keyframe_scale_offsets``        (K+1,) i8    each keyframe's rows of ``keyframe_scale_factors``
``keyframe_scale_factors``        (.,) f8      scale of each pyramid level (scale_factor ** level)
``keypoints_px``                  (N,2) f8     level-0 pixel coordinates (u, v)
``keypoint_levels``               (N,) i8      pyramid level
``keypoint_angles_deg``           (N,) f8      ORB orientation, degrees
``keypoint_right_u``              (N,) f8      right-image u, pixels (stereo; RGB-D virtual), -1 none
``keypoint_depth_m``              (N,) f8      depth, metres, -1 none
``keypoint_descriptors``          (N,32) u1    ORB descriptors (256 bits)
``keypoint_map_point_ids``        (N,) i8      the point each keypoint observes, -1 none
``point_ids``                     (P,) i8      point ids (from 2**62 up: made by the backend)
``point_p_world``                 (P,3) f8     positions, metres, world frame
``point_first_keyframe_ids``      (P,) i8      the keyframe that created each point
``point_created_serials``         (P,) i8      newest keyframe serial when it was created
``point_descriptors``             (P,32) u1    representative descriptors
``point_normals``                 (P,3) f8     mean viewing directions (unit, world)
``point_min_distance_m``          (P,) f8      scale-invariance distances, metres
``point_max_distance_m``          (P,) f8
``point_n_visible``               (P,) i8      keyframes whose frustum held the point
``point_n_found``                 (P,) i8      ... that observed it
``point_observation_offsets``     (P+1,) i8    each point's rows of the ``observation_*`` arrays
``observation_keyframe_ids``      (O,) i8      observing keyframe (mirrors ``keypoint_map_point_ids``)
``observation_keypoints``         (O,) i8      keypoint index in that keyframe
``covisibility_weights``          (.,3) i8     (a, b, shared points), a < b, every pair sharing one
``spanning_tree_parents``         (K,) i8      parent keyframe id, -1 for the root (first keyframe)
``loop_edges``                    (.,2) i8     closed loops (a, b), a < b
``culled_keyframe_ids``           (C,) i8      keyframes culled from the map ...
``culled_stamps_ns``              (C,) i8      ... their stamps,
``culled_parent_ids``             (C,) i8      ... their spanning-tree parent then,
``culled_T_parent_cam``           (C,4,4) f8   ... and their pose in that parent's frame
``fused_point_ids``               (.,2) i8     (fused-away id, the id that replaced it)
``bow_offsets``                   (K+1,) i8    each keyframe's rows of ``bow_*``
``bow_word_ids``, ``bow_weights`` i8, f8       bag-of-words vectors (TF-IDF, L1-normalised)
``feature_vector_offsets``        (K+1,) i8    each keyframe's rows of ``feature_vector_node_ids``
``feature_vector_node_ids``       (.,) i8      vocabulary nodes (direct index, DBoW2's FeatureVector)
``feature_vector_group_offsets``  (.+1,) i8    each node's rows of ``feature_vector_keypoints``
``feature_vector_keypoints``      (.,) i8      keypoint indices under that node
================================  ===========  ===================================================

A map is valid only with the camera and the vocabulary that made it: ``check_compatible`` refuses
another format version, camera or vocabulary. ``next_ids`` are the first keyframe id and point
ids a run that continues the map uses, so nothing it makes collides with the saved ids.
"""

from __future__ import annotations

import json
import logging
import math
import os
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from zenslam.backend.map import BackendMap
from zenslam.backend.map_arrays import KEYPOINT_COLUMNS, map_from_arrays, map_to_arrays
from zenslam.backend.place_recognition import PlaceRecognition
from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.errors import ZenslamError

logger = logging.getLogger(__name__)

FORMAT = "zenslam-map"
VERSION = 1
HEADER_NAME = "header.json"
_CALIBRATION_FIELDS = ("fx", "fy", "cx", "cy", "width", "height", "baseline_m")


class MapFileError(ZenslamError):
    """A saved map cannot be read, or does not fit this run (format version, camera, vocabulary)."""


@dataclass(frozen=True)
class MapHeader:
    """What ``header.json`` says (see the module doc)."""

    path: str
    version: int
    sensor: SensorKind
    calibration: PinholeCalibration
    vocabulary_id: str
    vocabulary_source: str
    counts: dict[str, int]
    first_keyframe_id: int | None
    next_serial: int
    next_keyframe_id: int
    next_frontend_point_id: int
    next_backend_point_id: int
    arrays: dict[str, dict[str, Any]]

    def camera_text(self) -> str:
        return f"{self.sensor} camera {self.calibration.summary()}"


def _camera_json(calibration: PinholeCalibration, sensor: SensorKind) -> dict[str, Any]:
    return {"sensor": sensor, **{name: getattr(calibration, name) for name in _CALIBRATION_FIELDS}}


def _member(name: str) -> zipfile.ZipInfo:
    """A member stamped 1980-01-01 (ZIP's epoch), so that the same map gives the same file bytes."""
    return zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))


def save_map(path: str | Path, bmap: BackendMap, places: PlaceRecognition, zenslam_version: str = "") -> MapHeader:
    """Write ``bmap`` and its place recognition's vectors to ``path`` (written to a temporary file
    beside it, then renamed: a reader never sees half a map). Refreshes stale point attributes first."""
    if not bmap.keyframes:
        raise MapFileError(f"the map has no keyframe: nothing to save to {path}")
    first = next(iter(bmap.keyframes.values()))
    bmap.refresh_points()
    arrays = map_to_arrays(bmap, places)
    header = {
        "format": FORMAT,
        "version": VERSION,
        "zenslam_version": zenslam_version,
        "camera": _camera_json(first.calibration, first.sensor),
        "vocabulary": {"id": places.vocabulary.content_id, "words": places.vocabulary.n_words, "source": places.vocabulary.source},
        "counts": {
            "keyframes": len(bmap.keyframes), "keypoints": len(arrays["keypoints_px"]), "points": len(bmap.points),
            "observations": len(arrays["observation_keypoints"]), "culled_keyframes": len(arrays["culled_keyframe_ids"]),
            "loop_edges": len(arrays["loop_edges"]),
        },  # fmt: skip
        "map": {"first_keyframe_id": bmap.first_keyframe_id, "next_serial": bmap.next_serial},
        "next_ids": bmap.next_ids(),
        "arrays": {name: {"dtype": a.dtype.str, "shape": list(a.shape)} for name, a in arrays.items()},
    }
    target = Path(path).expanduser()
    temporary = target.with_name(target.name + ".partial")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        with zipfile.ZipFile(temporary, "w", compression=zipfile.ZIP_STORED, allowZip64=True) as archive:
            archive.writestr(_member(HEADER_NAME), json.dumps(header, indent=1))
            for name, array in arrays.items():
                with archive.open(_member(f"{name}.npy"), "w", force_zip64=array.nbytes > (1 << 30)) as member:
                    np.lib.format.write_array(member, np.ascontiguousarray(array), allow_pickle=False)
        os.replace(temporary, target)
    except OSError as exc:
        raise MapFileError(f"cannot write the map to {target}: {exc.strerror or exc}") from None
    logger.info("saved the map (%d keyframes, %d points) to %s", len(bmap.keyframes), len(bmap.points), target)
    return _header_from_json(header, str(target))


def _open(path: str | Path) -> zipfile.ZipFile:
    file = Path(path).expanduser()
    try:
        return zipfile.ZipFile(file)
    except FileNotFoundError:
        raise MapFileError(f"map {file} does not exist: name a file written by 'zenslam run ... --save-map'") from None
    except (zipfile.BadZipFile, OSError) as exc:
        raise MapFileError(f"map {file} is not a zenslam map (not a ZIP archive: {exc}); name a file written by --save-map") from None


def read_header(path: str | Path) -> MapHeader:
    """The header of the map file ``path`` (its arrays are not read); MapFileError when it is not a
    zenslam map or of another format version."""
    with _open(path) as archive:
        return _read_header(archive, str(path))


def _read_header(archive: zipfile.ZipFile, path: str) -> MapHeader:
    try:
        data = json.loads(archive.read(HEADER_NAME).decode("utf-8"))
    except KeyError:
        raise MapFileError(f"map {path} has no {HEADER_NAME}: it is not a zenslam map") from None
    except (UnicodeDecodeError, json.JSONDecodeError, zipfile.BadZipFile) as exc:
        raise MapFileError(f"map {path}: {HEADER_NAME} cannot be read ({exc}); the file is corrupt") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        found = data.get("format") if isinstance(data, dict) else type(data).__name__
        raise MapFileError(f"map {path} has format {found!r}, not {FORMAT!r}: it is not a zenslam map")
    if data.get("version") != VERSION:
        raise MapFileError(
            f"map {path} is {FORMAT} version {data.get('version')!r} but this zenslam reads version {VERSION}: "
            f"use the zenslam version that wrote it ({data.get('zenslam_version') or 'unknown'}), or make the map again"
        )
    try:
        return _header_from_json(data, path)
    except (KeyError, TypeError, ValueError, ZenslamError) as exc:
        raise MapFileError(f"map {path}: {HEADER_NAME} is incomplete or malformed ({type(exc).__name__}: {exc})") from None


def _header_from_json(data: dict[str, Any], path: str) -> MapHeader:
    camera, vocabulary, next_ids = data["camera"], data["vocabulary"], data["next_ids"]
    calibration = PinholeCalibration(
        float(camera["fx"]), float(camera["fy"]), float(camera["cx"]), float(camera["cy"]), int(camera["width"]),
        int(camera["height"]), None if camera["baseline_m"] is None else float(camera["baseline_m"]),
    )  # fmt: skip
    if camera["sensor"] not in ("mono", "stereo", "rgbd"):
        raise ValueError(f"camera sensor {camera['sensor']!r} is not mono, stereo or rgbd")
    return MapHeader(
        path=path,
        version=int(data["version"]),
        sensor=camera["sensor"],
        calibration=calibration,
        vocabulary_id=str(vocabulary["id"]),
        vocabulary_source=str(vocabulary.get("source", "")),
        counts={str(k): int(v) for k, v in data["counts"].items()},
        first_keyframe_id=data["map"]["first_keyframe_id"],
        next_serial=int(data["map"]["next_serial"]),
        next_keyframe_id=int(next_ids["keyframe"]),
        next_frontend_point_id=int(next_ids["frontend_point"]),
        next_backend_point_id=int(next_ids["backend_point"]),
        arrays=dict(data["arrays"]),
    )


def _same_calibration(a: PinholeCalibration, b: PinholeCalibration) -> bool:
    if (a.width, a.height) != (b.width, b.height) or (a.baseline_m is None) != (b.baseline_m is None):
        return False
    pairs = [(getattr(a, n), getattr(b, n)) for n in ("fx", "fy", "cx", "cy", "baseline_m") if getattr(a, n) is not None]
    return all(math.isclose(x, y, rel_tol=1e-9, abs_tol=1e-9) for x, y in pairs)


def check_compatible(
    header: MapHeader, calibration: PinholeCalibration | None, sensor: SensorKind | None, vocabulary_id: str,
    vocabulary_source: str = "",
) -> None:
    """MapFileError when the map was made with another camera or vocabulary than this run's, naming both.
    A camera not known yet (None: frames from the bus) is checked by the backend at its first keyframe."""
    other_sensor = sensor is not None and sensor != header.sensor
    if other_sensor or (calibration is not None and not _same_calibration(calibration, header.calibration)):
        camera = f"{sensor or header.sensor} camera " + (calibration.summary() if calibration is not None else "")
        raise MapFileError(
            f"map {header.path} was made with a {header.camera_text()}, but this run's is a {camera.strip()}: "
            "a map holds only for the camera that made it; run the map's camera "
            "(its calibration: --orbslam-settings; its sensor: --sensor) or make a new map with --save-map"
        )
    if vocabulary_id != header.vocabulary_id:
        raise MapFileError(
            f"map {header.path} was made with vocabulary {header.vocabulary_id} ({header.vocabulary_source or 'unknown file'}), "
            f"but this run uses {vocabulary_id} ({vocabulary_source or 'unknown file'}): its bags of words mean nothing "
            "under another vocabulary; set backend.vocabulary and frontend.vocabulary to the map's, or make a new map"
        )


def _read_arrays(archive: zipfile.ZipFile, header: MapHeader) -> dict[str, np.ndarray]:
    """Every array the header lists, each checked against its stated dtype and shape."""
    needed = set(map_array_names())
    missing = sorted(needed - set(header.arrays))
    if missing:
        raise MapFileError(f"map {header.path} lacks the arrays {missing}: the file is incomplete")
    arrays: dict[str, np.ndarray] = {}
    for name in sorted(needed):
        try:
            with archive.open(f"{name}.npy") as member:
                array = np.lib.format.read_array(member, allow_pickle=False)
        except (KeyError, ValueError, OSError, zipfile.BadZipFile, EOFError) as exc:
            raise MapFileError(f"map {header.path}: array {name} cannot be read ({exc}); the file is corrupt") from None
        stated = header.arrays[name]
        if array.dtype.str != stated.get("dtype") or list(array.shape) != list(stated.get("shape", [])):
            raise MapFileError(
                f"map {header.path}: array {name} is {array.dtype.str} {list(array.shape)} but the header says "
                f"{stated.get('dtype')} {stated.get('shape')}; the file is corrupt"
            )
        arrays[name] = array
    _check_lengths(arrays, header.path)
    return arrays


def map_array_names() -> list[str]:
    """The names of a version-1 map's arrays."""
    return [
        "keyframe_ids", "keyframe_stamps_ns", "keyframe_serials", "keyframe_T_world_cam", "keyframe_keypoint_offsets",
        "keyframe_scale_offsets", "keyframe_scale_factors", *KEYPOINT_COLUMNS, "point_ids", "point_p_world",
        "point_first_keyframe_ids", "point_created_serials", "point_descriptors", "point_normals", "point_min_distance_m",
        "point_max_distance_m", "point_n_visible", "point_n_found", "point_observation_offsets",
        "observation_keyframe_ids", "observation_keypoints", "covisibility_weights", "spanning_tree_parents",
        "loop_edges", "culled_keyframe_ids", "culled_stamps_ns", "culled_parent_ids", "culled_T_parent_cam",
        "fused_point_ids", "bow_offsets", "bow_word_ids", "bow_weights", "feature_vector_offsets",
        "feature_vector_node_ids", "feature_vector_group_offsets", "feature_vector_keypoints",
    ]  # fmt: skip


def _check_lengths(a: dict[str, np.ndarray], path: str) -> None:
    """Offsets that end where their values do; per-keyframe and per-point arrays of one length."""
    k, p = len(a["keyframe_ids"]), len(a["point_ids"])
    ragged = {
        "keyframe_keypoint_offsets": (k, len(a["keypoints_px"])),
        "keyframe_scale_offsets": (k, len(a["keyframe_scale_factors"])),
        "point_observation_offsets": (p, len(a["observation_keypoints"])),
        "bow_offsets": (k, len(a["bow_word_ids"])),
        "feature_vector_offsets": (k, len(a["feature_vector_node_ids"])),
        "feature_vector_group_offsets": (len(a["feature_vector_node_ids"]), len(a["feature_vector_keypoints"])),
    }
    problems = []
    for name, (count, total) in ragged.items():
        offsets = a[name]
        if len(offsets) != count + 1 or offsets[0] != 0 or offsets[-1] != total or np.any(np.diff(offsets) < 0):
            problems.append(f"{name} does not cut {total} rows into {count} items")
    same_length = {name: k for name in ("keyframe_stamps_ns", "keyframe_serials", "keyframe_T_world_cam", "spanning_tree_parents")}
    same_length.update({name: p for name in map_array_names() if name.startswith("point_") and name != "point_observation_offsets"})
    same_length.update({name: len(a["keypoints_px"]) for name in KEYPOINT_COLUMNS})
    same_length.update({"bow_weights": len(a["bow_word_ids"]), "observation_keyframe_ids": len(a["observation_keypoints"])})
    for name, count in same_length.items():
        if len(a[name]) != count:
            problems.append(f"{name} has {len(a[name])} rows for {count} items")
    if problems:
        raise MapFileError(f"map {path} is inconsistent: {'; '.join(problems)}; the file is corrupt")


def load_map(
    path: str | Path, bmap: BackendMap, places: PlaceRecognition, calibration: PinholeCalibration | None = None,
    sensor: SensorKind | None = None,
) -> MapHeader:
    """Fill the empty ``bmap`` and ``places`` with the map in ``path``. Refused (MapFileError) when
    the file is not a version-1 zenslam map, was made with another vocabulary than ``places``', or,
    when ``calibration`` and ``sensor`` are given, with another camera."""
    if bmap.keyframes or bmap.points:
        raise MapFileError(f"a map is loaded into an empty backend map, this one has {len(bmap.keyframes)} keyframes")
    started = time.perf_counter()
    with _open(path) as archive:
        header = _read_header(archive, str(path))
        check_compatible(
            header, calibration if calibration is not None else header.calibration, sensor or header.sensor,
            places.vocabulary.content_id, places.vocabulary.source,
        )  # fmt: skip
        arrays = _read_arrays(archive, header)
    try:
        map_from_arrays(arrays, bmap, places, header.calibration, header.sensor, header.next_serial, header.next_backend_point_id)
    except (KeyError, IndexError, ValueError, ZenslamError) as exc:
        raise MapFileError(f"map {path} is inconsistent ({type(exc).__name__}: {exc}); the file is corrupt") from None
    logger.info(
        "loaded the map %s: %d keyframes, %d points in %.2f s",
        path, len(bmap.keyframes), len(bmap.points), time.perf_counter() - started,
    )  # fmt: skip
    return header
