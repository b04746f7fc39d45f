"""``zenslam publish SOURCE --key K``: play a dataset or scene onto the bus as a camera driver would.

The frames go out under the key prefix ``K`` in the layout a ``zenoh:K`` source reads
(sources/zenoh_family.py), at the recorded rate times ``--rate``, with a liveliness token on ``K``
that goes when the last frame is out. By default this process listens on tcp/127.0.0.1:7447
(zenoh's default port), where ``zenslam run zenoh:K`` connects: the two meet on one machine with
multicast scouting off. ``--connect`` joins a router (or a publisher of frames elsewhere) instead;
``--bus-config`` takes a whole zenoh JSON5 configuration.

With ``--ros2 NAMESPACE`` it is a ROS 2 camera driver on rmw_zenoh instead: sensor_msgs/Image and
CameraInfo on ``NAMESPACE/image_rect`` and ``NAMESPACE/camera_info`` (stereo: ``left/...`` and
``right/...``), in rmw_zenoh's keys, CDR payloads and graph tokens (service/ros2/frames.py), which
``zenslam run ros2:NAMESPACE`` and ROS 2 nodes on rmw_zenoh read.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import time
from pathlib import Path

from zenslam.runtime import bus
from zenslam.runtime.stop import EXIT_INTERRUPTED, StopFlag
from zenslam.service.bus_publisher import CameraPublisher, PublishOptions, publish_source, readable_frames
from zenslam.service.sources import Source, open_source
from zenslam.service.sources.config import DEFAULT_BUS_INPUT
from zenslam.service.sources.zenoh_family import check_prefix

logger = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "publish",
        help="play a dataset or synthetic scene onto zenoh as a camera driver would (for `zenslam run zenoh:KEY`)",
        description=__doc__.split("\n\n")[1].replace("\n", " "),
    )
    parser.add_argument("source", help="kitti:<root>/sequences/NN | euroc:<folder> | tum:<folder> | synthetic[:<scene>[/<sensor>][,laps=N][,seed=N]] | mcap:<run.mcap>")
    target = parser.add_mutually_exclusive_group(required=True)
    target.add_argument("--key", help="key prefix, e.g. cam/kitti (images on cam/kitti/left/image, ...)")
    target.add_argument(
        "--ros2", metavar="NAMESPACE",
        help="publish as a ROS 2 camera driver on rmw_zenoh under NAMESPACE, e.g. /cam (read by `zenslam run ros2:/cam`)",
    )
    parser.add_argument("--ros-domain", type=int, default=None, help="ROS 2 domain id (--ros2; default ROS_DOMAIN_ID, else 0)")
    parser.add_argument("--rate", type=float, default=1.0, help="multiple of the recorded rate (default 1; 0: as fast as possible)")
    parser.add_argument(
        "--format", choices=("foxglove", "zenslam"), default="foxglove",
        help="foxglove: CameraCalibration + RawImage/CompressedImage per camera (default); zenslam: one SensorFrame per frame",
    )
    parser.add_argument("--image-format", choices=("raw", "png"), default="raw", help="foxglove images: RawImage mono8 or PNG CompressedImage")
    parser.add_argument("--sensor", choices=("mono", "stereo", "rgbd"), default=None, help="publish the source as this sensor")
    parser.add_argument("--max-frames", type=int, default=None, help="stop after this many frames")
    parser.add_argument("--no-wait", action="store_true", help="start at once instead of waiting for a subscriber to the images")
    parser.add_argument(
        "--listen", action="append", default=None, metavar="ENDPOINT",
        help=f"zenoh endpoint to listen on (repeatable; default {DEFAULT_BUS_INPUT} unless --connect is given)",
    )
    parser.add_argument("--connect", action="append", default=None, metavar="ENDPOINT", help="zenoh endpoint to connect to (repeatable)")
    parser.add_argument("--bus-config", type=Path, default=None, help="zenoh JSON5 config file (replaces --listen/--connect)")
    parser.set_defaults(handler=run, stop_flag=True)


def bus_config_of(args: argparse.Namespace) -> bus.BusConfig:
    """The publisher's zenoh configuration: a file, or peer mode listening/connecting as asked."""
    if args.bus_config is not None:
        return bus.BusConfig(zenoh_config_file=str(args.bus_config))
    connect = tuple(args.connect or ())
    listen = tuple(args.listen or (() if connect else (DEFAULT_BUS_INPUT,)))
    return dataclasses.replace(bus.BusConfig(), listen=listen or ("tcp/127.0.0.1:0",), connect=connect)


def run(args: argparse.Namespace) -> int:
    """Open the source, declare the camera, publish every frame, print what was published."""
    stop: StopFlag = args.stop
    source = open_source(args.source, args.sensor)
    if args.ros2 is not None:
        return _publish_ros2(args, source, stop)
    check_prefix(args.key.strip("/"), f"--key {args.key}")
    options = PublishOptions(
        key=args.key, format=args.format, image_format=args.image_format, rate=args.rate,
        max_frames=args.max_frames, wait_for_subscriber=not args.no_wait,
    )  # fmt: skip
    config = bus_config_of(args)
    total = len(source) if args.max_frames is None else min(len(source), args.max_frames)
    with bus.open_session(config) as session, CameraPublisher(session, args.key, source.sensor, args.format, args.image_format) as camera:
        print(f"publishing {source.name}: {total} {source.sensor} frames, {source.calibration.summary()}")
        print(f"bus: {', '.join(config.listen) if config.zenoh_config_file is None else config.zenoh_config_file}"
              f"{' -> ' + ', '.join(config.connect) if config.connect else ''}; liveliness token {camera.key}")  # fmt: skip
        for key, schema in camera.keys().items():
            print(f"  {key}  {schema}")
        if options.wait_for_subscriber:
            print(f"waiting for a subscriber to {camera.image_key} ...", flush=True)
        started = time.monotonic()
        sent = publish_source(camera, source, options, stop)
        elapsed = time.monotonic() - started
    print(f"published {sent} frames in {elapsed:.1f} s at {args.rate:g}x the recorded rate")
    return EXIT_INTERRUPTED if stop() else 0


def _publish_ros2(args: argparse.Namespace, source: Source, stop: StopFlag) -> int:
    """``--ros2 NAMESPACE``: the frames as a ROS 2 camera driver on rmw_zenoh publishes them."""
    from zenslam.service.ros2.frames import publish_frames_ros2
    from zenslam.service.ros2.run_bridge import domain_id_from

    config = bus_config_of(args)
    domain = domain_id_from(args.ros_domain)
    total = len(source) if args.max_frames is None else min(len(source), args.max_frames)
    print(f"publishing {source.name}: {total} {source.sensor} frames as ROS 2 topics under {args.ros2} (domain {domain})")
    started = time.monotonic()
    with bus.open_session(config) as session:
        sent = publish_frames_ros2(
            session, readable_frames(source, total), source.calibration, args.ros2, domain, args.rate,
            wait_for_subscribers_s=0.0 if args.no_wait else config.start_timeout_s, stop=stop,
        )  # fmt: skip
    print(f"published {sent} frames in {time.monotonic() - started:.1f} s at {args.rate:g}x the recorded rate")
    return EXIT_INTERRUPTED if stop() else 0

