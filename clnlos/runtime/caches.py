"""One cache for plans: objects that hold device buffers (PSF spectra, FFT plans, scratch).

A plan is built once per key and reused while it fits the byte budget; the least recently
used plans are dropped first. Keys include the calling thread, because plans own scratch
buffers (``SpectralFilter._buf``, the FFT work arrays) and must not run in two threads at
once. ``clear()`` frees everything (and the program and VkFFT caches with
:func:`clear_all`). The budget defaults to a quarter of the device's global memory, or
``CLNLOS_PLAN_CACHE_MB``.
"""

from __future__ import annotations

import os
import threading
from collections import OrderedDict

ENV_BUDGET = "CLNLOS_PLAN_CACHE_MB"


def device_bytes(obj, _depth: int = 0, _seen=None) -> int:
    """Bytes of OpenCL device arrays reachable from ``obj``'s attributes (a few levels)."""
    import pyopencl.array as cla

    from clnlos.runtime.device import Scratch

    seen = set() if _seen is None else _seen
    if id(obj) in seen or _depth > 4:
        return 0
    seen.add(id(obj))
    if isinstance(obj, cla.Array):
        return int(obj.nbytes)
    if isinstance(obj, Scratch):
        return obj.nbytes  # its reserved work buffers (allocated at first use)
    if isinstance(obj, dict):
        items = obj.values()
    elif isinstance(obj, (list, tuple)):
        items = obj
    elif hasattr(obj, "__dict__"):
        items = vars(obj).values()
    else:
        return 0
    return sum(device_bytes(v, _depth + 1, seen) for v in items)


class PlanCache:
    """LRU cache of plans under a byte budget (see the module docstring)."""

    def __init__(self, name: str, budget_bytes: int | None = None):
        self.name = name
        self._budget = budget_bytes
        self._plans: OrderedDict = OrderedDict()  # key -> (plan, nbytes)
        self._lock = threading.Lock()

    def budget(self, queue=None) -> int:
        if self._budget is not None:
            return self._budget
        env = os.environ.get(ENV_BUDGET)
        if env:
            from clnlos.errors import ParameterError

            try:
                mb = float(env)
            except ValueError:
                raise ParameterError(ENV_BUDGET, env, "a number of MiB >= 0") from None
            if not mb >= 0:
                raise ParameterError(ENV_BUDGET, env, "a number of MiB >= 0")
            return int(mb * 2**20)
        if queue is not None:
            return int(queue.device.global_mem_size // 4)
        return 2**31

    def get(self, key, build, queue=None):
        """The plan for ``key`` (built by ``build()`` when missing) for this thread."""
        full = (threading.get_ident(), key)
        with self._lock:
            hit = self._plans.get(full)
            if hit is not None:
                self._plans.move_to_end(full)
                return hit[0]
        plan = build()
        size = device_bytes(plan)
        with self._lock:
            self._plans[full] = (plan, size)
            self._evict(self.budget(queue), keep=full)
        return plan

    def _evict(self, budget: int, keep) -> None:
        while self.nbytes > budget and len(self._plans) > 1:
            oldest = next(iter(self._plans))
            if oldest == keep:
                break
            self._plans.pop(oldest)

    @property
    def nbytes(self) -> int:
        return sum(size for _, size in self._plans.values())

    def __len__(self) -> int:
        return len(self._plans)

    def clear(self) -> None:
        with self._lock:
            self._plans.clear()


PIPELINES = PlanCache("reconstruction pipelines")
FORWARD_BLURS = PlanCache("forward-model slab blurs")


def clear_all() -> None:
    """Free every cached plan, VkFFT app and built program."""
    from clnlos.runtime import fft as fft
    from clnlos.runtime import device as runtime

    PIPELINES.clear()
    FORWARD_BLURS.clear()
    fft._vkfft_app.cache_clear()
    runtime._program_cache.clear()
