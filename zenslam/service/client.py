"""A Python client of a zenslam run: join its bus session, follow its poses, states and map updates, query its backend, send frames.

A run's messages are on zenoh under ``zenslam/<session>/`` (the session is the run id). A client
joins the session as a zenoh peer that connects to the run's hub (``Client.for_run`` reads the
endpoint from the run folder's ``session.json``; ``zenslam run --listen`` fixes it) or as a zenoh
client of a router (``mode="client"`` and the router's endpoint, or a zenoh JSON5 file):

    with Client.for_run("recordings/demo", name="pose-logger") as client:
        client.on_pose(lambda pose: print(pose.stamp_ns, pose.T_world_cam[:3, 3]))
        client.announce()  # a run started with --wait-for pose-logger starts now
        end = client.wait_for_end()

Callbacks receive decoded dataclasses (``Pose``, ``TrackingState``, ``MapUpdate``), never
protobufs, one at a time on the client's own thread, each stream in the order it was sent.
Delivery is lossless: a callback slower than the run holds the run back (its publishers block)
rather than missing a message. To receive a run from its first message, subscribe, then
``announce(name)`` and start the run with ``zenslam run --wait-for name``: every stage waits for
the name's liveliness token before publishing, and a token arrives after the subscriptions
declared before it.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.errors import ZenslamError
from zenslam.runtime import bus
from zenslam.runtime.backend_queries import query_map, query_trajectory
from zenslam.runtime.session_file import read_session_file
from zenslam.schemas import codec, keys
from zenslam.schemas.map_update import MapUpdate
from zenslam.schemas.sensor_data import SensorFrame

logger = logging.getLogger(__name__)

# What callbacks and queries return (decoded bus messages; see zenslam.schemas.codec for every field).
Pose = codec.StampedPose  # stamp_ns, T_world_cam (4x4: camera -> world), frame_id
TrackingState = codec.TrackingStateMessage  # index, stamp_ns, state ("ok", "lost", ...), has_pose, keyframe_id, ...
KeyframeTrajectory = codec.KeyframeTrajectoryMessage  # keyframe_ids, stamps_ns, T_world_cam (K, 4, 4), finished
MapSnapshot = codec.MapSnapshotMessage  # keyframes (a KeyframeTrajectory), point_ids, p_world (P, 3) metres

__all__ = [
    "Client", "ClientError", "KeyframeTrajectory", "MapSnapshot", "MapUpdate", "PinholeCalibration", "Pose",
    "RunEnd", "SensorFrame", "TrackingState",
]  # fmt: skip

_IDLE_S = 0.002  # seconds the dispatcher pauses when no message is waiting


class ClientError(ZenslamError):
    """A client callback failed, or the run did not end in time."""


@dataclass(frozen=True)
class RunEnd:
    """What the client received from a run, as ``wait_for_end`` returns it."""

    frames: int  # tracking states received: one per frame the frontend handled
    poses: int  # poses received (frames tracked with a pose)
    map_updates: int  # backend map updates received (0 unless subscribed with ``on_map_update``)
    tracking_ended: bool  # the frontend's end of stream arrived, with every pose it announced
    mapping_ended: bool  # the backend's end of stream arrived (False unless subscribed to map updates)


@dataclass
class _Stream:
    """One subscription: its inbox, the user's callback, and what it has passed on."""

    inbox: bus.Inbox
    callback: Callable[[Any], None] | None
    received: int = 0
    ended: bool = False


@dataclass
class _Progress:
    """What the dispatcher has seen, for ``wait_for_end`` (guarded by the client's lock)."""

    announced_pose_stamps: set[int] = field(default_factory=set)  # stamps of states with has_pose
    pose_stamps: set[int] = field(default_factory=set)


class Client:
    """One process's membership of a zenslam run's bus session; use as a context manager.

    ``session``: the run id. ``connect``: zenoh endpoints to connect to (the run's hub, or a router
    with ``mode="client"``). ``zenoh_config_file``: a zenoh JSON5 file instead of ``mode`` and
    ``connect`` (TLS, access control). ``name``: the liveliness name ``announce`` declares.
    ``queue``: messages each subscription holds before the run's publishers block.
    """

    def __init__(
        self,
        session: str,
        connect: tuple[str, ...] | list[str] = (),
        mode: Literal["peer", "client"] = "peer",
        zenoh_config_file: str | Path | None = None,
        name: str | None = None,
        queue: int = 256,
    ):
        keys.session_prefix(session)  # a valid key chunk, or a ConfigError naming it
        self.session_name = session
        self.name = name
        self._queue = queue
        config = bus.BusConfig(
            mode=mode, connect=tuple(connect), zenoh_config_file=None if zenoh_config_file is None else str(zenoh_config_file)
        )
        self._session_context = bus.open_session(config)
        self.session: bus.Session = self._session_context.__enter__()
        try:
            self._start()
        except BaseException:
            self._session_context.__exit__(None, None, None)
            raise

    def _start(self) -> None:
        """The client's state, its states subscription and its thread (the session is open)."""
        self._lock = threading.Lock()
        self._streams: dict[str, _Stream] = {}
        self._progress = _Progress()
        self._token: bus.LivelinessToken | None = None
        self._frame_publisher: bus.Publisher | None = None
        self._frames_sent = 0
        self._error: BaseException | None = None
        self._closing = threading.Event()
        # States are always followed: they say when tracking has ended and which poses to expect.
        self._subscribe(keys.frontend_state(self.session_name), codec.decode_tracking_state, None)
        self._thread = threading.Thread(target=self._dispatch, name="zenslam-client", daemon=True)
        self._thread.start()

    @classmethod
    def for_run(cls, run_dir: str | Path, name: str | None = None, timeout_s: float = 60.0, **kwargs: Any) -> Client:
        """Join the run writing to ``run_dir`` (its ``session.json``: session and hub endpoint), waiting up
        to ``timeout_s`` seconds for the run to write it; ``kwargs`` as for ``Client``."""
        info = read_session_file(Path(run_dir), timeout_s)
        return cls(info.session, connect=kwargs.pop("connect", info.connect), name=name, **kwargs)

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- following the run ----

    def on_pose(self, callback: Callable[[Pose], None]) -> None:
        """Call ``callback(pose)`` for every frontend/pose: the camera pose of every frame tracked, in order."""
        self._subscribe(keys.frontend_pose(self.session_name), codec.decode_pose_in_frame, callback)

    def on_state(self, callback: Callable[[TrackingState], None]) -> None:
        """Call ``callback(state)`` for every frontend/state: the tracking outcome of every frame, in order."""
        self._streams[keys.frontend_state(self.session_name)].callback = callback

    def on_map_update(self, callback: Callable[[MapUpdate], None]) -> None:
        """Call ``callback(update)`` for every backend/map_update: the keyframe poses and map points the
        backend changed (after each keyframe, and loop corrections), in order."""
        self._subscribe(keys.backend_map_update(self.session_name), codec.decode_map_update, callback)

    def announce(self, name: str | None = None) -> None:
        """Declare this client's liveliness token as ``name`` (default: the constructor's): a run started
        with ``--wait-for NAME`` waits for it, and then delivers every message to the subscriptions
        made before this call."""
        name = name or self.name
        if name is None:
            raise ClientError("announce() needs a name: give Client(..., name=...) or announce(name)")
        if self._token is not None:
            raise ClientError(f"this client is already announced as {self.name!r}")
        self.name = name
        self._token = bus.declare_alive(self.session, self.session_name, name)

    def wait_for(self, *processes: str, timeout_s: float = 60.0) -> None:
        """Wait until the named processes of the session are up (their liveliness tokens: stages are
        "source", "frontend", "backend", "recorder"); a stage's subscriptions have then reached this
        client, so e.g. frames published after ``wait_for("frontend")`` are all tracked. Raises
        ClientError naming those still missing after ``timeout_s`` seconds."""
        missing = bus.wait_for_alive(self.session, self.session_name, processes, timeout_s)
        if missing:
            raise ClientError(f"{sorted(missing)} of session {self.session_name!r} did not come up within {timeout_s:.0f} s")

    def wait_for_end(self, timeout_s: float | None = None) -> RunEnd:
        """Wait until tracking has ended (the frontend's end of stream, and every pose it announced has
        been passed to ``on_pose``) and, when subscribed to map updates, mapping too; returns what was
        received. Raises ClientError when ``timeout_s`` seconds pass first, or a callback failed."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while not self._ended():
            self._raise_callback_error()
            if deadline is not None and time.monotonic() > deadline:
                raise ClientError(f"the run of session {self.session_name!r} did not end within {timeout_s:.0f} s: {self.received()}")
            time.sleep(0.01)
        self._raise_callback_error()
        return self.received()

    def received(self) -> RunEnd:
        """What has been received so far."""
        with self._lock:
            states = self._streams[keys.frontend_state(self.session_name)]
            poses = self._streams.get(keys.frontend_pose(self.session_name))
            updates = self._streams.get(keys.backend_map_update(self.session_name))
            return RunEnd(
                frames=states.received,
                poses=0 if poses is None else poses.received,
                map_updates=0 if updates is None else updates.received,
                tracking_ended=states.ended and (poses is None or self._progress.announced_pose_stamps <= self._progress.pose_stamps),
                mapping_ended=updates is not None and updates.ended,
            )

    # ---- asking the backend ----

    def query_trajectory(self, timeout_s: float = 10.0) -> KeyframeTrajectory | None:
        """The backend's keyframe poses now; None when no backend answers within ``timeout_s`` seconds."""
        return query_trajectory(self.session, self.session_name, timeout_s)

    def query_map(self, timeout_s: float = 10.0) -> MapSnapshot | None:
        """A snapshot of the backend's map (keyframe poses, point positions); None when no backend answers."""
        return query_map(self.session, self.session_name, timeout_s)

    # ---- sending frames ----

    def publish_frame(self, frame: SensorFrame, calibration: PinholeCalibration, sensor: SensorKind, source_name: str = "") -> None:
        """Send ``frame`` on the session's sensor/frame key, as the source stage does, lossless (the frontend
        of a session whose stages were started with ``zenslam stage`` tracks it). ``sensor``: "mono",
        "stereo" or "rgbd"; the images must match ``calibration``'s size."""
        data = codec.encode_sensor_frame(frame, calibration, sensor, source_name)
        self._frames().put(data)
        self._frames_sent += 1

    def end_frames(self) -> None:
        """Send the end of stream after the last frame: the frontend then ends its own stream, and the run ends."""
        self._frames().put(codec.encode_end_of_stream(codec.SENSOR_FRAME, self._frames_sent))

    def close(self) -> None:
        """Stop the callbacks, undeclare everything and leave the session."""
        if self._closing.is_set():
            return
        self._closing.set()
        self._thread.join()
        if self._token is not None:
            self._token.undeclare()
        if self._frame_publisher is not None:
            self._frame_publisher.undeclare()
        for stream in self._streams.values():
            stream.inbox.close()
        self._session_context.__exit__(None, None, None)

    # ---- internals ----

    def _subscribe(self, key: str, decode: Callable[[bytes], Any], callback: Callable[[Any], None] | None) -> None:
        if key in self._streams:
            self._streams[key].callback = callback
            return
        inbox = bus.subscribe(self.session, key, decode, "lossless", self._queue)
        with self._lock:
            self._streams[key] = _Stream(inbox, callback)

    def _frames(self) -> bus.Publisher:
        if self._frame_publisher is None:
            key = keys.sensor_frame(self.session_name)
            self._frame_publisher = bus.declare_publisher(self.session, key, codec.SENSOR_FRAME, "lossless")
        return self._frame_publisher

    def _ended(self) -> bool:
        end = self.received()
        mapping = keys.backend_map_update(self.session_name) not in self._streams or end.mapping_ended
        return end.tracking_ended and mapping

    def _raise_callback_error(self) -> None:
        if self._error is not None:
            raise ClientError(f"a callback of the zenslam client failed: {self._error!r}") from self._error

    def _dispatch(self) -> None:
        """The client's thread: take each stream's messages in order and pass them to the callbacks."""
        while not self._closing.is_set():
            with self._lock:
                streams = list(self._streams.items())
            busy = False
            for key, stream in streams:
                while (message := stream.inbox.get(0)) is not None:
                    busy = True
                    self._deliver(key, stream, message)
            if not busy:
                time.sleep(_IDLE_S)

    def _deliver(self, key: str, stream: _Stream, message: Any) -> None:
        if isinstance(message, codec.EndOfStream):
            with self._lock:
                stream.ended = True
            return
        try:
            # After a failed callback messages are still taken, uncalled: a stuck client must not
            # hold the run's publishers back.
            if stream.callback is not None and self._error is None:
                stream.callback(message)
        except Exception as exc:  # raised to the user by wait_for_end
            logger.exception("a zenslam client callback failed on %s", key)
            self._error = exc
        with self._lock:
            stream.received += 1
            if isinstance(message, codec.TrackingStateMessage) and message.has_pose:
                self._progress.announced_pose_stamps.add(message.stamp_ns)
            elif isinstance(message, codec.StampedPose):
                self._progress.pose_stamps.add(message.stamp_ns)
