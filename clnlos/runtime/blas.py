"""The host BLAS's thread count around clnlos's few dense factorisations.

clnlos calls LAPACK only for small dense problems (a lobe's separable terms: two SVDs of a
few hundred depths by a few thousand lateral offsets, :mod:`clnlos.physics.lobe`), in a
process whose cores PoCL's and pocketfft's threads already use. OpenBLAS's own threads then
oversubscribe them: on the 2-core test machine under other jobs' load the retroreflective
lobe's operator took 43.8 s (13.7 CPU s) to build with OpenBLAS's threads and 4.1 s (1.1
CPU s) with one. :func:`single_threaded_blas` sets OpenBLAS's thread-local count to one for
the calling thread (``openblas_set_num_threads_local``, OpenBLAS >= 0.3.27), found in the
process's loaded libraries; elsewhere (another BLAS, an older OpenBLAS, not Linux) it does
nothing.
"""

from __future__ import annotations

import contextlib
import ctypes
from functools import lru_cache

import numpy  # noqa: F401  (loads the BLAS whose setter is looked up in the process's maps)

from clnlos.runtime.caches import CACHES

LOCAL_SETTER = "openblas_set_num_threads_local"


@lru_cache(maxsize=1)
def _local_setter():
    """OpenBLAS's thread-local setter of a library this process has loaded, or None."""
    try:
        with open("/proc/self/maps") as f:
            paths = {line.split()[-1] for line in f if "openblas" in line.lower()
                     and line.split()[-1].startswith("/")}
    except OSError:
        return None
    for path in sorted(paths):
        try:
            fn = getattr(ctypes.CDLL(path), LOCAL_SETTER)
        except (OSError, AttributeError):
            continue
        fn.argtypes, fn.restype = [ctypes.c_int], ctypes.c_int
        return fn
    return None


CACHES.register("OpenBLAS thread setter", _local_setter.cache_clear)


@contextlib.contextmanager
def single_threaded_blas():
    """Inside the block, OpenBLAS runs on the calling thread alone (module docstring)."""
    fn = _local_setter()
    if fn is None:
        yield
        return
    old = fn(1)
    try:
        yield
    finally:
        fn(old if old > 0 else 0)
