"""The bus on loopback: lossless topics lose nothing to a slow consumer, live topics keep the newest, liveliness works."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import pytest
import zenoh

from zenslam.errors import ConfigError
from zenslam.runtime import bus
from zenslam.schemas import codec, keys


def _state(i: int, padding: int = 0) -> bytes:
    # lost_reason pads the message to a realistic size for the congestion tests
    return codec.encode_tracking_state(codec.TrackingStateMessage(i, i, "lost", lost_reason="x" * padding))


@pytest.fixture(scope="module")
def two_sessions() -> Iterator[tuple[zenoh.Session, zenoh.Session]]:
    """A hub listening on a loopback port and a peer connected to it, like a run's processes.

    Shared by the module's tests (each uses its own keys): a second connection from one process
    takes zenoh about 0.5 s.
    """
    hub_endpoint = bus.free_tcp_endpoint()
    with bus.open_session(bus.BusConfig(listen=(hub_endpoint,))) as hub:
        with bus.open_session(bus.BusConfig(connect=(hub_endpoint,))) as peer:
            yield hub, peer


def test_default_config_stays_on_loopback_without_multicast():
    cfg = bus.zenoh_config(bus.BusConfig())
    assert json.loads(cfg.get_json("scouting/multicast/enabled")) is False
    assert json.loads(cfg.get_json("listen/endpoints")) == ["tcp/127.0.0.1:0"]
    assert json.loads(cfg.get_json("mode")) == "peer"
    assert json.loads(cfg.get_json("transport/shared_memory/enabled")) is False
    shm = bus.zenoh_config(bus.BusConfig(shared_memory=True))
    assert json.loads(shm.get_json("transport/shared_memory/enabled")) is True


def test_zenoh_config_file_replaces_the_fields(tmp_path):
    path = tmp_path / "zenoh.json5"
    path.write_text('{ mode: "client", connect: { endpoints: ["tcp/127.0.0.1:7447"] } }')
    cfg = bus.zenoh_config(bus.BusConfig(zenoh_config_file=str(path)))
    assert json.loads(cfg.get_json("mode")) == "client"
    assert json.loads(cfg.get_json("connect/endpoints")) == ["tcp/127.0.0.1:7447"]


def test_missing_zenoh_config_file_names_it(tmp_path):
    with pytest.raises(ConfigError, match="nope.json5 does not exist"):
        bus.zenoh_config(bus.BusConfig(zenoh_config_file=str(tmp_path / "nope.json5")))


def test_lossless_topic_loses_nothing_to_a_slow_consumer(two_sessions):
    hub, peer = two_sessions
    key = keys.frontend_state("lossless")
    inbox = bus.subscribe(hub, key, codec.decode_tracking_state, "lossless", capacity=4)
    publisher = bus.declare_publisher(peer, key, codec.TRACKING_STATE, "lossless")
    assert bus.wait_for_subscribers(publisher, timeout_s=5.0)
    n = 150

    def produce() -> None:
        for i in range(n):
            publisher.put(_state(i, padding=60_000))  # 60 KB, the size zenoh's defaults dropped

    producer = threading.Thread(target=produce)
    producer.start()
    received = []
    deadline = time.monotonic() + 20.0
    while len(received) < n and time.monotonic() < deadline:
        message = inbox.get(timeout_s=0.5)
        if message is not None:
            received.append(message.index)
            if len(received) % 10 == 0:
                time.sleep(0.01)  # a consumer slower than the producer
    producer.join(timeout=10.0)
    assert received == list(range(n))
    inbox.close()


def test_live_topic_keeps_the_newest(two_sessions):
    hub, peer = two_sessions
    key = keys.sensor_frame("live")
    inbox = bus.subscribe(hub, key, codec.decode_tracking_state, "live", capacity=2)
    # A lossless publisher, so that every message reaches the subscriber and only its ring drops.
    publisher = bus.declare_publisher(peer, key, codec.TRACKING_STATE, "lossless")
    assert bus.wait_for_subscribers(publisher, timeout_s=5.0)
    for i in range(50):
        publisher.put(_state(i))
    # Let everything arrive while nobody takes it: the last one sent is waiting once all have come.
    deadline = time.monotonic() + 20.0
    while not inbox.count_waiting(lambda m: m.index == 49):
        assert time.monotonic() < deadline, "the last message did not arrive"
        time.sleep(0.01)
    got = []
    while (message := inbox.get(timeout_s=0.2)) is not None:
        got.append(message.index)
    assert got == [48, 49]
    inbox.close()


def test_get_times_out_with_none(two_sessions):
    hub, _ = two_sessions
    inbox = bus.subscribe(hub, keys.frontend_pose("timeout"), codec.decode_pose_in_frame, "lossless", capacity=2)
    started = time.monotonic()
    assert inbox.get(timeout_s=0.1) is None
    assert time.monotonic() - started >= 0.09  # it did wait (returning at all is the other half)
    inbox.close()


def test_capacity_must_be_positive(two_sessions):
    hub, _ = two_sessions
    with pytest.raises(ConfigError, match="at least 1"):
        bus.subscribe(hub, keys.frontend_pose("capacity"), codec.decode_pose_in_frame, "live", capacity=0)


def test_publishers_carry_the_schema_and_qos(two_sessions):
    _, peer = two_sessions
    lossless = bus.declare_publisher(peer, keys.frontend_keyframe("qos"), codec.KEYFRAME, "lossless")
    live = bus.declare_publisher(peer, keys.sensor_frame("qos"), codec.SENSOR_FRAME, "live")
    assert lossless.congestion_control == zenoh.CongestionControl.BLOCK
    assert live.congestion_control == zenoh.CongestionControl.DROP
    assert "zenslam.Keyframe" in str(lossless.encoding)


def test_liveliness_tokens_come_and_go(two_sessions):
    hub, peer = two_sessions
    token = bus.declare_alive(peer, "alive", "frontend")
    assert bus.wait_for_alive(hub, "alive", ["frontend"], timeout_s=5.0) == set()
    assert bus.alive_processes(hub, "alive") == {"frontend"}
    token.undeclare()
    deadline = time.monotonic() + 5.0
    while bus.alive_processes(hub, "alive") and time.monotonic() < deadline:
        time.sleep(0.01)
    assert bus.alive_processes(hub, "alive") == set()


def test_waiting_for_a_missing_process_gives_up(two_sessions):
    hub, _ = two_sessions
    assert bus.wait_for_alive(hub, "missing", ["backend"], timeout_s=0.2) == {"backend"}


def test_no_subscriber_means_no_match(two_sessions):
    _, peer = two_sessions
    publisher = bus.declare_publisher(peer, keys.backend_loop("nomatch"), codec.KEYFRAME, "lossless")
    assert not bus.wait_for_subscribers(publisher, timeout_s=0.1)


def test_count_waiting_counts_the_matching_messages_and_takes_none(two_sessions):
    sender, receiver = two_sessions
    inbox = bus.subscribe(receiver, "zenslam/t/count", bytes, "lossless", 8)
    publisher = bus.declare_publisher(sender, "zenslam/t/count", "test.Bytes", "lossless")
    assert bus.wait_for_subscribers(publisher, timeout_s=5.0)
    for payload in (b"a", b"bb", b"c", b"end"):
        publisher.put(payload)
    deadline = time.monotonic() + 5.0
    while inbox.depth < 4 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert inbox.count_waiting(lambda m: m != b"end") == 3
    assert [inbox.get(timeout_s=1.0) for _ in range(4)] == [b"a", b"bb", b"c", b"end"]
    assert inbox.count_waiting(lambda m: True) == 0
    inbox.close()


# ---- the wrappers for declarations other than stage topics: raw publishers, callback subscribers,
# tokens, token watches, queryables and queries ----


def _wait_for(condition, timeout_s: float = 10.0, what: str = "the condition") -> None:
    """Poll ``condition()`` until it holds; fail naming ``what`` after ``timeout_s`` seconds."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"{what} did not happen within {timeout_s} s"
        time.sleep(0.005)


def _next_sample(channel, timeout_s: float = 10.0) -> zenoh.Sample:
    """The next sample of a FifoChannel-backed subscriber, waiting up to ``timeout_s`` seconds."""
    deadline = time.monotonic() + timeout_s
    while (sample := channel.try_recv()) is None:
        assert time.monotonic() < deadline, f"no sample arrived within {timeout_s} s"
        time.sleep(0.005)
    return sample


def test_protobuf_encoding_names_the_schema():
    encoding = bus.protobuf_encoding(codec.KEYFRAME)
    assert str(encoding) == f"application/protobuf;{codec.KEYFRAME}"
    assert encoding != bus.protobuf_encoding(codec.MAP_UPDATE)


def test_raw_publishers_carry_the_qos_and_encoding_asked_for(two_sessions):
    hub, peer = two_sessions
    key = "zenslam/t/raw"
    got: list[zenoh.Sample] = []
    arrived = threading.Event()
    subscriber = bus.declare_callback_subscriber(hub, key, lambda sample: (got.append(sample), arrived.set()))
    plain = bus.declare_raw_publisher(peer, key, reliable=False, block=False)
    named = bus.declare_raw_publisher(peer, key, reliable=True, block=True, encoding=bus.protobuf_encoding("foxglove.CompressedImage"))
    assert plain.reliability == zenoh.Reliability.BEST_EFFORT and plain.congestion_control == zenoh.CongestionControl.DROP
    assert named.reliability == zenoh.Reliability.RELIABLE and named.congestion_control == zenoh.CongestionControl.BLOCK
    assert bus.wait_for_subscribers(named, timeout_s=5.0)
    named.put(b"\x01cdr")
    assert arrived.wait(timeout=10.0), "the sample of the raw publisher did not arrive"
    assert got[0].payload.to_bytes() == b"\x01cdr"
    assert str(got[0].encoding) == "application/protobuf;foxglove.CompressedImage"
    arrived.clear()
    plain.put(b"no encoding")
    assert arrived.wait(timeout=10.0), "the sample of the plain publisher did not arrive"
    assert got[1].payload.to_bytes() == b"no encoding"
    assert got[1].encoding == zenoh.Encoding.ZENOH_BYTES  # none declared: zenoh's default, as rmw_zenoh sends
    for declared in (plain, named, subscriber):
        declared.undeclare()


def test_a_callback_subscriber_gets_each_sample_until_undeclared(two_sessions):
    hub, peer = two_sessions
    key = "zenslam/t/callback"
    payloads: list[bytes] = []
    control: list[bytes] = []
    control_got_two = threading.Event()

    def on_control(sample: zenoh.Sample) -> None:
        control.append(sample.payload.to_bytes())
        if len(control) == 2:
            control_got_two.set()

    subscriber = bus.declare_callback_subscriber(hub, key, lambda sample: payloads.append(sample.payload.to_bytes()))
    control_subscriber = bus.declare_callback_subscriber(hub, key, on_control)
    publisher = bus.declare_publisher(peer, key, "test.Bytes", "lossless")
    assert bus.wait_for_subscribers(publisher, timeout_s=5.0)
    publisher.put(b"first")
    _wait_for(lambda: payloads == [b"first"], what="the first sample reaching the callback")
    subscriber.undeclare()
    publisher.put(b"second")
    # The control subscriber of the same session had the second sample: the undeclared one would have too.
    assert control_got_two.wait(timeout=10.0), "the control subscriber did not get the second sample"
    assert control == [b"first", b"second"]
    assert payloads == [b"first"]
    control_subscriber.undeclare()


def test_watched_tokens_appear_with_their_history_and_vanish(two_sessions):
    hub, peer = two_sessions
    token = bus.declare_token(peer, "zenslam/t/tokens/camera")
    watch = bus.watch_tokens(hub, "zenslam/t/tokens/**")  # declared after the token: its history has it
    sample = _next_sample(watch)
    assert (str(sample.key_expr), sample.kind) == ("zenslam/t/tokens/camera", zenoh.SampleKind.PUT)
    token.undeclare()
    sample = _next_sample(watch)
    assert (str(sample.key_expr), sample.kind) == ("zenslam/t/tokens/camera", zenoh.SampleKind.DELETE)
    watch.undeclare()


def test_watched_tokens_can_go_to_a_callback(two_sessions):
    hub, peer = two_sessions
    seen: list[tuple[str, zenoh.SampleKind]] = []
    appeared, vanished = threading.Event(), threading.Event()

    def on_sample(sample: zenoh.Sample) -> None:
        seen.append((str(sample.key_expr), sample.kind))
        (appeared if sample.kind == zenoh.SampleKind.PUT else vanished).set()

    watch = bus.watch_tokens(hub, "zenslam/t/callback_tokens/*", on_sample)
    token = bus.declare_token(peer, "zenslam/t/callback_tokens/node")
    assert appeared.wait(timeout=10.0), "the token's appearance did not reach the callback"
    token.undeclare()
    assert vanished.wait(timeout=10.0), "the token's disappearance did not reach the callback"
    assert seen == [("zenslam/t/callback_tokens/node", zenoh.SampleKind.PUT), ("zenslam/t/callback_tokens/node", zenoh.SampleKind.DELETE)]
    watch.undeclare()


@contextmanager
def _answering(queryable: zenoh.Queryable, handle) -> Iterator[None]:
    """A worker thread handling each waiting query of ``queryable`` with ``handle(query)``, for the
    ``with`` block."""
    stop = threading.Event()

    def work() -> None:
        while not stop.is_set():
            for query in bus.waiting_queries(queryable):
                handle(query)
            time.sleep(0.002)

    worker = threading.Thread(target=work, daemon=True)
    worker.start()
    try:
        yield
    finally:
        stop.set()
        worker.join(timeout=10.0)


def _replies_once_routed(session: zenoh.Session, key: str, **query_args) -> list[zenoh.Reply]:
    """The replies to a query on ``key``, asked again until some arrive (the queryable's declaration
    may not have reached ``session`` yet; a query no queryable matches ends at once, with none)."""
    deadline = time.monotonic() + 10.0
    while not (replies := list(bus.query(session, key, timeout_s=10.0, **query_args))):
        assert time.monotonic() < deadline, f"no reply on {key} within 10 s"
        time.sleep(0.005)
    return replies


def test_a_query_with_a_payload_gets_the_queryables_reply(two_sessions):
    hub, peer = two_sessions
    key = "zenslam/t/query/echo"
    queryable = bus.declare_queryable(hub, key)
    asked: list[tuple[bytes, str]] = []

    def echo(query: zenoh.Query) -> None:
        asked.append((query.payload.to_bytes(), str(query.encoding)))
        bus.reply(query, key, b"re:" + query.payload.to_bytes(), codec.KEYFRAME_TRAJECTORY)

    with _answering(queryable, echo):
        (reply,) = _replies_once_routed(peer, key, payload=b"hello", schema=codec.RELOCALISATION_QUERY)
    assert asked[-1] == (b"hello", f"application/protobuf;{codec.RELOCALISATION_QUERY}")
    assert reply.ok is not None and reply.ok.payload.to_bytes() == b"re:hello"
    assert str(reply.ok.encoding) == f"application/protobuf;{codec.KEYFRAME_TRAJECTORY}"
    assert str(reply.ok.key_expr) == key
    bus.close_queryable(queryable)


def test_a_refused_query_gets_an_error_reply(two_sessions):
    hub, peer = two_sessions
    key = "zenslam/t/query/refuse"
    queryable = bus.declare_queryable(hub, key)
    with _answering(queryable, lambda query: bus.reply_error(query, "not a relocalisation query")):
        (reply,) = _replies_once_routed(peer, key)
    assert reply.ok is None
    assert reply.err.payload.to_bytes() == b"not a relocalisation query"
    bus.close_queryable(queryable)


def test_a_query_nobody_answers_ends_without_replies(two_sessions):
    _, peer = two_sessions
    assert list(bus.query(peer, "zenslam/t/query/nobody", timeout_s=5.0)) == []


def _ask_until_taken(session: zenoh.Session, key: str, taken: threading.Event, replies: list) -> threading.Thread:
    """A querier thread on ``key`` (60 s timeout) whose query a worker has taken (``taken``), asked
    again while the queryable's declaration has not reached ``session`` (such a query ends at once)."""

    def ask() -> threading.Thread:
        querier = threading.Thread(target=lambda: replies.extend(bus.query(session, key, timeout_s=60.0)), daemon=True)
        querier.start()
        return querier

    querier = ask()
    deadline = time.monotonic() + 10.0
    while not taken.wait(timeout=0.05):
        assert time.monotonic() < deadline, "no query reached the queryable"
        if not querier.is_alive():
            querier = ask()
    return querier


def test_a_query_taken_but_not_answered_is_finalised_when_the_worker_moves_on(two_sessions):
    hub, peer = two_sessions
    key = "zenslam/t/query/unanswered"
    queryable = bus.declare_queryable(hub, key)
    taken = threading.Event()
    replies: list[zenoh.Reply] = []
    with _answering(queryable, lambda query: taken.set()):  # takes each query, answers none
        querier = _ask_until_taken(peer, key, taken, replies)
        # Finalised by the worker's loop, the query ends long before its 60 s timeout, with no reply.
        querier.join(timeout=20.0)
    assert not querier.is_alive(), "the querier still waits: the unanswered query was not finalised"
    assert replies == []
    bus.close_queryable(queryable)


def test_closing_a_queryable_finalises_the_queries_still_waiting_and_answers_no_more(two_sessions):
    hub, peer = two_sessions
    key = "zenslam/t/query/closed"
    closed = bus.declare_queryable(hub, key)  # nobody answers it: queries wait in its channel
    # A second queryable of the same session on the same key: a query it takes has been handed to
    # ``closed`` as well, in the same routing step.
    detector = bus.declare_queryable(hub, key)
    taken = threading.Event()
    replies: list[zenoh.Reply] = []
    with _answering(detector, lambda query: taken.set()):
        querier = _ask_until_taken(peer, key, taken, replies)
        bus.close_queryable(closed)
        querier.join(timeout=20.0)
    assert not querier.is_alive(), "the querier still waits: the query left in the closed queryable was not finalised"
    assert replies == []
    bus.close_queryable(detector)
    assert list(bus.query(peer, key, timeout_s=5.0)) == []  # nothing answers on the key any more
