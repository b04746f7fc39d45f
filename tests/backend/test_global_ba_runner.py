"""Global BA runner: in place (lockstep) and in a helper process (pipelined, live) reach the same map."""

from __future__ import annotations

import time

import numpy as np
import pytest

from zenslam.backend.global_ba import GlobalBAConfig
from zenslam.backend.global_ba_runner import GlobalBARunner
from zenslam.backend.local_mapping import BAWindowConfig
from test_global_ba import perturbed_map  # noqa: E402  (tests/backend is on the path under pytest)


def poses_and_points(bmap):
    return (
        np.stack([bmap.keyframes[k].T_world_cam for k in sorted(bmap.keyframes)]),
        np.stack([bmap.points[p].p_world for p in sorted(bmap.points)]),
    )


@pytest.mark.slow(12)  # the helper process imports numpy and gtsam
def test_in_place_and_in_a_helper_process_give_the_same_map():
    in_place, _, _ = perturbed_map()
    runner = GlobalBARunner(in_place, GlobalBAConfig(), BAWindowConfig(), in_background=False)
    assert runner.start() is True and runner.applied == 1  # applied before start() returns
    assert in_place.take_changes().keyframes  # the correction lists what moved

    background, _, _ = perturbed_map()
    before = poses_and_points(background)
    runner = GlobalBARunner(background, GlobalBAConfig(), BAWindowConfig(), in_background=True)
    try:
        assert runner.start() is False and runner.running
        deadline = time.monotonic() + 120
        while not runner.poll():
            assert time.monotonic() < deadline, "the helper process gave no result within 120 s"
            time.sleep(0.05)
    finally:
        runner.close()
    assert runner.applied == 1 and not runner.running
    after = poses_and_points(background)
    assert not np.array_equal(before[1], after[1])
    for a, b in zip(poses_and_points(in_place), after):
        np.testing.assert_array_equal(a, b)  # same kernels, same numbers


def test_run_in_place_refines_the_map_as_it_is_now():
    """The global BA before a map is saved: solved and applied before it returns, whatever the runner's mode."""
    from test_global_ba import errors, perturbed_map as scene  # noqa: E402

    bmap, poses, points = scene()
    before = errors(bmap, poses, points)
    runner = GlobalBARunner(bmap, GlobalBAConfig(), BAWindowConfig(), in_background=True)
    try:
        assert runner.run_in_place() is True and runner.applied == 1 and not runner.running
    finally:
        runner.close()
    after = errors(bmap, poses, points)
    assert after[0] < before[0] / 3 and after[2] < before[2] / 1.5  # as test_global_ba's bounds
    assert bmap.take_changes().points
