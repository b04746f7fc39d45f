"""The hub's columns of tracking states and poses (service/frame_table.py)."""

from __future__ import annotations

import dataclasses
import tracemalloc

import numpy as np

from zenslam.schemas import codec
from zenslam.service.frame_table import FrameTable


def _state(index: int, state: str = "ok", **fields) -> codec.TrackingStateMessage:
    values = {"stamp_ns": 1000 * index, "n_tracked": 100 + index, "has_pose": state == "ok"} | fields
    return codec.TrackingStateMessage(index=index, state=state, **values)  # type: ignore[arg-type]


def _pose(x: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = x
    return T


def test_states_come_back_in_frame_order_as_they_were_sent():
    table = FrameTable()
    T_ref = _pose(0.5)
    sent = [
        _state(2, keyframe_id=1, reference_keyframe_id=1, T_reference_cam=T_ref),
        _state(0, keyframe_id=0),
        _state(1, "lost", lost_reason="too_few_matches"),
        _state(4, "initializing", lost_reason="waiting_for_parallax", relocalised=True),
    ]
    for state in sent:
        assert table.add_state(state)
    states = table.states()
    assert states.index.tolist() == [0, 1, 2, 4]
    assert len(table) == 4 and table.newest_index() == 4 and table.newest_keyframe_id == 1
    assert table.has(1) and not table.has(3) and not table.has(5) and not table.has(-1)
    for k, state in enumerate(sorted(sent, key=lambda s: s.index)):
        message = states.message(k)
        assert message.T_reference_cam is None if state.T_reference_cam is None else np.array_equal(message.T_reference_cam, T_ref)
        assert dataclasses.replace(message, T_reference_cam=None) == dataclasses.replace(state, T_reference_cam=None)
    assert states.is_state("lost").tolist() == [False, True, False, False]
    assert states.lost_reasons(np.ones(4, dtype=bool)) == [None, "too_few_matches", None, "waiting_for_parallax"]


def test_a_state_sent_again_replaces_the_first_and_the_newest_pose_of_a_stamp_wins():
    table = FrameTable()
    table.add_state(_state(0, "lost"))
    table.add_state(_state(0, n_tracked=7))
    table.add_pose(0, _pose(1.0))
    table.add_pose(0, _pose(2.0))
    table.add_pose(5000, _pose(3.0))
    states = table.states()
    assert len(table) == 1 and states.n_tracked.tolist() == [7] and states.is_state("ok").tolist() == [True]
    stamps, poses = table.poses()
    assert stamps.tolist() == [0, 5000] and poses[:, 0, 3].tolist() == [2.0, 3.0]


def test_missing_poses_counts_states_that_announced_a_pose_not_received():
    table = FrameTable()
    assert table.missing_poses() == 0
    for i in range(3):
        table.add_state(_state(i))
    table.add_state(_state(3, "lost"))
    assert table.missing_poses() == 3
    table.add_pose(1000, _pose(0.0))
    assert table.missing_poses() == 2


def test_a_frame_index_out_of_range_is_refused():
    table = FrameTable()
    assert not table.add_state(_state(-1))
    assert table.add_state(_state(10))
    assert not table.add_state(_state(10 + 2_000_000))
    assert len(table) == 1 and table.newest_index() == 10


def test_a_frame_costs_a_few_hundred_bytes():
    """What the hub holds for a soak's 24,000 frames: a state and a pose each."""
    table = FrameTable()
    states = [_state(i, reference_keyframe_id=i // 3, T_reference_cam=_pose(0.1)) for i in range(10_000)]
    poses = [_pose(float(i)) for i in range(10_000)]
    tracemalloc.start()
    before = tracemalloc.get_traced_memory()[0]
    for state, pose in zip(states, poses):
        table.add_state(state)
        table.add_pose(state.stamp_ns, pose)
    held = tracemalloc.get_traced_memory()[0] - before
    tracemalloc.stop()
    assert held / 10_000 < 400, f"{held / 10_000:.0f} bytes per frame"
