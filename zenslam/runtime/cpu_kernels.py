"""One choice of math kernels for the stage processes, so lockstep output has the same bits on any x86-64 CPU.

Several libraries pick their code paths at run time by CPU model. Different paths round
differently in the last bits, and one differing bit is enough for a lockstep run to diverge
(a keypoint kept or dropped, a point culled or not), so a recording made on one machine would
not replay on another. The supervisor therefore starts every stage with the environment of
``with_pinned_kernels``, which makes each such library take a path that every x86-64 CPU able to
run the installed wheels has. Each pin was checked by running the lockstep KITTI clip with that
library's choice varied, and by probing the functions concerned (the figures are in
benchmarks/stage_processes.md):

- OpenBLAS (numpy's copy, and scipy's and OpenCV's): OPENBLAS_CORETYPE=Nehalem. OpenBLAS picks its
  BLAS/LAPACK kernels (SkylakeX, Haswell, Zen, ...) by CPU model, and numpy's matmul, dot and
  linalg results differ between them; the KITTI poses differ from the second frame on. A forced
  core whose instructions the CPU lacks crashes, and an unknown name silently falls back to
  detection; Nehalem's SSE kernels run on every x86-64-v2 CPU, which numpy's wheels require.
- numpy's own SIMD dispatch: NPY_DISABLE_CPU_FEATURES=<every target the installed numpy dispatches
  to>, leaving the baseline the build requires of any CPU. numpy picks AVX2 or AVX-512 loops for
  float64 exp, log, tan, arcsin, ... (AVX-512 SVML), float32 sin, cos, exp, log, ... and for
  sort, argsort and argpartition (x86-simd-sort, which orders equal keys differently); the KITTI
  poses differ between its AVX-512 and AVX2 choices.
- OpenCV's own dispatch: OPENCV_CPU_DISABLE=<every feature the installed OpenCV dispatches to>,
  leaving the SSE3 baseline its build requires. The ORB features of KITTI frames differed
  between its AVX2 path and the paths CPUs without AVX2 take (its AVX-512 path agreed with AVX2):
  ORB.compute's descriptors, for about 1 keypoint in 10,000. The frontend no longer calls it (its
  rBRIEF kernel, ``frontend/orb_descriptor``), and every OpenCV function it does call (resize,
  FAST, copyMakeBorder, batchDistance, solvePnP's EPnP, Rodrigues) gives the same bits on both
  paths (tests/runtime/test_opencv_dispatch.py), so the frontend process, where OpenCV is hot,
  runs OpenCV's own choice: the pin slowed its extraction markedly (benchmarks/frontend.md).
  The other stages keep the pin, where it costs next to nothing.
- glibc's libm: GLIBC_TUNABLES glibc.cpu.hwcaps=-FMA,-FMA4. libm has FMA variants of exp, log, pow,
  atan2, acos, tan, ... that it uses on CPUs with FMA and AVX2; now and then a result differs in
  the last bit from the SSE2 variants that CPUs without FMA get. Python's
  math module, numpy's baseline float64 exp/log/power/arctan2/arccos (once its SIMD dispatch is
  pinned: the stages call these), OpenCV and GTSAM call them. The KITTI clip hit none of the
  differing results, but other inputs will; the pin costs next to nothing.

Checked and left alone: numba's target CPU (NUMBA_CPU_NAME). zenslam's kernels compile without
fastmath, so LLVM keeps every floating-point operation as written whatever instructions it picks,
and tests/test_compiled.py checks that the generic x86-64 build gives the same features as the
machine's own; pinning generic would only cost the wider vector code. OpenCV's Intel IPP paths
(OPENCV_IPP=disabled or sse42 against its AVX-512 choice) gave the same bits on KITTI. Not pinnable from outside: GTSAM's Eigen blocks
large matrix products by the CPU's L1 data cache size (read with cpuid), which changes the
summation order of products whose inner dimension exceeds a few hundred, so machines with
different L1 caches (48 KiB on recent Intel cores, 32 KiB on most others) may differ in such
products; GTSAM's Python bindings do not expose Eigen's setCpuCacheSizes.

Other architectures keep their libraries' own choices: the pins name x86-64 code paths.
"""

from __future__ import annotations

import logging
import platform
from collections.abc import Mapping

logger = logging.getLogger(__name__)

X86_64_MACHINES = frozenset({"x86_64", "amd64"})  # platform.machine() on Linux/macOS and Windows, lower-cased
# Stage modules whose OpenCV calls give the same bits on every OpenCV dispatch path (see above).
OPENCV_DISPATCH_FREE_STAGES = frozenset({"zenslam.frontend.node"})
OPENBLAS_CORETYPE = "Nehalem"
LIBM_HWCAPS_MASK = ("-FMA", "-FMA4")  # glibc.cpu.hwcaps entries: treat the CPU as lacking FMA and FMA4
_HWCAPS = "glibc.cpu.hwcaps"


def numpy_dispatch_targets() -> tuple[str, ...]:
    """The instruction-set targets the installed numpy compiled extra loops for, beyond its baseline."""
    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__
    except ImportError:  # numpy < 2
        from numpy.core._multiarray_umath import __cpu_dispatch__
    return tuple(__cpu_dispatch__)


def opencv_dispatch_targets() -> tuple[str, ...]:
    """The CPU features the installed OpenCV compiled extra code paths for, beyond its baseline
    (the entries marked ``*`` in ``cv2.getCPUFeaturesLine()``, in OpenCV's spelling: ``SSE4.1``, ``AVX512-SKX``)."""
    import cv2

    return tuple(item.strip("*?") for item in cv2.getCPUFeaturesLine().split() if item.startswith("*"))


def with_hwcaps_mask(tunables: str, mask: tuple[str, ...]) -> str:
    """A GLIBC_TUNABLES value (``name=value:name=value``) with ``mask`` added to its glibc.cpu.hwcaps list."""
    entries = [entry for entry in tunables.split(":") if entry]
    for i, entry in enumerate(entries):
        name, _, value = entry.partition("=")
        if name == _HWCAPS:
            present = [item for item in value.split(",") if item]
            entries[i] = f"{_HWCAPS}={','.join(present + [m for m in mask if m not in present])}"
            return ":".join(entries)
    return ":".join(entries + [f"{_HWCAPS}={','.join(mask)}"])


def kernel_pins(env: Mapping[str, str], opencv: bool = True) -> dict[str, str]:
    """The environment variables (name -> value) that pin the math kernels, given the environment ``env``
    they are added to (whose GLIBC_TUNABLES they extend); without ``opencv``, OpenCV's dispatch is left alone."""
    pins = {
        "OPENBLAS_CORETYPE": OPENBLAS_CORETYPE,
        "NPY_DISABLE_CPU_FEATURES": " ".join(numpy_dispatch_targets()),
        "OPENCV_CPU_DISABLE": ",".join(opencv_dispatch_targets()),
        "GLIBC_TUNABLES": with_hwcaps_mask(env.get("GLIBC_TUNABLES", ""), LIBM_HWCAPS_MASK),
    }
    if not opencv:
        del pins["OPENCV_CPU_DISABLE"]
    return pins


def with_pinned_kernels(env: Mapping[str, str], machine: str | None = None, opencv: bool = True) -> dict[str, str]:
    """``env`` with the math kernels pinned (see the module docstring) when ``machine`` (default: this
    one's ``platform.machine()``) is x86-64; ``env`` unchanged otherwise. A value the caller set for a
    pinned variable is replaced, with a warning: lockstep output must not depend on it. Without
    ``opencv``, OpenCV's dispatch is not pinned (a process whose OpenCV calls do not depend on it)."""
    pinned = dict(env)
    if (machine or platform.machine()).lower() not in X86_64_MACHINES:
        return pinned
    for name, value in kernel_pins(env, opencv).items():
        given = env.get(name)
        if given is not None and given != value and name != "GLIBC_TUNABLES":
            logger.warning("%s=%s replaced by %s for the stage processes: their results must not depend on the CPU", name, given, value)
        pinned[name] = value
    return pinned
