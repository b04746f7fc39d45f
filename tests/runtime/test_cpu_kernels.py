"""Pinned math kernels: which variables, merged with the caller's, only on x86-64, and what a child process then computes."""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys

import pytest

from zenslam.runtime import cpu_kernels

# A child's view: numpy's active dispatch targets, and digests of results that depend on the kernels picked.
_CHILD = """
import hashlib, json, math
import cv2
import numpy as np
try:
    from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
except ImportError:
    from numpy.core._multiarray_umath import __cpu_dispatch__, __cpu_features__
rng = np.random.default_rng(7)
x = rng.uniform(-20.0, 20.0, 20001)
a, b = rng.normal(size=(64, 64)), rng.normal(size=(64, 64))
keys = rng.integers(0, 30, 20001)
digest = lambda *arrays: hashlib.sha1(b"".join(np.ascontiguousarray(v).tobytes() for v in arrays)).hexdigest()
print(json.dumps({
    "active": [t for t in __cpu_dispatch__ if __cpu_features__.get(t)],
    "blas": digest(a @ b, np.linalg.solve(a, b[:, 0]), np.linalg.svd(a)[1]),
    "numpy": digest(np.exp(x), np.log(np.abs(x) + 0.1), np.arcsin(x / 20.0), np.sin(x.astype(np.float32)), np.argsort(keys)),
    "libm": digest(np.array([math.exp(v) + math.atan(v) + math.tan(v) for v in x])),
    "opencv": digest(cv2.ORB_create(500).detectAndCompute(cv2.GaussianBlur(rng.integers(0, 256, (240, 320), dtype=np.uint8), (5, 5), 1.5), None)[1]),
    "opencv_disabled": [f for f in cv2.getCPUFeaturesLine().split() if f.startswith("*") and not f.endswith("?")],
}))
"""


def _child(env: dict[str, str]) -> dict:
    result = subprocess.run([sys.executable, "-c", _CHILD], env=env, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    return json.loads(result.stdout)


def test_the_pins_on_x86_64():
    env = cpu_kernels.with_pinned_kernels({"PATH": "/bin", "GLIBC_TUNABLES": "glibc.malloc.arena_max=2"}, machine="x86_64")
    assert env["PATH"] == "/bin" and env["OPENBLAS_CORETYPE"] == "Nehalem"
    assert env["NPY_DISABLE_CPU_FEATURES"].split() == list(cpu_kernels.numpy_dispatch_targets())
    assert env["OPENCV_CPU_DISABLE"].split(",") == list(cpu_kernels.opencv_dispatch_targets())
    assert env["GLIBC_TUNABLES"] == "glibc.malloc.arena_max=2:glibc.cpu.hwcaps=-FMA,-FMA4"
    assert cpu_kernels.with_pinned_kernels({}, machine="AMD64")["OPENBLAS_CORETYPE"] == "Nehalem"


def test_other_architectures_keep_their_environment():
    env = {"PATH": "/bin", "OPENBLAS_CORETYPE": "NEOVERSEN1"}
    assert cpu_kernels.with_pinned_kernels(env, machine="aarch64") == env


def test_hwcaps_masks_merge_with_the_callers():
    merged = cpu_kernels.with_hwcaps_mask("glibc.cpu.hwcaps=-AVX512F,-FMA:glibc.malloc.arena_max=2", ("-FMA", "-FMA4"))
    assert merged == "glibc.cpu.hwcaps=-AVX512F,-FMA,-FMA4:glibc.malloc.arena_max=2"
    assert cpu_kernels.with_hwcaps_mask("", ("-FMA",)) == "glibc.cpu.hwcaps=-FMA"


def test_a_callers_kernel_choice_is_replaced_with_a_warning(caplog):
    with caplog.at_level(logging.WARNING, logger=cpu_kernels.__name__):
        env = cpu_kernels.with_pinned_kernels({"OPENBLAS_CORETYPE": "Haswell"}, machine="x86_64")
    assert env["OPENBLAS_CORETYPE"] == "Nehalem"
    assert "OPENBLAS_CORETYPE=Haswell replaced by Nehalem" in caplog.text


@pytest.mark.skipif(not sys.platform.startswith("linux") or os.uname().machine != "x86_64", reason="pins x86-64 Linux kernels")
def test_a_pinned_child_computes_the_same_bits_whatever_kernels_its_parent_asked_for():
    base = {k: v for k, v in os.environ.items() if k not in cpu_kernels.kernel_pins({})}
    pinned = _child(cpu_kernels.with_pinned_kernels(base))
    assert pinned["active"] == [] and pinned["opencv_disabled"] == []  # numpy and OpenCV run their baseline code
    # The caller asks for other kernels: the pins replace its choice (so the child never sees a core
    # this CPU may lack) and the bits stay the same.
    asked = {
        **base, "OPENBLAS_CORETYPE": "Haswell", "NPY_DISABLE_CPU_FEATURES": cpu_kernels.numpy_dispatch_targets()[-1],
        "OPENCV_CPU_DISABLE": cpu_kernels.opencv_dispatch_targets()[-1],
    }  # fmt: skip
    assert _child(cpu_kernels.with_pinned_kernels(asked)) == pinned
    # libm without FMA variants: masking more of glibc's choices (AVX, AVX2) changes nothing further.
    fewer = cpu_kernels.with_pinned_kernels({**base, "GLIBC_TUNABLES": "glibc.cpu.hwcaps=-AVX,-AVX2"})
    assert _child(fewer)["libm"] == pinned["libm"]

