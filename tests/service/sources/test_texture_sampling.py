"""The synthetic renderer's texture sampler: exact bilinear interpolation, OpenCV's conventions, the same
bits whatever OpenCV's CPU dispatch picks."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys

import cv2
import numpy as np
import pytest

from zenslam.runtime import cpu_kernels
from zenslam.service.sources.synthetic.tile_raster import _reflect_101, sample_bilinear

RNG = np.random.default_rng(3)
TEXTURE = RNG.integers(0, 256, size=(37, 53), dtype=np.uint8)
# A perspective map from a 60 x 40 block of pixels onto the texture, reaching past its borders.
M = np.array([[0.9, 0.12, -1.7], [-0.05, 1.05, -0.8], [2e-3, -1e-3, 1.0]])


def block(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    return np.arange(width, dtype=np.float64)[None, :], np.arange(height, dtype=np.float64)[:, None]


def test_reflect_101_folds_as_opencv_border_interpolate() -> None:
    for size in (1, 2, 5, 37):
        index = np.arange(-3 * size - 2, 4 * size + 3)
        expected = [cv2.borderInterpolate(int(i), size, cv2.BORDER_REFLECT_101) for i in index]
        assert [_reflect_101(int(i), size) for i in index] == expected


def test_each_pixel_is_the_bilinear_interpolation_at_its_projected_centre() -> None:
    cols, rows = block(60, 40)
    sampled = sample_bilinear(TEXTURE, M, cols, rows)
    assert sampled.shape == (40, 60) and sampled.dtype == np.uint8
    padded = TEXTURE.astype(np.float64)
    h, w = TEXTURE.shape
    for row, col in RNG.integers(0, (40, 60), size=(200, 2)):
        x, y, s = M @ (col, row, 1.0)
        x, y = x / s, y / s
        ix, iy = int(np.floor(x)), int(np.floor(y))
        ax, ay = x - ix, y - iy
        at = lambda c, r: padded[  # noqa: E731
            cv2.borderInterpolate(r, h, cv2.BORDER_REFLECT_101), cv2.borderInterpolate(c, w, cv2.BORDER_REFLECT_101)
        ]
        value = (1 - ay) * ((1 - ax) * at(ix, iy) + ax * at(ix + 1, iy)) + ay * (
            (1 - ax) * at(ix, iy + 1) + ax * at(ix + 1, iy + 1)
        )
        assert abs(int(sampled[row, col]) - value) <= 0.5 + 1e-3


def test_identity_and_whole_texel_shifts_copy_the_texture() -> None:
    h, w = TEXTURE.shape
    cols, rows = block(w, h)
    assert np.array_equal(sample_bilinear(TEXTURE, np.eye(3), cols, rows), TEXTURE)
    shift = np.array([[1.0, 0.0, 2.0], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]])
    shifted = sample_bilinear(TEXTURE, shift, cols, rows)
    assert np.array_equal(shifted[: h - 1, : w - 2], TEXTURE[1:, 2:])


def test_a_mask_samples_only_its_pixels_in_row_major_order() -> None:
    cols, rows = block(60, 40)
    mask = RNG.random((40, 60)) < 0.3
    assert np.array_equal(sample_bilinear(TEXTURE, M, cols, rows, mask), sample_bilinear(TEXTURE, M, cols, rows)[mask])


def test_it_follows_warp_perspective_conventions() -> None:
    """Same pixel-centre and inverse-map conventions as OpenCV: the two differ only by OpenCV's rounding
    (1/32-texel coordinates in 4.x), never by half a pixel."""
    cols, rows = block(60, 40)
    ours = sample_bilinear(TEXTURE, M, cols, rows).astype(int)
    opencv = cv2.warpPerspective(
        TEXTURE, M, (60, 40), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REFLECT_101
    ).astype(int)
    difference = np.abs(ours - opencv)
    assert np.mean(difference) < 1.0
    assert np.mean(difference <= 2) > 0.97


FRAME_DIGEST = """
import hashlib
from zenslam.service.sources.synthetic import SyntheticSource, scene_config
source = SyntheticSource(scene_config("loop", width=320, height=240, fx=230.0, fy=230.0, cx=159.5, cy=119.5))
digest = hashlib.sha256()
for index in (0, 100):
    frame = source.frame(index)
    digest.update(frame.left.tobytes())
    digest.update(frame.right.tobytes())
print(digest.hexdigest())
"""


@pytest.mark.slow(20)
def test_synthetic_frames_do_not_depend_on_the_machines_math_kernels() -> None:
    """The frames made with the machine's own kernel choices (OpenCV's, numpy's and OpenBLAS's CPU
    dispatch) equal those made with every kernel pinned to the x86-64 baseline, as the stage
    processes run (``cpu_kernels``). OpenCV 5.0's warpPerspective, the old renderer, gave other pixels
    on its AVX2 path than on its baseline one; the scenes are the input of every synthetic test and
    in-process benchmark, which run unpinned, so they must be the same on every CPU."""
    machine_env = {k: v for k, v in os.environ.items() if k not in cpu_kernels.kernel_pins({})}
    digests = []
    for env in (machine_env, cpu_kernels.with_pinned_kernels(machine_env)):
        run = subprocess.run([sys.executable, "-c", FRAME_DIGEST], capture_output=True, text=True, env=env, timeout=300)
        assert run.returncode == 0, run.stderr
        digests.append(run.stdout.strip())
    assert digests[0] == digests[1]
    assert len(digests[0]) == len(hashlib.sha256().hexdigest())
