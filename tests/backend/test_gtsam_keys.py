"""GTSAM keys: stable, invertible, and defined for both point id spaces including ids >= 2**62."""

import gtsam
import numpy as np
import pytest

from zenslam.backend.gtsam_keys import (
    bias_key,
    key_kind,
    keyframe_id_of_key,
    landmark_index,
    landmark_key,
    landmark_keys,
    point_id_of_key,
    pose_key,
    pose_keys,
    velocity_key,
)
from zenslam.errors import ZenslamError
from zenslam.schemas.map_update import BACKEND_POINT_ID_BASE


def test_keys_are_gtsam_symbols_with_the_house_characters():
    assert pose_key(7) == gtsam.symbol_shorthand.X(7)
    assert velocity_key(7) == gtsam.symbol_shorthand.V(7)
    assert bias_key(7) == gtsam.symbol_shorthand.B(7)
    assert landmark_key(7) == gtsam.symbol_shorthand.L(7)  # frontend ids are their own index
    assert [key_kind(k) for k in (pose_key(1), velocity_key(1), bias_key(1), landmark_key(1))] == ["x", "v", "b", "l"]
    assert gtsam.Symbol(landmark_key(123)).string() == "l123"


def test_backend_point_ids_above_2_62_map_into_the_upper_half_and_back():
    ids = [BACKEND_POINT_ID_BASE, BACKEND_POINT_ID_BASE + 1, BACKEND_POINT_ID_BASE + 2**55 - 1]
    for point_id in ids:
        key = landmark_key(point_id)
        assert key_kind(key) == "l"
        assert landmark_index(point_id) == 2**55 + (point_id - BACKEND_POINT_ID_BASE)
        assert point_id_of_key(key) == point_id
    assert landmark_key(2**55 - 1) != landmark_key(BACKEND_POINT_ID_BASE)  # the two halves never collide
    assert point_id_of_key(landmark_key(2**55 - 1)) == 2**55 - 1


def test_mapping_is_injective_and_order_preserving_over_mixed_ids():
    rng = np.random.default_rng(0)
    frontend = rng.integers(0, 2**40, 500)
    backend = BACKEND_POINT_ID_BASE + rng.integers(0, 2**40, 500)
    ids = np.unique(np.concatenate([frontend, backend]).astype(np.int64))
    keys = landmark_keys(ids)
    assert len(set(keys)) == len(ids)
    assert keys == sorted(keys)  # ascending ids give ascending keys (gtsam's Values order)
    assert [point_id_of_key(k) for k in keys] == ids.tolist()


def test_keyframe_keys_round_trip():
    ids = np.array([0, 5, 2**56 - 1], dtype=np.int64)
    assert [keyframe_id_of_key(k) for k in pose_keys(ids)] == ids.tolist()
    assert keyframe_id_of_key(velocity_key(9)) == 9 and keyframe_id_of_key(bias_key(9)) == 9


@pytest.mark.parametrize("point_id", [-1, 2**55, BACKEND_POINT_ID_BASE - 1, BACKEND_POINT_ID_BASE + 2**55])
def test_ids_outside_both_point_spaces_raise_naming_the_id(point_id):
    with pytest.raises(ZenslamError, match=str(point_id)):
        landmark_key(point_id)


def test_bad_keyframe_ids_and_wrong_key_kinds_raise():
    with pytest.raises(ZenslamError, match="-3"):
        pose_key(-3)
    with pytest.raises(ZenslamError, match="not a landmark key"):
        point_id_of_key(pose_key(1))
    with pytest.raises(ZenslamError, match="not a keyframe key"):
        keyframe_id_of_key(landmark_key(1))
