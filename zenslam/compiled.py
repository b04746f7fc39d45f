"""How zenslam compiles its numeric kernels: numba, nopython, cached on disk, GIL released, IEEE arithmetic."""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import TypeVar

import numba
import numpy as np

F = TypeVar("F", bound=Callable)

# The module whose import tells numba a BLAS is there (numba/np/linalg.py's ensure_blas).
_SCIPY_BLAS = "scipy.linalg.cython_blas"


def _load_numpy_support_without_scipy() -> None:
    """Load numba's numpy support without scipy.linalg: its first import (at a process's first
    kernel load) imports scipy.linalg to find a BLAS for ``np.dot`` and ``np.linalg`` in nopython
    code (``numba.np.arraymath._HAVE_BLAS``). No zenslam kernel calls either; scipy.linalg costs
    each stage that loads kernels ~0.35 s of CPU and ~27 MB at start (benchmarks/footprint.md).

    The BLAS module reads as missing only while numba's numpy support is imported: a kernel that
    calls ``np.dot`` then fails to compile with numba's "scipy 0.16+ is required" (never a wrong
    result), and scipy itself imports as usual for whoever uses it afterwards.
    """
    if _SCIPY_BLAS in sys.modules or "numba.np.arraymath" in sys.modules:
        return  # scipy.linalg already loaded, or numba's numpy support already decided
    sys.modules[_SCIPY_BLAS] = None  # type: ignore[assignment]  # import of it raises ImportError
    try:
        import numba.np.arraymath  # noqa: F401  (its _check_blas runs here)
    finally:
        del sys.modules[_SCIPY_BLAS]


_load_numpy_support_without_scipy()


def kernel(function: F) -> F:
    """``function`` compiled by numba in nopython mode.

    cache=True: the machine code is written beside the module (or to numba's user cache dir when
    the package is not writable, or to NUMBA_CACHE_DIR) and loaded by every later process, so
    only the first start on a machine pays the compile. nogil=True: the two images of a stereo
    pair are extracted in two threads. fastmath stays off: without it LLVM neither reassociates
    nor contracts floating-point operations, so the result has the same bits on every x86-64
    target numba may compile for (tests/test_compiled.py checks the generic one against the host's).
    """
    return numba.njit(cache=True, nogil=True, fastmath=False)(function)


def inlined_kernel(function: F) -> F:
    """``kernel``, inlined into the kernels that call it (numba's ``inline="always"``, on its IR).

    A call from one kernel to another is otherwise a real call, with numba's status and exception
    handling around it: in a loop over every pixel, the helpers it calls cost more than their work.
    """
    return numba.njit(cache=True, nogil=True, fastmath=False, inline="always")(function)


def kernel_array(array: np.ndarray, dtype: type) -> np.ndarray:
    """``array`` as a C-contiguous, writable array of ``dtype``, copied only when it is not one.

    numba compiles a kernel once per argument type, and a read-only array (a message's, a view's)
    is another type: kernels that take arrays from such callers keep one signature this way.
    """
    return np.require(array, dtype, ("C", "W"))
