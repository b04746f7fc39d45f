"""The bus on loopback: lossless topics lose nothing to a slow consumer, live topics keep the newest, liveliness works."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator

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
