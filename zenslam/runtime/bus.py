"""The zenoh bus: session configuration, publishers with per-topic delivery, and bounded subscriber inboxes.

Delivery is chosen per topic where each publisher or subscription is declared:
- ``lossless`` (keyframes, poses, states, end-of-stream, lockstep frames): RELIABLE with
  CongestionControl.BLOCK on the publisher, and a bounded zenoh FifoChannel on the subscriber, so a
  slow consumer slows the producer down instead of losing messages (with zenoh's defaults a slow
  subscriber silently loses most large messages; benchmarks/stage_processes.md).
- ``live`` (camera frames in live mode): BEST_EFFORT with CongestionControl.DROP on the publisher
  and a RingChannel on the subscriber that keeps the newest frames and drops the oldest, as a
  robot's tracker must keep up with the camera rather than fall behind it.
"""

from __future__ import annotations

import json
import logging
import os
import socket
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Generic, Literal, TypeVar

import zenoh

from zenslam.errors import BusError, ConfigError
from zenslam.schemas import keys

logger = logging.getLogger(__name__)
# Undecodable messages: the first few are logged each, then one line per hundred.
_REJECTIONS_LOGGED = 3

T = TypeVar("T")
Delivery = Literal["lossless", "live"]


@dataclass(frozen=True)
class BusConfig:
    """How a process joins the zenoh network (the ``bus`` section of a run configuration)."""

    mode: Literal["peer", "client"] = "peer"  # zenoh mode: peer on one machine, client to go through routers
    listen: tuple[str, ...] = ("tcp/127.0.0.1:0",)  # zenoh endpoints to listen on; port 0 picks a free port
    connect: tuple[str, ...] = ()  # zenoh endpoints to connect to: the run's hub, or routers
    multicast_scouting: bool = False  # UDP multicast discovery; off keeps a run on its own machine
    # zenoh's shared-memory transport: on, every process that sends large messages keeps a 16 MiB
    # pool, mapped into the memory of every process it sends to; off, large messages cross the
    # loopback socket instead (one copy per receiver, cheap at camera rates).
    shared_memory: bool = False
    zenoh_config_file: str | None = None  # a zenoh JSON5 config file; when set it replaces the five fields above
    lossless_queue: int = 32  # messages a lossless inbox holds before the sender blocks, messages
    live_queue: int = 2  # newest camera frames a live inbox keeps (older ones dropped), frames
    # Seconds a process waits for the stages it needs to come up. The frontend's first start on a
    # machine compiles its kernels before it says it is up: about 36 s of CPU, over a minute on a
    # busy 2-core machine; later starts load them from numba's cache in about a second.
    start_timeout_s: float = 180.0


def zenoh_config_from_file(config_file: str | Path, name: str) -> zenoh.Config:
    """The zenoh JSON5 config file ``config_file``; ConfigError naming it as ``name`` when it is
    missing or not a valid zenoh configuration."""
    path = Path(config_file).expanduser()
    if not path.is_file():
        raise ConfigError(f"{name} {path} does not exist; give the path of a zenoh JSON5 config file")
    try:
        return zenoh.Config.from_file(str(path))
    except zenoh.ZError as exc:
        raise ConfigError(f"{name} {path} is not a valid zenoh configuration: {exc}") from exc


def zenoh_config(config: BusConfig) -> zenoh.Config:
    """The zenoh.Config of ``config`` (the config file as is, when one is named)."""
    if config.zenoh_config_file is not None:
        return zenoh_config_from_file(config.zenoh_config_file, "bus.zenoh_config_file")
    cfg = zenoh.Config()
    try:
        cfg.insert_json5("mode", json.dumps(config.mode))
        cfg.insert_json5("scouting/multicast/enabled", json.dumps(config.multicast_scouting))
        cfg.insert_json5("listen/endpoints", json.dumps(list(config.listen)))
        cfg.insert_json5("connect/endpoints", json.dumps(list(config.connect)))
        cfg.insert_json5("transport/shared_memory/enabled", json.dumps(config.shared_memory))
    except zenoh.ZError as exc:
        raise ConfigError(f"invalid bus configuration {config}: {exc}") from exc
    return cfg


@contextmanager
def open_session(config: BusConfig) -> Iterator[zenoh.Session]:
    """Open a zenoh session and close it on exit (an unclosed session can hang interpreter exit)."""
    try:
        session = zenoh.open(zenoh_config(config))
    except zenoh.ZError as exc:
        raise BusError(f"cannot open a zenoh session with {config}: {exc}; check the endpoints") from exc
    try:
        yield session
    finally:
        session.close()


def free_tcp_endpoint(host: str = "127.0.0.1") -> str:
    """A ``tcp/<host>:<port>`` endpoint on a port that was free a moment ago (for a run's hub)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind((host, 0))
        port = sock.getsockname()[1]
    return f"tcp/{host}:{port}"


def quiet_zenoh_logs() -> None:
    """Let zenoh's own logger print only errors unless RUST_LOG says otherwise (process entry points only)."""
    zenoh.init_log_from_env_or("error")


def protobuf_encoding(schema: str) -> zenoh.Encoding:
    """The zenoh encoding of a payload that is a protobuf ``schema`` message (the name travels with it)."""
    return zenoh.Encoding.APPLICATION_PROTOBUF.with_schema(schema)


def declare_publisher(session: zenoh.Session, key: str, schema: str, delivery: Delivery) -> zenoh.Publisher:
    """A publisher on ``key`` whose payloads are protobuf ``schema`` messages, with ``delivery``'s QoS."""
    lossless = delivery == "lossless"
    return declare_raw_publisher(session, key, reliable=lossless, block=lossless, encoding=protobuf_encoding(schema))


def declare_raw_publisher(
    session: zenoh.Session, key: str, *, reliable: bool, block: bool, encoding: zenoh.Encoding | None = None
) -> zenoh.Publisher:
    """A publisher on ``key`` for payloads that are not zenslam messages (ROS 2 CDR, foxglove protobufs),
    with the QoS their peers expect: RELIABLE or BEST_EFFORT, congestion BLOCK or DROP; ``encoding``
    names the payloads, or none is declared (as rmw_zenoh declares none)."""
    options = {} if encoding is None else {"encoding": encoding}
    return session.declare_publisher(
        key,
        congestion_control=zenoh.CongestionControl.BLOCK if block else zenoh.CongestionControl.DROP,
        reliability=zenoh.Reliability.RELIABLE if reliable else zenoh.Reliability.BEST_EFFORT,
        **options,
    )


def declare_callback_subscriber(session: zenoh.Session, key: str, on_sample: Callable[[zenoh.Sample], None]) -> zenoh.Subscriber:
    """A subscriber on ``key`` that hands each sample to ``on_sample`` on zenoh's thread: the callback
    must only decode and enqueue (the recorder, a bus source); the caller undeclares it."""
    return session.declare_subscriber(key, on_sample)


def declare_token(session: zenoh.Session, key: str) -> zenoh.LivelinessToken:
    """A liveliness token on ``key`` (any key: a ROS 2 graph entity, a camera publisher); it vanishes when
    undeclared or when the session closes or dies. ``declare_alive`` is the one a stage announces itself with."""
    return session.liveliness().declare_token(key)


def watch_tokens(session: zenoh.Session, key: str, on_sample: Callable[[zenoh.Sample], None] | None = None, capacity: int = 64):
    """Follow the liveliness tokens under ``key``, those present now included (history): each appearing
    (PUT) or vanishing (DELETE) token is a sample handed to ``on_sample`` on zenoh's thread, or, without
    it, queued in a FifoChannel of ``capacity`` samples to ``try_recv``. The caller undeclares it."""
    handler = on_sample if on_sample is not None else zenoh.handlers.FifoChannel(capacity)
    return session.liveliness().declare_subscriber(key, handler, history=True)


def declare_queryable(session: zenoh.Session, key: str, capacity: int = 16) -> zenoh.Queryable:
    """A queryable on ``key`` whose queries wait (up to ``capacity``) in a FifoChannel until the owner's
    worker answers them with ``reply``; the caller closes it with ``close_queryable``."""
    return session.declare_queryable(key, zenoh.handlers.FifoChannel(capacity))


def reply(query: zenoh.Query, key: str, payload: bytes, schema: str) -> None:
    """Answer ``query`` with the protobuf ``schema`` message ``payload`` on ``key``."""
    query.reply(key, payload, encoding=protobuf_encoding(schema))


def reply_error(query: zenoh.Query, message: str) -> None:
    """Refuse ``query`` with an error reply carrying ``message`` (the querier's request was wrong)."""
    query.reply_err(message)


def waiting_queries(queryable: zenoh.Queryable) -> Iterator[zenoh.Query]:
    """The queries waiting on ``queryable`` (``declare_queryable``), oldest first; each is finalised
    once the loop's body is done with it, so its querier stops waiting whether it was answered or not."""
    while (query := queryable.try_recv()) is not None:
        with query:
            yield query


def close_queryable(queryable: zenoh.Queryable) -> None:
    """Finalise the queries still waiting on ``queryable`` unanswered (their queriers stop waiting at
    once instead of at their timeout), then undeclare it."""
    while (query := queryable.try_recv()) is not None:
        query.drop()
    queryable.undeclare()


def query(
    session: zenoh.Session, key: str, timeout_s: float, payload: bytes | None = None, schema: str | None = None
) -> Iterator[zenoh.Reply]:
    """Ask the queryables on ``key`` (with the protobuf ``schema`` message ``payload``, if any) and yield
    their replies as they come, until all have answered or ``timeout_s`` seconds have passed."""
    options = {} if payload is None else {"payload": payload, "encoding": protobuf_encoding(schema)}
    yield from session.get(key, timeout=timeout_s, **options)


class Inbox(Generic[T]):
    """Decoded messages of one subscription, taken by the stage's worker thread.

    zenoh's channel does the enqueueing on its own thread; the worker decodes as it takes
    messages, so no stage work ever runs on zenoh's threads. A message that does not decode
    (damaged bytes, a faulty sender: the decoder raises) is dropped with a warning and counted in
    ``rejected``; the stage goes on with the next one.
    """

    def __init__(
        self, subscriber: zenoh.Subscriber, decode: Callable[[bytes], T], capacity: int, drop_oldest: bool, key: str = ""
    ):
        self._subscriber = subscriber
        self._decode = decode
        self._capacity = capacity
        self._drop_oldest = drop_oldest
        self._key = key
        self._pending: deque[zenoh.Sample] = deque()
        self.rejected = 0  # messages dropped because they did not decode

    def _pull(self) -> None:
        while self._drop_oldest or len(self._pending) < self._capacity:
            sample = self._subscriber.try_recv()
            if sample is None:
                return
            if self._drop_oldest and len(self._pending) >= self._capacity:
                self._pending.popleft()  # the ring channel's policy, kept on this side too
            self._pending.append(sample)

    @property
    def depth(self) -> int:
        """Messages waiting for the worker (a lower bound: zenoh's channel may hold more)."""
        self._pull()
        return len(self._pending)

    def count_waiting(self, matches: Callable[[T], bool]) -> int:
        """Waiting messages for which ``matches(decoded message)`` holds (a lower bound like ``depth``;
        each is decoded to check, and decoded again when taken)."""
        return sum(1 for message in self.waiting() if matches(message))

    def waiting(self) -> list[T]:
        """The waiting messages that decode, oldest first, left in place (decoded again when taken)."""
        self._pull()
        return [message for sample in self._pending if (message := self._try_decode(sample, False)) is not None]

    def _try_decode(self, sample: zenoh.Sample, count: bool) -> T | None:
        """The sample decoded, or None when it does not decode (counted and logged when ``count``)."""
        data = sample.payload.to_bytes()
        try:
            return self._decode(data)
        except Exception as exc:  # any decoder failure on foreign bytes: the message is unusable, not the stage
            if count:
                self.rejected += 1
                if self.rejected <= _REJECTIONS_LOGGED or self.rejected % 100 == 0:
                    logger.warning(
                        "dropped a message of %d bytes on %s that does not decode (%d so far): %s: %s",
                        len(data), self._key or "the bus", self.rejected, type(exc).__name__, exc,
                    )  # fmt: skip
            return None

    def get(self, timeout_s: float | None = None) -> T | None:
        """The next decoded message, or None if none arrives within ``timeout_s`` seconds (None: wait forever)."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        pause = 0.0002
        while True:
            self._pull()
            while self._pending:
                message = self._try_decode(self._pending.popleft(), True)
                if message is not None:
                    return message
            if deadline is not None and time.monotonic() >= deadline:
                return None
            # zenoh's blocking recv cannot be interrupted by SIGINT; poll with a short, growing pause.
            time.sleep(pause)
            pause = min(pause * 2.0, 0.005)

    def close(self) -> None:
        """Undeclare the subscription; what is still queued is discarded.

        A full FifoChannel blocks zenoh's receiving thread, which would block closing the
        session: empty it first.
        """
        while self._subscriber.try_recv() is not None:
            pass
        self._subscriber.undeclare()
        self._pending.clear()


def subscribe(session: zenoh.Session, key: str, decode: Callable[[bytes], T], delivery: Delivery, capacity: int) -> Inbox[T]:
    """Subscribe to ``key``: ``lossless`` uses a FifoChannel of ``capacity`` (back-pressure when full),
    ``live`` a RingChannel keeping the newest ``capacity`` messages."""
    if capacity < 1:
        raise ConfigError(f"an inbox capacity must be at least 1 message, got {capacity}")
    if delivery == "lossless":
        subscriber = session.declare_subscriber(key, zenoh.handlers.FifoChannel(capacity))
        return Inbox(subscriber, decode, capacity, drop_oldest=False, key=key)
    subscriber = session.declare_subscriber(key, zenoh.handlers.RingChannel(capacity))
    return Inbox(subscriber, decode, capacity, drop_oldest=True, key=key)


def declare_alive(session: zenoh.Session, session_name: str, process: str) -> zenoh.LivelinessToken:
    """Announce that ``process`` is up; the token vanishes when the process's session closes or dies."""
    return declare_token(session, keys.alive(session_name, process))


def alive_processes(session: zenoh.Session, session_name: str, timeout_s: float = 0.5) -> set[str]:
    """Names of the processes of the session whose liveliness tokens are present now."""
    prefix = keys.alive(session_name, "x")[:-1]
    names = set()
    for reply in session.liveliness().get(keys.all_alive(session_name), timeout=timeout_s):
        if reply.ok is not None:
            names.add(str(reply.ok.key_expr).removeprefix(prefix))
    return names


class Comebacks:
    """Follows one process of the session through its liveliness token: ``gone`` while the token is
    absent after having been seen (the process died or left), and ``returned`` once it is back (a
    restart). Poll; ``close`` when done."""

    def __init__(self, session: zenoh.Session, session_name: str, process: str) -> None:
        self._subscriber = session.liveliness().declare_subscriber(
            keys.alive(session_name, process), zenoh.handlers.FifoChannel(64), history=True
        )
        self.gone = False
        self._returns = 0  # times the token came back after vanishing
        self._returns_seen = 0

    def poll(self) -> None:
        """Take the token's changes so far."""
        while (sample := self._subscriber.try_recv()) is not None:
            if sample.kind == zenoh.SampleKind.DELETE:
                self.gone = True
            elif self.gone:
                self.gone = False
                self._returns += 1

    def returned(self) -> bool:
        """True when the process came back since the last call."""
        self.poll()
        back = self._returns > self._returns_seen
        self._returns_seen = self._returns
        return back

    def close(self) -> None:
        self._subscriber.undeclare()


def wait_for_alive(
    session: zenoh.Session,
    session_name: str,
    processes: Iterable[str],
    timeout_s: float,
    keep_waiting: Callable[[], bool] = lambda: True,
) -> set[str]:
    """Wait until every named process's token is present; returns the ones still missing at the deadline
    (or when ``keep_waiting`` says to stop)."""
    missing = set(processes)
    prefix = keys.alive(session_name, "x")[:-1]
    deadline = time.monotonic() + timeout_s
    with session.liveliness().declare_subscriber(
        keys.all_alive(session_name), zenoh.handlers.FifoChannel(64), history=True
    ) as subscriber:
        while missing and time.monotonic() < deadline and keep_waiting():
            sample = subscriber.try_recv()
            if sample is None:
                time.sleep(0.002)
                continue
            name = str(sample.key_expr).removeprefix(prefix)
            if sample.kind == zenoh.SampleKind.PUT:
                missing.discard(name)
    return missing


def require_alive(
    session: zenoh.Session,
    session_name: str,
    processes: Iterable[str],
    timeout_s: float,
    keep_waiting: Callable[[], bool] = lambda: True,
) -> None:
    """Wait for the named processes' tokens; raise BusError naming those missing after ``timeout_s``.

    Seeing a process's token also means its earlier declarations (a recorder's subscriber, declared
    before its token) have reached this session: one peer's declarations arrive in order.
    """
    missing = wait_for_alive(session, session_name, processes, timeout_s, keep_waiting)
    if missing and keep_waiting():
        raise BusError(f"stage(s) {sorted(missing)} did not come up within {timeout_s:.0f} s")


def wait_for_subscribers(publisher: zenoh.Publisher, timeout_s: float, keep_waiting: Callable[[], bool] = lambda: True) -> bool:
    """Wait until some subscriber matches ``publisher``; False if none did within ``timeout_s`` seconds."""
    deadline = time.monotonic() + timeout_s
    while not publisher.matching_status.matching:
        if time.monotonic() >= deadline or not keep_waiting():
            return False
        time.sleep(0.002)
    return True


def parent_alive(parent_pid: int | None) -> bool:
    """True while the process that started this one is still its parent (False once orphaned)."""
    return parent_pid is None or os.getppid() == parent_pid


# The zenoh types that modules above the bus name in their signatures, so that they need not import
# zenoh (only service/ros2/session.py does besides, to build rmw_zenoh's own session config).
Session = zenoh.Session
Sample = zenoh.Sample
Encoding = zenoh.Encoding
Publisher = zenoh.Publisher
LivelinessToken = zenoh.LivelinessToken


def token_appeared(sample: zenoh.Sample) -> bool:
    """True when a sample of ``watch_tokens`` says its token appeared (PUT), False when it vanished."""
    return sample.kind == zenoh.SampleKind.PUT
