"""Sources of frames: dataset readers (KITTI, EuRoC, TUM RGB-D) and synthetic scenes, named by a spec string.

Spec strings (what ``zenslam run SOURCE`` and ``zenslam inspect SOURCE`` take):
``kitti:<root>/sequences/NN``, ``euroc:<sequence folder holding mav0/>``, ``tum:<sequence folder>``,
``synthetic`` (the loop scene) or ``synthetic:<scene>`` with scene one of loop, figure_eight, still,
corridor, corridor_aliased, optionally followed by ``/<sensor>`` (stereo, rgbd, mono) and by
``,laps=N`` (N laps of the scene's path, each as long as one of the scene's own: long runs), e.g.
``synthetic:figure_eight/rgbd`` or ``synthetic:figure_eight,laps=20`` (or ``,seed=3``: another draw of its textures and noise);
``mcap:<recording>`` replays the sensor frames of a run's ``run.mcap``;
``zenoh:<key>`` takes the frames another program publishes under that key (sources/zenoh_family.py
states the keys and messages): a *bus source*, opened by the source process with ``open_bus_family``,
live, with no length and no ground truth.

``sensor`` (``zenslam run --sensor``, ``source.sensor``) plays a source as another sensor than its
own where it can give it: a stereo or RGB-D dataset as mono (sources/sensor_selection.py); a
synthetic scene renders whichever is asked.
"""

from __future__ import annotations

from pathlib import Path

from zenslam.camera import SensorKind
from zenslam.errors import SourceSpecError
from zenslam.service.sources.bus_messages import MessageFamily
from zenslam.service.sources.frame import ImuSamples, SensorFrame, Source
from zenslam.service.sources.sensor_selection import as_sensor

__all__ = ["ImuSamples", "SensorFrame", "Source", "open_source", "open_bus_family", "is_bus_spec", "SOURCE_KINDS"]

SOURCE_KINDS = ("kitti", "euroc", "tum", "synthetic", "mcap")
BUS_KINDS = ("zenoh", "ros2")


def is_bus_spec(spec: str) -> bool:
    """True when ``spec`` names frames from the bus (``zenoh:<key>``) rather than a dataset or scene."""
    return spec.partition(":")[0] in BUS_KINDS


def open_bus_family(spec: str, ros_domain: int = 0) -> MessageFamily:
    """The message family of a bus source spec (which keys, which messages; ``ros_domain`` for ``ros2:``);
    SourceSpecError if it is none."""
    kind, _, argument = spec.partition(":")
    if kind == "ros2":
        from zenslam.service.sources.ros2_family import Ros2Family

        if not argument:
            raise SourceSpecError(f"source {spec!r} needs a camera namespace after 'ros2:', e.g. ros2:/camera")
        return Ros2Family(argument, ros_domain)
    if kind == "zenoh":
        from zenslam.service.sources.zenoh_family import ZenohFamily

        if not argument:
            raise SourceSpecError(f"source {spec!r} needs a key after 'zenoh:', e.g. zenoh:cam/front")
        return ZenohFamily(argument)
    raise SourceSpecError(f"source {spec!r} is not a bus source: use zenoh:<key> or ros2:<namespace>")


def open_source(spec: str, sensor: SensorKind | None = None) -> Source:
    """Open the source named by ``spec``, played as ``sensor`` (None: its own); raises SourceSpecError
    naming the accepted forms, or the sensors the source can give."""
    kind, _, argument = spec.partition(":")
    if kind == "synthetic":
        return _open_synthetic(argument, sensor)
    if is_bus_spec(spec):
        raise SourceSpecError(
            f"{spec!r} is a live bus source: its frames exist only while a publisher sends them, so it has no length "
            "to inspect or replay; `zenslam run` takes it"
        )
    source = _open_dataset(spec, kind, argument, sensor)
    return source if sensor is None else as_sensor(source, sensor)


def _open_dataset(spec: str, kind: str, argument: str, sensor: SensorKind | None) -> Source:
    if kind not in SOURCE_KINDS:
        raise SourceSpecError(
            f"unknown source {spec!r}: use one of kitti:<root>/sequences/NN, euroc:<folder>, tum:<folder>, "
            "synthetic[:<scene>[/<sensor>][,laps=N][,seed=N]], mcap:<run.mcap>, zenoh:<key>"
        )
    if not argument:
        raise SourceSpecError(f"source {spec!r} needs a path after '{kind}:', e.g. {kind}:/data/{kind}/sequence")
    path = Path(argument).expanduser()
    if kind == "kitti":
        from zenslam.service.sources.kitti import KittiSource

        return KittiSource(path, mono_allowed=sensor == "mono")  # a clip of image_0 alone plays as mono
    if kind == "euroc":
        from zenslam.service.sources.euroc import EurocSource

        return EurocSource(path)
    if kind == "mcap":
        from zenslam.service.sources.mcap_source import McapSource

        return McapSource(path)
    from zenslam.service.sources.tum import TumSource

    return TumSource(path)


def _open_synthetic(argument: str, sensor_choice: SensorKind | None) -> Source:
    from zenslam.service.sources.synthetic import SCENE_NAMES, SyntheticSource, scene_config

    name, *options = (argument or "loop").split(",")
    scene, _, sensor = name.partition("/")
    if scene not in SCENE_NAMES:
        raise SourceSpecError(f"unknown synthetic scene {scene!r}: choose one of {sorted(SCENE_NAMES)}")
    sensors = ("stereo", "rgbd", "mono")
    if sensor and sensor not in sensors:
        raise SourceSpecError(f"unknown synthetic sensor {sensor!r}: choose one of {list(sensors)}")
    if sensor_choice is not None:
        sensor = sensor_choice  # a scene renders any sensor; the choice overrides the spec's
    overrides: dict[str, object] = {"sensor": sensor} if sensor else {}
    for option in options:
        key, _, value = option.partition("=")
        if key == "seed" and value.isdigit():
            overrides["seed"] = int(value)  # another draw of the textures and of every noise
            continue
        if key != "laps" or not value.isdigit() or int(value) < 1:
            raise SourceSpecError(
                f"synthetic option {option!r} not understood: the options are laps=N (a whole number of laps >= 1) "
                "and seed=N (a whole number)"
            )
        preset = scene_config(scene)
        if preset.trajectory not in ("loop", "figure_eight", "corridor"):
            raise SourceSpecError(f"synthetic scene {scene!r} has no laps (a still camera): laps=N applies to a path")
        overrides.update(laps=int(value), duration_s=preset.duration_s / preset.laps * int(value))
    return SyntheticSource(scene_config(scene, **overrides))
