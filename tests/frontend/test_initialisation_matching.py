"""Monocular initialisation matching (ORB-SLAM's SearchForInitialization) on rendered images."""

import numpy as np
import pytest

from zenslam.frontend.frame import make_mono_frame
from zenslam.frontend.initialisation_matching import InitialisationMatchingConfig, search_for_initialisation
from zenslam.frontend.orb_extractor import OrbExtractor
from zenslam.service.sources import open_source


@pytest.fixture(scope="module")
def scene():
    source = open_source("synthetic:loop/mono")
    return source, OrbExtractor()


def _frame(scene, index, shift_px=0):
    source, extractor = scene
    image = source.frame(index).left
    if shift_px:
        image = np.ascontiguousarray(np.roll(image, shift_px, axis=1))
    return make_mono_frame(index, index, image, source.calibration, extractor)


def test_a_frame_matches_itself(scene):
    frame = _frame(scene, 0)
    match = search_for_initialisation(frame, frame, frame.features.px)
    finest = np.flatnonzero(frame.features.level == 0)
    matched = finest[match[finest] >= 0]
    assert len(matched) > 0.9 * len(finest)
    np.testing.assert_array_equal(match[matched], matched)
    assert (match[frame.features.level > 0] == -1).all()  # only the finest level is searched


def test_shifted_image_matches_shifted_keypoints(scene):
    ref, cur = _frame(scene, 0), _frame(scene, 0, shift_px=9)
    match = search_for_initialisation(ref, cur, ref.features.px)
    idx = np.flatnonzero(match >= 0)
    assert len(idx) > 0.5 * np.count_nonzero(ref.features.level == 0)
    offset = cur.features.px[match[idx]] - ref.features.px[idx]
    inside = np.abs(offset[:, 0] - 9) < 1.5
    assert inside.mean() > 0.95
    assert np.abs(offset[inside, 1]).max() < 1.5
    assert len(np.unique(match[idx])) == len(idx)  # one to one


def test_window_bounds_the_search(scene):
    ref, cur = _frame(scene, 0), _frame(scene, 0, shift_px=30)
    small = search_for_initialisation(ref, cur, ref.features.px, InitialisationMatchingConfig(window_px=10))
    assert np.count_nonzero(small >= 0) < 0.05 * np.count_nonzero(ref.features.level == 0)
    # Searching around where the keypoints were last matched finds them again.
    moved = search_for_initialisation(ref, cur, ref.features.px + [30, 0], InitialisationMatchingConfig(window_px=10))
    assert np.count_nonzero(moved >= 0) > 0.5 * np.count_nonzero(ref.features.level == 0)
