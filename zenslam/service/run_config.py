"""The configuration of one run: a YAML file with one section per stage, and ORB-SLAM3 settings files.

``load_run_config`` reads the YAML (the run ``mode``, the ``map`` rules both stages share, and one
section per stage: ``bus``, ``source``, ``frontend``, ``backend``, ``rerun``, ``evaluation``,
``recorder``; unknown keys are an error). Each stage's section is defined with its stage; a stage
process reads only its own sections of the resolved file (``runtime.stage.load_section``), so the
``map`` section is copied into the frontend's and the backend's sections (``with_map_rules``).

``read_orbslam_settings`` reads an ORB-SLAM3 (or ORB-SLAM2) settings file with OpenCV's FileStorage,
and ``apply_orbslam_settings`` makes its rectified calibration override the source's and its
ORB/threshold values override the frontend's, so users can bring their existing files.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from zenslam.backend.config import MAP_RULES_PATH as BACKEND_MAP_RULES_PATH
from zenslam.backend.config import BackendConfig
from zenslam.camera import PinholeCalibration
from zenslam.config import from_mapping, load_yaml, to_mapping
from zenslam.errors import CalibrationError, ConfigError
from zenslam.frontend.config import MAP_RULES_PATH as FRONTEND_MAP_RULES_PATH
from zenslam.frontend.config import FrontendConfig
from zenslam.map_rules_config import MapRulesConfig
from zenslam.runtime.bus import BusConfig
from zenslam.runtime.rerun_config import RerunConfig
from zenslam.runtime.stage import RunMode
from zenslam.runtime.supervisor import SupervisionConfig
from zenslam.service.evaluation.metrics import EvaluationConfig
from zenslam.service.recorder_config import RecorderConfig
from zenslam.service.sources.config import SourceConfig

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class RunConfig:
    """Everything a run needs, one section per stage; written resolved next to the run's outputs."""

    mode: RunMode = "lockstep"  # how the stages are paced: lockstep | pipelined | live (runtime.stage.RunMode)
    # The map rules both stages apply; the frontend and backend sections carry copies (``with_map_rules``).
    map: MapRulesConfig = field(default_factory=MapRulesConfig)
    bus: BusConfig = field(default_factory=BusConfig)
    source: SourceConfig = field(default_factory=SourceConfig)
    frontend: FrontendConfig = field(default_factory=FrontendConfig)
    backend: BackendConfig = field(default_factory=BackendConfig)
    rerun: RerunConfig = field(default_factory=RerunConfig)
    # Monocular runs are compared after a Sim(3) alignment whatever ``alignment`` says (no metric scale).
    evaluation: EvaluationConfig = field(default_factory=EvaluationConfig)
    recorder: RecorderConfig = field(default_factory=RecorderConfig)
    supervision: SupervisionConfig = field(default_factory=SupervisionConfig)

    def __post_init__(self) -> None:
        for section, path in _MAP_RULES_COPIES.items():
            copy = functools.reduce(getattr, path, getattr(self, section))
            if copy != self.map:
                raise ConfigError(
                    f"{_dotted(section, *path)}={copy} differs from map={self.map}: it is the {section}'s copy of the "
                    "map section; set the map section (run_config.with_map_rules) instead"
                )


# The copies of the ``map`` section in the stages' sections, which stage processes read.
_MAP_RULES_COPIES = {"frontend": FRONTEND_MAP_RULES_PATH, "backend": BACKEND_MAP_RULES_PATH}


def with_map_rules(config: RunConfig, rules: MapRulesConfig) -> RunConfig:
    """``config`` with the map rules ``rules``, in its ``map`` section and in the stages' copies."""
    stages = {section: _replaced(getattr(config, section), path, rules) for section, path in _MAP_RULES_COPIES.items()}
    return dataclasses.replace(config, map=rules, **stages)


def _replaced(obj: Any, path: tuple[str, ...], value: Any) -> Any:
    """The frozen dataclass ``obj`` with the field at ``path`` (names, outermost first) set to ``value``."""
    inner = value if len(path) == 1 else _replaced(getattr(obj, path[0]), path[1:], value)
    return dataclasses.replace(obj, **{path[0]: inner})


def _dotted(*names: str) -> str:
    return ".".join(names)


def load_run_config(path: str | Path | None) -> RunConfig:
    """The run configuration in the YAML file ``path`` (defaults for missing keys), or all defaults for None.

    Files written before the run mode and the per-stage sections (``source.lockstep``,
    ``backend.wait_for_map_updates`` and the keys of ``_MOVED_KEYS``), or before the ``map`` section,
    are read with a warning. The stages' copies of the ``map`` section are filled from it.
    """
    if path is None:
        return RunConfig()
    data = _upgrade_earlier_keys(load_yaml(Path(path)), Path(path))
    return from_mapping(RunConfig, _with_map_rules_copies(data, Path(path)), "")


# Keys of earlier configuration files and where they live now: (section, key) -> (section, key).
_MOVED_KEYS = {
    ("source", "start_timeout_s"): ("bus", "start_timeout_s"),
    ("backend", "map_update_queue"): ("frontend", "map_update_queue"),
    ("backend", "update_timeout_s"): ("frontend", "update_timeout_s"),
}


def _upgrade_earlier_keys(data: dict[str, Any], path: Path) -> dict[str, Any]:
    """``data`` with the keys of earlier files moved to their place today, and those without a place
    dropped, each with a warning (a copy; ``data`` is kept)."""
    data = {k: dict(v) if isinstance(v, dict) else v for k, v in data.items()}
    moved: list[str] = []
    source, backend = data.get("source"), data.get("backend")
    lockstep = source.pop("lockstep", None) if isinstance(source, dict) else None
    waits = backend.pop("wait_for_map_updates", None) if isinstance(backend, dict) else None
    if lockstep is not None or waits is not None:
        moved.append("source.lockstep/backend.wait_for_map_updates -> mode")
        if "mode" not in data:
            data["mode"] = "live" if lockstep is False else "pipelined" if waits is False else "lockstep"
    for (section, key), (new_section, new_key) in _MOVED_KEYS.items():
        old = data.get(section)
        if isinstance(old, dict) and key in old:
            moved.append(f"{section}.{key} -> {new_section}.{new_key}")
            data.setdefault(new_section, {}).setdefault(new_key, old.pop(key))
    moved += _move_map_rules(data, path)
    if moved:
        logger.warning("%s uses keys of an earlier zenslam, read as: %s", path, "; ".join(moved))
    local_map = _section(data, _LOCAL_MAP) or {}
    dropped = [key for key in _FRONTEND_CULLING_KEYS if key in local_map]
    for key in dropped:
        del local_map[key]
    if dropped:
        logger.warning(
            "%s: %s dropped: the frontend no longer culls map points, the backend culls them (backend.point_culling)",
            path, ", ".join(_dotted(*_LOCAL_MAP, key) for key in dropped),
        )  # fmt: skip
    return data


# Earlier files set the covisibility threshold once per stage; it is the ``map`` section's now.
_LOCAL_MAP = ("frontend", "tracking", "local_map")
_EARLIER_MAP_RULES_SECTIONS = (_LOCAL_MAP, ("backend", "local_mapping"))
_MAP_RULES_KEY = "min_covisibility_weight"
# Keys of the frontend's recent-point culling in earlier files; the backend's map owns its points.
_FRONTEND_CULLING_KEYS = ("cull_recent_points", "cull_min_found_ratio", "cull_min_keyframe_observations", "cull_window_keyframes")


def _move_map_rules(data: dict[str, Any], path: Path) -> list[str]:
    """Move the earlier per-stage ``min_covisibility_weight`` keys of ``data`` to ``map``; the moves
    made, as "old -> new". Values that disagree (with each other or with ``map``) are a ConfigError."""
    new_key = _dotted("map", _MAP_RULES_KEY)
    given: dict[str, Any] = {}
    for names in _EARLIER_MAP_RULES_SECTIONS:
        section = _section(data, names)
        if section is not None and _MAP_RULES_KEY in section:
            given[_dotted(*names, _MAP_RULES_KEY)] = section.pop(_MAP_RULES_KEY)
    if not given:
        return []
    rules = _section(data, ("map",), create=True)
    if rules is None:
        raise ConfigError(f"{path}: map={data['map']!r} must be a mapping")
    if _MAP_RULES_KEY in rules:
        given[new_key] = rules[_MAP_RULES_KEY]
    if len({repr(v) for v in given.values()}) > 1:
        raise ConfigError(
            f"{path}: {' and '.join(f'{k}={v!r}' for k, v in given.items())} disagree; the covisibility threshold is "
            f"one setting now: give {new_key} alone"
        )
    rules[_MAP_RULES_KEY] = next(iter(given.values()))
    return [f"{old} -> {new_key}" for old in given if old != new_key]


def _with_map_rules_copies(data: dict[str, Any], path: Path) -> dict[str, Any]:
    """``data`` with the stages' copies of the ``map`` section set to it; a copy the file gives
    that differs from ``map`` is a ConfigError (the copies are written by zenslam, not set by hand)."""
    rules = from_mapping(MapRulesConfig, data.get("map"), "map")
    for section, names in _MAP_RULES_COPIES.items():
        *parents, leaf = (section, *names)
        given = (_section(data, tuple(parents)) or {}).get(leaf)
        copy = None if given is None else from_mapping(MapRulesConfig, given, _dotted(section, *names))
        # A copy at the defaults or at ``map`` is zenslam's (a written config.yaml whose map section was
        # edited holds the old copies): filled from ``map``. Any other was set by hand.
        if copy is not None and copy not in (rules, MapRulesConfig()):
            raise ConfigError(
                f"{path}: {_dotted(section, *names)}={given!r} differs from map={data.get('map')!r}: it is the "
                f"{section}'s copy of the map section, filled from it; set map alone"
            )
        target = _section(data, tuple(parents), create=True)
        if target is None:
            raise ConfigError(f"{path}: {_dotted(*parents)} must be a mapping")
        target[leaf] = to_mapping(rules)
    return data


def _section(data: dict[str, Any], names: tuple[str, ...], create: bool = False) -> dict[str, Any] | None:
    """The mapping at ``names`` in ``data``, copied on the way so that no mapping ``data`` shares
    with its caller's is changed; None when one on the way is missing (and not ``create``d) or not a mapping."""
    node = data
    for name in names:
        child = node.get(name)
        if child is None and create:
            child = {}
        if not isinstance(child, dict):
            return None
        node[name] = child = dict(child)
        node = child
    return node


def run_config_to_yaml(config: RunConfig) -> str:
    """The YAML text of ``config`` (load_run_config reads it back to an equal config)."""
    import yaml

    return yaml.safe_dump(to_mapping(config), sort_keys=False)


@dataclass(frozen=True)
class OrbSlamSettings:
    """What zenslam takes from an ORB-SLAM2/3 settings file; None where the file does not say."""

    calibration: PinholeCalibration  # rectified intrinsics (and baseline for stereo/RGB-D)
    fps: float | None = None  # Camera.fps, frames per second
    th_depth: float | None = None  # ThDepth / Stereo.ThDepth: close/far threshold, in baselines
    depth_map_factor: float | None = None  # DepthMapFactor / RGBD.DepthMapFactor: depth image units per metre
    orb: dict[str, float] = field(default_factory=dict)  # OrbConfig field -> value from ORBextractor.*


# ORB-SLAM settings key -> OrbConfig field.
_ORB_KEYS = {
    "ORBextractor.nFeatures": ("n_features", int),
    "ORBextractor.scaleFactor": ("scale_factor", float),
    "ORBextractor.nLevels": ("n_levels", int),
    "ORBextractor.iniThFAST": ("ini_fast_threshold", int),
    "ORBextractor.minThFAST": ("min_fast_threshold", int),
}


def _read_node(fs: cv2.FileStorage, path: Path, *names: str) -> Any:
    """The first of ``names`` present in the file: a float, a string, or a matrix; None if none is.

    ConfigError naming the key when its value is none of those (a sequence, or a mapping that is
    not an ``!!opencv-matrix``).
    """
    for name in names:
        node = fs.getNode(name)
        if node.empty() or node.isNone():
            continue
        if node.isString():
            return node.string()
        if node.isMap():
            try:
                return node.mat()
            except (cv2.error, SystemError) as exc:  # SystemError: how the cv2 bindings relay some cv2.errors
                raise ConfigError(
                    f"ORB-SLAM settings file {path}: {name} is a mapping but not an !!opencv-matrix "
                    "(rows, cols, dt, data); give a number or a matrix"
                ) from exc
        if node.isSeq():
            raise ConfigError(f"ORB-SLAM settings file {path}: {name} is a list; give a number or an !!opencv-matrix")
        return node.real()
    return None


def _read_number(fs: cv2.FileStorage, path: Path, *names: str) -> float | None:
    """The first of ``names`` present in the file as a float; None if none is; ConfigError if it is not a number."""
    for name in names:
        value = _read_node(fs, path, name)
        if value is None:
            continue
        if not isinstance(value, float):
            shown = repr(value) if isinstance(value, str) else f"a {value.shape[0]}x{value.shape[1]} matrix"
            raise ConfigError(f"ORB-SLAM settings file {path}: {name} is {shown}; it must be a number")
        return value
    return None


def _open_settings(path: Path) -> cv2.FileStorage:
    """``path`` opened with OpenCV's FileStorage; ConfigError naming the file when it is not an OpenCV YAML file."""
    what_to_do = "pass an ORB-SLAM2/3 settings file (OpenCV YAML, starting with %YAML:1.0) to --orbslam-settings"
    if not path.exists():
        raise ConfigError(f"ORB-SLAM settings file {path} does not exist; {what_to_do}")
    if not path.is_file():
        raise ConfigError(f"ORB-SLAM settings file {path} is not a file; {what_to_do}")
    if path.stat().st_size == 0:
        raise ConfigError(f"ORB-SLAM settings file {path} is empty; {what_to_do}")
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_FORMAT_YAML)
    except (cv2.error, SystemError) as exc:  # the bindings raise SystemError with the cv2.error as its cause
        raise ConfigError(
            f"ORB-SLAM settings file {path} is not an OpenCV YAML file{_parse_error(exc, path)}; {what_to_do}"
        ) from exc
    if not fs.isOpened():
        raise ConfigError(f"ORB-SLAM settings file {path} cannot be opened as an OpenCV YAML file; {what_to_do}")
    return fs


def _parse_error(exc: BaseException, path: Path) -> str:
    """`` (line N: what)`` from OpenCV's parsing error behind ``exc``, or "" when it is another error."""
    import re

    cause = exc if isinstance(exc, cv2.error) else exc.__cause__ or exc.__context__
    match = re.search(r"Parsing error\) \w+ in function '.*\((\d+)\): (.*)'", str(cause or ""))
    return f" (line {match.group(1)}: {match.group(2).strip()})" if match else ""


def read_orbslam_settings(path: str | Path) -> OrbSlamSettings:
    """Read an ORB-SLAM2 (``Camera.fx``) or ORB-SLAM3 (``Camera1.fx``, ``File.version``) settings file.

    The calibration must describe rectified images, as zenslam's sources deliver them: either the
    ``Camera`` intrinsics with zero distortion, or the stereo rectification ``LEFT.P``/``RIGHT.P``.
    The baseline comes from ``Stereo.b`` (metres), ``Camera.bf`` (metres x fx) or ``RIGHT.P``.
    ConfigError names the file when it is missing or not an OpenCV YAML file, and the key whose
    value is not what it must be.
    """
    path = Path(path)
    fs = _open_settings(path)
    try:
        calibration = _read_calibration(fs, path)
        orb = {}
        for key, (name, kind) in _ORB_KEYS.items():
            value = _read_number(fs, path, key)
            if value is not None:
                orb[name] = kind(value)
        return OrbSlamSettings(
            calibration=calibration,
            fps=_read_number(fs, path, "Camera.fps"),
            th_depth=_read_number(fs, path, "Stereo.ThDepth", "ThDepth"),
            depth_map_factor=_read_number(fs, path, "RGBD.DepthMapFactor", "DepthMapFactor"),
            orb=orb,
        )
    finally:
        fs.release()


def _read_calibration(fs: cv2.FileStorage, path: Path) -> PinholeCalibration:
    size = [_read_number(fs, path, f"Camera.{k}", f"Camera1.{k}") for k in ("width", "height")]
    if None in size:
        raise CalibrationError(f"{path}: Camera.width and Camera.height are required to check the images' size")
    width, height = int(size[0]), int(size[1])
    left_p, right_p = _read_node(fs, path, "LEFT.P"), _read_node(fs, path, "RIGHT.P")
    if isinstance(left_p, np.ndarray) and left_p.shape == (3, 4):
        # Stereo rectification given: the rectified projection is what the images will have.
        fx, fy, cx, cy = left_p[0, 0], left_p[1, 1], left_p[0, 2], left_p[1, 2]
        baseline = None
        if isinstance(right_p, np.ndarray) and right_p.shape == (3, 4) and right_p[0, 3] != 0:
            baseline = -float(right_p[0, 3]) / float(right_p[0, 0])
        return PinholeCalibration(
            float(fx), float(fy), float(cx), float(cy), width, height, baseline or _baseline(fs, path, fx)
        )
    values = {k: _read_number(fs, path, f"Camera1.{k}", f"Camera.{k}") for k in ("fx", "fy", "cx", "cy")}
    missing = [k for k, v in values.items() if v is None]
    if missing:
        raise CalibrationError(f"{path}: missing Camera.{missing[0]} (or Camera1.{missing[0]}); cannot build the calibration")
    distortion = {k: _read_number(fs, path, f"Camera1.{k}", f"Camera.{k}") for k in ("k1", "k2", "p1", "p2", "k3")}
    nonzero = {k: v for k, v in distortion.items() if v is not None and v != 0.0}
    if nonzero:
        raise CalibrationError(
            f"{path}: distortion {nonzero} is not zero, but zenslam's sources deliver rectified images; give the "
            "rectified intrinsics (LEFT.P/RIGHT.P, or Camera.* with zero distortion)"
        )
    fx = float(values["fx"])
    return PinholeCalibration(
        fx, float(values["fy"]), float(values["cx"]), float(values["cy"]), width, height, _baseline(fs, path, fx)
    )


def _baseline(fs: cv2.FileStorage, path: Path, fx: float) -> float | None:
    """Stereo baseline in metres from ``Stereo.b`` (metres) or ``Camera.bf`` (metres x fx); None without either."""
    b = _read_number(fs, path, "Stereo.b")
    if b is not None:
        return b
    bf = _read_number(fs, path, "Camera.bf")
    return bf / fx if bf is not None else None


def apply_orbslam_settings(config: RunConfig, settings: OrbSlamSettings) -> RunConfig:
    """``config`` with the settings' calibration overriding the source's and their values the frontend's.

    ThDepth sets the frontend's close/far threshold (in baselines) and Camera.fps its keyframe
    rate; a value the frontend has no field for is logged and skipped.
    """
    overrides: dict[str, Any] = {f"orb.{name}": value for name, value in settings.orb.items()}
    if settings.th_depth is not None:
        overrides["keyframe.close_depth_baselines"] = float(settings.th_depth)
    if settings.fps is not None:
        overrides["keyframe.max_frames"] = int(round(settings.fps))
    frontend = config.frontend
    for dotted, value in overrides.items():
        frontend = _replace_path(frontend, dotted.split("."), value)
    if settings.depth_map_factor is not None:
        logger.info("settings DepthMapFactor=%s not used: zenslam's RGB-D sources already give metres", settings.depth_map_factor)
    source = dataclasses.replace(config.source, calibration=settings.calibration)
    return dataclasses.replace(config, source=source, frontend=frontend)


def fit_calibration_to_images(config: RunConfig, width: int, height: int) -> RunConfig:
    """``config`` with its calibration override (if any) fitted to the source's ``width`` x ``height``
    images: a small size mismatch is a warning, a gross one a CalibrationError (``PinholeCalibration.fitted_to``)."""
    override = config.source.calibration
    if override is None:
        return config
    fitted = override.fitted_to(width, height)
    return config if fitted is override else dataclasses.replace(config, source=dataclasses.replace(config.source, calibration=fitted))


def _replace_path(obj: Any, path: list[str], value: Any) -> Any:
    name = path[0]
    if not dataclasses.is_dataclass(obj) or name not in {f.name for f in dataclasses.fields(obj)}:
        logger.warning("the frontend configuration has no field %r; ORB-SLAM setting value %r skipped", name, value)
        return obj
    if len(path) == 1:
        return dataclasses.replace(obj, **{name: value})
    return dataclasses.replace(obj, **{name: _replace_path(getattr(obj, name), path[1:], value)})
