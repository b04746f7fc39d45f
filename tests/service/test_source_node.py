"""The source process's playback: paced at the recorded rate, limited in frames, and always ending its stream."""

from __future__ import annotations

import time

import numpy as np
import pytest

from zenslam.camera import PinholeCalibration
from zenslam.schemas import codec, keys
from zenslam.runtime import bus
from zenslam.service.run_config import SourceConfig
from zenslam.service import source_node
from zenslam.service.source_node import play
from zenslam.service.sources.frame import SensorFrame

CAL = PinholeCalibration(fx=100.0, fy=100.0, cx=8.0, cy=6.0, width=16, height=12)


def _frames(n: int, period_ns: int) -> list[SensorFrame]:
    return [SensorFrame(i, 5_000 + i * period_ns, np.full((12, 16), i, np.uint8)) for i in range(n)]


@pytest.fixture(scope="module")
def session():
    with bus.open_session(bus.BusConfig()) as s:
        yield s


class FakeClock:
    """Seconds that pass only when someone sleeps: the pacer's schedule, free of the machine's load."""

    def __init__(self) -> None:
        self.now_s = 1000.0
        self.slept_s: list[float] = []

    def monotonic(self) -> float:
        return self.now_s

    def sleep(self, seconds: float) -> None:
        self.slept_s.append(seconds)
        self.now_s += seconds


@pytest.fixture
def release_times(monkeypatch) -> tuple[FakeClock, list[float]]:
    """play() paces on a fake clock; the list gets each frame's release time (fake clock s)."""
    clock, released = FakeClock(), []

    class FakeClockPacer(source_node._Pacer):
        def __init__(self, rate, should_stop):
            super().__init__(rate, should_stop, clock=clock.monotonic, sleep=clock.sleep)

        def wait_for(self, stamp_ns: int) -> None:
            super().wait_for(stamp_ns)
            released.append(clock.now_s)

    monkeypatch.setattr(source_node, "_Pacer", FakeClockPacer)
    return clock, released


def _offsets(released: list[float]) -> list[float]:
    return [t - released[0] for t in released]


def _collect(inbox: bus.Inbox) -> list:
    out = []
    while not isinstance(message := inbox.get(timeout_s=10.0), codec.EndOfStream):
        assert message is not None, "the stream did not end"
        out.append(message.frame.index)
    return out + [message]


def _play(session, name: str, frames, config: SourceConfig, should_stop=lambda: False, mode="live"):
    # Lossless on the receiving side, so the test sees everything the source sent.
    inbox = bus.subscribe(session, keys.sensor_frame(name), codec.decode_sensor_frame, "lossless", 64)
    sent = play(session, name, frames, CAL, "mono", config, should_stop, "test", mode=mode)
    received = _collect(inbox)
    inbox.close()
    return sent, received


def test_live_playback_keeps_the_recorded_rate(session, release_times):
    clock, released = release_times
    sent, received = _play(session, "paced", _frames(6, 40_000_000), SourceConfig(rate=1.0))
    assert sent == 6 and received == [0, 1, 2, 3, 4, 5, codec.EndOfStream(6)]
    assert _offsets(released) == pytest.approx([0.0, 0.04, 0.08, 0.12, 0.16, 0.20], abs=1e-9)  # five 40 ms gaps


def test_rate_scales_the_pace_and_zero_means_as_fast_as_possible(session, release_times):
    clock, released = release_times
    frames = _frames(6, 100_000_000)  # 0.5 s of recording
    _play(session, "fast", frames, SourceConfig(rate=2.0))
    assert _offsets(released) == pytest.approx([0.0, 0.05, 0.10, 0.15, 0.20, 0.25], abs=1e-9)  # 0.25 s at twice the speed
    released.clear()
    clock.slept_s.clear()
    _play(session, "fastest", frames, SourceConfig(rate=0.0))
    assert len(released) == 6 and clock.slept_s == []  # never waits


def test_the_pacer_sleeps_in_short_steps_and_stops_waiting_on_request():
    """Sleeps of at most 50 ms, so a stop request ends a long wait for a far frame at once."""
    clock, stop = FakeClock(), {"now": False}

    def sleep(seconds: float) -> None:
        clock.sleep(seconds)
        stop["now"] = len(clock.slept_s) == 3

    pacer = source_node._Pacer(1.0, lambda: stop["now"], clock=clock.monotonic, sleep=sleep)
    pacer.wait_for(0)
    pacer.wait_for(10_000_000_000)  # due 10 s later
    assert clock.slept_s == pytest.approx([0.05] * 3)


def test_max_frames_stops_early_and_still_ends_the_stream(session):
    sent, received = _play(session, "limited", _frames(10, 1), SourceConfig(rate=0.0, max_frames=3))
    assert sent == 3 and received == [0, 1, 2, codec.EndOfStream(3)]


def test_a_stop_request_still_ends_the_stream(session):
    stop = {"now": False}

    def frames():
        for frame in _frames(10, 1):
            if frame.index == 2:
                stop["now"] = True  # as if SIGINT arrived while frame 2 was being read
            yield frame

    sent, received = _play(session, "stopped", frames(), SourceConfig(rate=0.0), lambda: stop["now"])
    assert sent == 2 and received == [0, 1, codec.EndOfStream(2)]


def test_no_subscriber_is_an_error_naming_the_key(session):
    with pytest.raises(bus.BusError, match="no subscriber to zenslam/lonely/sensor/frame"):
        play(session, "lonely", _frames(2, 1), CAL, "mono", SourceConfig(), lambda: False, mode="live", start_timeout_s=0.2)


class _LockstepFrontend:
    """Answers lockstep frames with their frontend/state, holding each answer until ``lag`` more frames arrived
    (or none came for 0.3 s): how far ahead the source sends is then visible in what arrives."""

    def __init__(self, session, name: str, lag: int):
        self.lag = lag
        self.unanswered: list[int] = []
        self.most_unanswered = 0
        self.order: list[int] = []
        self._state = bus.declare_publisher(session, keys.frontend_state(name), codec.TRACKING_STATE, "lossless")
        self._frames = bus.subscribe(session, keys.sensor_frame(name), codec.decode_sensor_frame, "lossless", 64)

    def run(self) -> None:
        deadline = time.monotonic() + 10.0
        while not isinstance(message := self._frames.get(timeout_s=0.3), codec.EndOfStream):
            assert time.monotonic() < deadline, "the stream did not end"
            if message is None:  # the source waits for answers: give them
                for index in self.unanswered:
                    self._answer(index)
                self.unanswered.clear()
                continue
            self.order.append(message.frame.index)
            self.unanswered.append(message.frame.index)
            self.most_unanswered = max(self.most_unanswered, len(self.unanswered))
            while len(self.unanswered) > self.lag:
                self._answer(self.unanswered.pop(0))
        for index in self.unanswered:
            self._answer(index)
        self._frames.close()

    def _answer(self, index: int) -> None:
        state = codec.TrackingStateMessage(index, 5_000 + index, "ok", None, 0, {}, False, -1)
        self._state.put(codec.encode_tracking_state(state))


@pytest.mark.parametrize("window", [1, 2, 3])
def test_lockstep_keeps_at_most_frames_in_flight_unanswered_in_order(session, window):
    import threading

    name = f"window-{window}"
    frontend = _LockstepFrontend(session, name, lag=window - 1)  # holds back all it may: a deadlock if the source sent fewer
    thread = threading.Thread(target=frontend.run)
    thread.start()
    config = SourceConfig(frames_in_flight=window, answer_timeout_s=5.0)
    sent = play(session, name, _frames(8, 1), CAL, "mono", config, lambda: False, "test", mode="lockstep", start_timeout_s=5.0)
    thread.join(timeout=10.0)
    assert sent == 8 and not thread.is_alive()
    assert frontend.order == list(range(8))
    assert frontend.most_unanswered == window


def _with_skips(n: int, skipped: dict[int, str]) -> list:
    """Frames 0..n-1 where the indices in ``skipped`` are SkippedFrame with that reason."""
    from zenslam.errors import FrameReadError
    from zenslam.service.sources.frame_stream import SkippedFrame

    frames = _frames(n, 1_000)
    return [
        SkippedFrame(i, skipped[i], FrameReadError(i, f"image /data/{i:06d}.png could not be decoded", f"/data/{i:06d}.png"))
        if i in skipped else frames[i]
        for i in range(n)
    ]  # fmt: skip


def _statuses(inbox: bus.Inbox) -> list:
    out = []
    while (status := inbox.get(timeout_s=1.0)) is not None:
        out.append(status)
        if status.state in ("finished", "failed"):
            return out
    raise AssertionError(f"no final source status among {out}")


def test_lockstep_skips_bad_frames_without_waiting_for_them_and_reports_counts(session, caplog):
    import threading

    name = "skips"
    frontend = _LockstepFrontend(session, name, lag=0)
    statuses = bus.subscribe(session, keys.status(name, "source"), codec.decode_stage_status, "lossless", 64)
    thread = threading.Thread(target=frontend.run)
    thread.start()
    config = SourceConfig(frames_in_flight=1, answer_timeout_s=5.0)
    frames = _with_skips(8, {2: "corrupt", 5: "stamp_repeat", 6: "corrupt"})
    with caplog.at_level("WARNING", logger="zenslam.service.source_node"):
        sent = play(session, name, frames, CAL, "mono", config, lambda: False, "test", mode="lockstep", start_timeout_s=5.0)
    thread.join(timeout=10.0)
    assert sent == 5 and not thread.is_alive()
    assert frontend.order == [0, 1, 3, 4, 7]
    final = _statuses(statuses)[-1]
    statuses.close()
    assert final.state == "finished" and final.processed == 5
    assert final.skipped == {"corrupt": 2, "stamp_repeat": 1}
    warnings = [r.getMessage() for r in caplog.records if "skipping" in r.getMessage()]
    assert len(warnings) == 3  # one per skipped frame
    assert "frame 2: image /data/000002.png could not be decoded [corrupt; 1 frame(s) skipped so far]" in warnings[0]


def test_strict_stops_at_the_first_bad_frame_with_a_failed_status_naming_it(session):
    from zenslam.errors import FrameReadError

    name = "strict"
    inbox = bus.subscribe(session, keys.sensor_frame(name), codec.decode_sensor_frame, "lossless", 64)
    statuses = bus.subscribe(session, keys.status(name, "source"), codec.decode_stage_status, "lossless", 64)
    config = SourceConfig(rate=0.0, strict=True)
    with pytest.raises(FrameReadError, match=r"frame 3: image /data/000003\.png could not be decoded"):
        play(session, name, _with_skips(6, {3: "corrupt"}), CAL, "mono", config, lambda: False, "test", mode="live", start_timeout_s=5.0)
    assert _collect(inbox) == [0, 1, 2, codec.EndOfStream(3)]  # the stream still ends
    final = _statuses(statuses)[-1]
    inbox.close()
    statuses.close()
    assert final.state == "failed" and final.detail.startswith("frame 3: image /data/000003.png could not be decoded")


def test_strict_still_lets_injected_drops_pass(session):
    sent, received = _play(session, "strict-drop", _with_skips(4, {1: "drop"}), SourceConfig(rate=0.0, strict=True))
    assert sent == 3 and received == [0, 2, 3, codec.EndOfStream(3)]


def test_a_frontend_that_ends_its_stream_stops_a_lockstep_source_without_error(session):
    """The frontend was stopped while the source waited for its answer: the source ends its own stream."""
    name = "frontend-stopped"
    frames = bus.subscribe(session, keys.sensor_frame(name), codec.decode_sensor_frame, "lossless", 64)
    states = bus.declare_publisher(session, keys.frontend_state(name), codec.TRACKING_STATE, "lossless")

    def frontend() -> None:  # answers frame 0, then ends its stream instead of answering frame 1
        assert frames.get(timeout_s=10.0).frame.index == 0
        states.put(codec.encode_tracking_state(codec.TrackingStateMessage(0, 5_000, "ok", None, 0, {}, False, -1)))
        assert frames.get(timeout_s=10.0).frame.index == 1
        states.put(codec.encode_end_of_stream(codec.TRACKING_STATE, 1))

    import threading

    thread = threading.Thread(target=frontend)
    thread.start()
    config = SourceConfig(frames_in_flight=1, answer_timeout_s=30.0)
    sent = play(session, name, _frames(8, 1), CAL, "mono", config, lambda: False, "test", mode="lockstep", start_timeout_s=5.0)
    thread.join(timeout=10.0)
    assert sent == 2
    assert frames.get(timeout_s=5.0) == codec.EndOfStream(2)
    frames.close()


class _SlowStates:
    """An inbox whose answer to frame ``index`` comes after ``after_s`` seconds."""

    def __init__(self, index: int, after_s: float):
        self._due, self._index = time.monotonic() + after_s, index

    def get(self, timeout_s: float):
        time.sleep(min(timeout_s, 0.01))
        if time.monotonic() < self._due:
            return None
        return codec.TrackingStateMessage(index=self._index, stamp_ns=0, state="ok")


class _Frontend:
    """A frontend's liveliness as bus.Comebacks reports it: ``gone`` until ``back_after_s``, when it
    returns (a restart); never back when ``back_after_s`` is None."""

    def __init__(self, gone: bool = False, back_after_s: float | None = None):
        self.gone = gone
        self._back_at = None if back_after_s is None else time.monotonic() + back_after_s
        self._returned = False

    def returned(self) -> bool:
        if self.gone and self._back_at is not None and time.monotonic() >= self._back_at:
            self.gone, self._returned = False, True
        back, self._returned = self._returned, False
        return back


def _window(states, frontend, resent: list[bytes], timeout_s: float = 0.1, restart_wait_s: float = 0.3):
    window = source_node._AnswerWindow(states, frontend, resent.append, timeout_s, restart_wait_s, lambda: False)
    window.sent(4, b"frame 4")
    window.sent(5, b"frame 5")
    return window


def test_lockstep_waits_past_the_timeout_while_the_frontend_runs(caplog):
    window = _window(_SlowStates(4, 0.5), _Frontend(), [])
    with caplog.at_level("WARNING", logger="zenslam.service.source_node"):
        assert window.wait_for_oldest()
    assert len(window) == 1
    assert any("no answer to frame 4" in r.getMessage() and "frontend is running" in r.getMessage() for r in caplog.records)


def test_lockstep_fails_when_the_frontend_is_gone_and_does_not_come_back():
    window = _window(_SlowStates(4, 60.0), _Frontend(gone=True), [])
    with pytest.raises(bus.BusError, match="frontend is gone with frame 4 unanswered and did not come back within 0 s"):
        window.wait_for_oldest()


def test_a_restarted_frontend_gets_the_frames_in_flight_again_oldest_first(caplog):
    resent: list[bytes] = []
    window = _window(_SlowStates(4, 0.4), _Frontend(gone=True, back_after_s=0.2), resent, restart_wait_s=5.0)
    with caplog.at_level("WARNING", logger="zenslam.service.source_node"):
        assert window.wait_for_oldest()
    assert resent == [b"frame 4", b"frame 5"] and window.resent == 2
    assert len(window) == 1
    assert any("frontend restarted: sending its 2 frame(s) in flight again" in r.getMessage() for r in caplog.records)


def test_a_later_frames_answer_settles_the_frames_before_it():
    """A frame the crashed frontend held that never reached its successor is not waited for forever."""
    window = _window(_SlowStates(5, 0.0), _Frontend(), [])
    assert window.wait_for_oldest()
    assert len(window) == 0
