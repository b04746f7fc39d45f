"""Damaged messages on the stages' own input keys are dropped or refused, never crash a stage.

The backend's input (frontend/keyframe) and the frontend's (sensor/frame, backend/map_update) take
thousands of mutants of the golden recording's messages: truncated, bit-flipped, random, grown
with junk, or oversized. Each either fails to decode (a MessageError; the inbox drops and counts it,
tested over a real zenoh session below), or decodes to values the checks accept and is then refused
by the stage (counted) or mapped/tracked/applied without an exception.
"""

from __future__ import annotations

import dataclasses
import random
from pathlib import Path

import numpy as np
import pytest

from zenslam.backend.config import BackendConfig
from zenslam.backend.node import BackendNode
from zenslam.errors import MessageError
from zenslam.frontend.node import FrontendNode
from zenslam.frontend.pipeline import FrontendConfig, FrontendPipeline
from zenslam.runtime import bus
from zenslam.schemas import codec
from zenslam.service.replay import read_topics
from zenslam.service.sources import open_source

REPO_ROOT = Path(__file__).resolve().parents[2]
GOLDEN = REPO_ROOT / "recordings" / "golden" / "synthetic_loop" / "run.mcap"
KEYFRAMES, UPDATES = "/frontend/keyframe", "/backend/map_update"


def _mutants(messages: list[bytes], count: int, seed: int):
    """``count`` damaged copies of ``messages``: cut, bit flips, random bytes, junk inserted, oversized."""
    rng = random.Random(seed)
    for i in range(count):
        data = bytearray(messages[i % len(messages)])
        kind = i % 5
        if kind == 0:
            yield bytes(data[: rng.randrange(len(data))])
        elif kind == 1:
            for _ in range(rng.randint(1, 6)):
                data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
            yield bytes(data)
        elif kind == 2:
            yield rng.randbytes(rng.randrange(1, 300))
        elif kind == 3:
            at = rng.randrange(len(data))
            yield bytes(data[:at]) + rng.randbytes(rng.randrange(1, 64)) + bytes(data[at:])
        else:
            yield bytes(data) + rng.randbytes(rng.randrange(1, 1 << 20))


def _renumbered(keyframe: codec.KeyframeMessage, new_id: int, point_offset: int) -> codec.KeyframeMessage:
    """``keyframe`` as the newest one, its new points with ids no keyframe used (the map refuses repeats)."""
    ids = keyframe.map_point_ids.copy()
    ids[np.isin(ids, keyframe.new_point_ids)] += point_offset
    return dataclasses.replace(keyframe, id=new_id, map_point_ids=ids, new_point_ids=keyframe.new_point_ids + point_offset)


def _decoded(decode, data: bytes):
    """The message, or None when it does not decode; any other exception fails the test."""
    try:
        return decode(data)
    except MessageError:
        return None


def _decodable_mutants(decode, messages: list[bytes], count: int, seed: int):
    """(mutant number, decoded message) for each of ``count`` mutants that still decodes to a message."""
    for i, data in enumerate(_mutants(messages, count, seed)):
        message = _decoded(decode, data)
        if message is not None and not isinstance(message, codec.EndOfStream):
            yield i, message


@pytest.fixture(scope="module")
def golden_messages() -> dict[str, list[bytes]]:
    topics = read_topics(GOLDEN, (KEYFRAMES, UPDATES))
    return {topic: [m.data for m in messages] for topic, messages in topics.items()}


def test_damaged_keyframes_are_refused_or_mapped_and_never_crash_the_backend(golden_messages):
    keyframes = [d for d in golden_messages[KEYFRAMES] if not isinstance(codec.decode_keyframe(d), codec.EndOfStream)]
    node = BackendNode.from_config(BackendConfig())
    for data in keyframes[:6]:
        node.step(codec.decode_keyframe(data))
    decoded = refused = mapped = 0
    for i, message in _decodable_mutants(codec.decode_keyframe, keyframes[6:], 1500, seed=1):
        decoded += 1
        if i % 2:  # half as a keyframe the map has not seen: damaged content reaches local mapping
            message = _renumbered(message, 1000 + i, 10_000_000 * (i + 1))
        if node.refusal(message) is not None:
            node.refuse(message)
            refused += 1
            continue
        node.step(message)
        mapped += 1
    assert node.refused == refused
    assert refused > 0 and mapped > 0, f"the mutants should reach both outcomes: {decoded} decoded, {refused} refused, {mapped} mapped"
    # An undamaged keyframe after them is mapped.
    intact = _renumbered(codec.decode_keyframe(keyframes[6]), 10_000, 10**12)
    assert node.refusal(intact) is None
    node.step(intact)
    assert 10_000 in node.map.keyframes


def test_damaged_map_updates_never_crash_the_frontends_map(golden_messages):
    updates = [d for d in golden_messages[UPDATES] if not isinstance(codec.decode_map_update(d), codec.EndOfStream)]
    source = open_source(f"mcap:{GOLDEN}")
    pipeline = FrontendPipeline(FrontendConfig(), source.calibration, source.sensor)
    for frame in list(source)[:12]:
        pipeline.step(frame.index, frame.stamp_ns, frame.left, right=frame.right, depth_m=frame.depth_m)
    applied = 0
    for _, update in _decodable_mutants(codec.decode_map_update, updates, 1500, seed=2):
        pipeline.apply_map_update(update)
        applied += 1
    assert applied > 0


def test_damaged_sensor_frames_are_refused_or_tracked_and_never_crash_the_frontend():
    source = open_source(f"mcap:{GOLDEN}")
    frames = [codec.encode_sensor_frame(frame, source.calibration, source.sensor) for frame in list(source)[:8]]
    node = FrontendNode(lambda calibration, sensor: FrontendPipeline(FrontendConfig(), calibration, sensor))
    for data in frames[:4]:
        node.handle(codec.decode_sensor_frame(data))
    decoded = tracked = refused = 0
    for i, message in _decodable_mutants(codec.decode_sensor_frame, frames[4:], 400, seed=3):
        decoded += 1
        if i % 2:  # half as the next frame of the stream: damaged images reach tracking
            message = dataclasses.replace(message, frame=dataclasses.replace(message.frame, index=100 + i, stamp_ns=10**10 + i))
        if node.refusal(message) is not None:
            refused += 1
            continue
        node.handle(message)
        tracked += 1
    assert tracked > 0 and refused > 0, f"{decoded} decoded, {tracked} tracked, {refused} refused"


def test_the_inbox_drops_and_counts_what_does_not_decode():
    """Over a real zenoh session: garbage between two good keyframes is counted, both good ones arrive."""
    keyframe = read_topics(GOLDEN, (KEYFRAMES,))[KEYFRAMES][0].data
    with bus.open_session(bus.BusConfig()) as session:
        inbox = bus.subscribe(session, "fuzz/keyframe", codec.decode_keyframe, "lossless", 64)
        publisher = bus.declare_publisher(session, "fuzz/keyframe", codec.KEYFRAME, "lossless")
        assert bus.wait_for_subscribers(publisher, 10.0)
        garbage = list(_mutants([keyframe], 40, seed=4))
        undecodable = sum(_decoded(codec.decode_keyframe, g) is None for g in garbage)
        publisher.put(keyframe)
        for data in garbage:
            publisher.put(data)
        publisher.put(keyframe)
        received = [inbox.get(timeout_s=10.0) for _ in range(2 + len(garbage) - undecodable)]
        inbox.close()
    assert all(m is not None for m in received)
    assert inbox.rejected == undecodable > 0
