"""One BLAS thread for the prediction's many small products (OpenBLAS on Linux).

The closed-loop prediction (:func:`idstlpy.executor.predict.predict_closed_loop`) pushes about a
thousand samples through every plan step: per step a few dozen matrix products of a few million
flops each, too small to gain from threads. OpenBLAS still splits each of them over its threads,
and those threads busy-wait for each other: on a machine whose cores are shared with other
processes one such product took 84 ms on two threads against 0.1 ms on one (a 1000 x 48 by
1000 x 48 cross-product, 2-core machine at load 4.7; ``benchmarks/prediction_cost_results.md``).

:func:`single_blas_thread` runs a block with every loaded OpenBLAS (numpy's and scipy's bundled
copies, or a system one) limited to one thread and restores the previous counts afterwards. It
finds the libraries among the process's loaded objects (``/proc/self/maps``, read once, after
numpy and scipy's linear algebra are imported) and calls their ``*openblas_set_num_threads*``
entry points, as ``threadpoolctl`` does; where that is not possible (another operating system,
another BLAS) it does nothing.

What it changes in the numbers: a product that OpenBLAS would have split over threads is the
same sum in the same order on one thread, but LAPACK's blocked routines (``eigh``, ``solve``) may
round differently: the samples, their moments and the rates they give do not change, the
regression of the particle closure's transitions can change in its last bits (measured in
``benchmarks/prediction_cost_results.md``).
"""

from __future__ import annotations

import ctypes
import logging
import os
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager

import numpy  # noqa: F401  (loads numpy's OpenBLAS before the one look at the loaded libraries)
import scipy.linalg  # noqa: F401  (and scipy's)

__all__ = ["single_blas_thread"]

logger = logging.getLogger(__name__)

_ENTRY_POINTS = (
    # (get, set) as exported by numpy's / scipy's bundled OpenBLAS (64-bit and 32-bit integers)
    # and by a system OpenBLAS
    ("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"),
    ("scipy_openblas_get_num_threads", "scipy_openblas_set_num_threads"),
    ("openblas_get_num_threads64_", "openblas_set_num_threads64_"),
    ("openblas_get_num_threads", "openblas_set_num_threads"),
)

_lock = threading.Lock()
_depth = 0
_saved: list[tuple[object, object, int]] = []  # (get, set, previous count) per library
_found: list[ctypes.CDLL] | None = None  # the libraries, looked up once (2-3 ms a look)


def _loaded_openblas() -> list[ctypes.CDLL]:
    """The OpenBLAS libraries this process has loaded (Linux; none elsewhere), looked up once."""
    global _found
    if _found is not None:
        return _found
    _found = []
    if not sys.platform.startswith("linux"):
        return _found
    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as fh:
            paths = {line.split()[-1] for line in fh if "openblas" in line.lower() and ".so" in line}
    except OSError:
        return _found
    for path in sorted(paths):
        try:  # RTLD_NOLOAD: only a library already loaded (never load one)
            _found.append(ctypes.CDLL(path, mode=os.RTLD_NOLOAD | os.RTLD_LOCAL))
        except OSError:
            continue
    return _found


def _controls(lib: ctypes.CDLL) -> tuple[object, object] | None:
    for get_name, set_name in _ENTRY_POINTS:
        get, put = getattr(lib, get_name, None), getattr(lib, set_name, None)
        if get is not None and put is not None:
            get.restype = ctypes.c_int
            put.restype = None
            return get, put
    return None


@contextmanager
def single_blas_thread() -> Iterator[None]:
    """Run the block with every loaded OpenBLAS on one thread (re-entrant, thread-safe).

    The outermost entry saves each library's thread count and sets it to 1; the outermost exit
    restores it. Nothing happens where the libraries cannot be found.
    """
    global _depth
    with _lock:
        if _depth == 0:
            _saved.clear()
            for lib in _loaded_openblas():
                ctl = _controls(lib)
                if ctl is None:
                    continue
                get, put = ctl
                try:
                    before = int(get())  # type: ignore[operator]
                    if before > 1:
                        put(ctypes.c_int(1))  # type: ignore[operator]
                        _saved.append((get, put, before))
                except (OSError, ValueError, ctypes.ArgumentError) as exc:  # pragma: no cover
                    logger.debug("single_blas_thread: cannot set the thread count: %s", exc)
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                for _get, put, before in _saved:
                    put(ctypes.c_int(before))  # type: ignore[operator]
                _saved.clear()
