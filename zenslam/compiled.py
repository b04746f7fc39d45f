"""How zenslam compiles its numeric kernels: numba, nopython, cached on disk, GIL released, IEEE arithmetic."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

import numba
import numpy as np

F = TypeVar("F", bound=Callable)


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


def kernel_array(array: np.ndarray, dtype: type) -> np.ndarray:
    """``array`` as a C-contiguous, writable array of ``dtype``, copied only when it is not one.

    numba compiles a kernel once per argument type, and a read-only array (a message's, a view's)
    is another type: kernels that take arrays from such callers keep one signature this way.
    """
    return np.require(array, dtype, ("C", "W"))
