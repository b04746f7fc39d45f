"""Key expressions: one session's keys under zenslam/<session>/, matched by the session wildcard, names checked."""

from __future__ import annotations

import pytest
import zenoh

from zenslam.errors import ConfigError
from zenslam.schemas import keys

DATA_KEYS = [
    keys.sensor_frame,
    keys.frontend_pose,
    keys.frontend_state,
    keys.frontend_keyframe,
    keys.backend_map_update,
    keys.backend_loop,
    keys.backend_map_query,
    keys.backend_trajectory_query,
    keys.backend_relocalisation_query,
]


def test_keys_are_under_the_session_and_distinct():
    built = [f("run-1") for f in DATA_KEYS] + [keys.status("run-1", s) for s in keys.STAGES]
    assert len(set(built)) == len(built)
    everything = zenoh.KeyExpr(keys.everything("run-1"))
    for key in built:
        assert key.startswith("zenslam/run-1/")
        assert everything.intersects(zenoh.KeyExpr(key)), key


def test_the_documented_layout():
    assert keys.sensor_frame("s") == "zenslam/s/sensor/frame"
    assert keys.frontend_pose("s") == "zenslam/s/frontend/pose"
    assert keys.frontend_keyframe("s") == "zenslam/s/frontend/keyframe"
    assert keys.backend_map_update("s") == "zenslam/s/backend/map_update"
    assert keys.status("s", "frontend") == "zenslam/s/frontend/status"
    assert keys.alive("s", "source") == "zenslam/s/alive/source"


def test_sessions_do_not_see_each_other():
    other = zenoh.KeyExpr(keys.everything("a"))
    assert not other.intersects(zenoh.KeyExpr(keys.frontend_pose("b")))


def test_status_wildcard_matches_every_stage():
    pattern = zenoh.KeyExpr(keys.all_status("s"))
    assert all(pattern.intersects(zenoh.KeyExpr(keys.status("s", stage))) for stage in keys.STAGES)
    assert not pattern.intersects(zenoh.KeyExpr(keys.frontend_pose("s")))


@pytest.mark.parametrize("name", ["", "a/b", "x*", "$y", "has space", "@hidden", "q?"])
def test_bad_session_names_are_refused(name):
    with pytest.raises(ConfigError, match="cannot be a zenoh key chunk"):
        keys.frontend_pose(name)


def test_run_ids_with_dates_are_fine():
    assert keys.frontend_state("20260314-091502-4242") == "zenslam/20260314-091502-4242/frontend/state"
