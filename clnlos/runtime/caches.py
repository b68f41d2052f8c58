"""Every in-memory cache of the package, registered with one owner (:data:`CACHES`).

:class:`CacheRegistry`: each cache (contexts, queues, built programs, VkFFT apps, the plan
caches below, blur margins, ...) registers a ``clear`` function when its module is imported;
``CACHES.clear()`` empties them all.

:class:`PlanCache`: objects that hold device buffers (PSF spectra, FFT plans, scratch). A
plan is built once per key and reused while it fits the byte budget; the least recently
used plans are dropped first. Keys include the calling thread, because plans own scratch
buffers (the spectral filters' work arrays, the FFT work arrays) and must not run in two
threads at once. The budget defaults to a quarter of the device's global memory, or
``CLNLOS_PLAN_CACHE_MB`` (:mod:`clnlos.settings`).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable

import pyopencl.array as cla

from clnlos.settings import Settings, resolve


class CacheRegistry:
    """The one owner of the package's caches: ``register(name, clear)``; ``clear()`` calls
    every registered ``clear`` (a process that wants its memory back, a test that wants a
    cold start)."""

    def __init__(self):
        self._clear: dict[str, Callable[[], None]] = {}

    def register(self, name: str, clear: Callable[[], None]) -> None:
        self._clear[name] = clear

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self._clear)

    def clear(self) -> None:
        for clear in self._clear.values():
            clear()


CACHES = CacheRegistry()


def device_bytes(obj, _depth: int = 0, _seen=None) -> int:
    """Bytes of OpenCL device arrays reachable from ``obj``'s attributes (a few levels)."""
    seen = set() if _seen is None else _seen
    if id(obj) in seen or _depth > 4:
        return 0
    seen.add(id(obj))
    if isinstance(obj, cla.Array):
        return int(obj.nbytes)
    reserved = getattr(obj, "reserved_nbytes", None)  # a Scratch: its work buffers
    if reserved is not None and not isinstance(obj, (dict, list, tuple)):
        return int(reserved)
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

    def budget(self, queue=None, settings: Settings | None = None) -> int:
        if self._budget is not None:
            return self._budget
        configured = resolve(settings).plan_cache_bytes
        if configured is not None:
            return configured
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
CACHES.register(PIPELINES.name, PIPELINES.clear)
CACHES.register(FORWARD_BLURS.name, FORWARD_BLURS.clear)
