"""Memory limits, checked from declared sizes before anything is read or allocated.

:func:`check_memory` is the one check: what a step will need -- computed from the sizes a
file or a parameter declares (a capture's dataset shape and dtype, the surface elements a
scene implies, a texture's grid) -- against the host's available memory
(:func:`host_available_bytes`) and a device's global memory and largest allocation. A size
that does not fit is one :class:`~clnlos.errors.MemoryLimitError` line naming the step,
the size needed, the limit and which memory.

Capture readers declare their dataset through :func:`declared_capture` before they read
it; a command that knows what it will do with the capture (reconstruct: the pipeline's
device buffers) adds its own check for the duration of the read with :func:`capture_use`.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
from collections.abc import Callable, Iterator

from clnlos.errors import DeviceMemoryError, MemoryLimitError

MEMINFO = "/proc/meminfo"
# cgroup memory limits (v2, v1) that cap what this process may use
CGROUP_LIMITS = ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes")
# host bytes per element of a capture read: the stored value, its float32 copy and the
# validation's two boolean masks (clnlos.io.formats.common.validate_transient)
READ_EXTRA_BYTES = 4 + 2


def format_bytes(n: float) -> str:
    """``n`` bytes in binary units: "512 B", "3.2 MiB", "6.0 GiB"."""
    for unit, scale in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{int(n)} B"


def _meminfo_available() -> int | None:
    try:
        with open(MEMINFO, encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def _cgroup_limit() -> int | None:
    for path in CGROUP_LIMITS:
        try:
            with open(path, encoding="ascii") as f:
                raw = f.read().strip()
        except OSError:
            continue
        if raw.isdigit():
            return int(raw)
    return None


def host_available_bytes() -> int | None:
    """Host memory a new allocation can get (bytes): MemAvailable of /proc/meminfo (free
    and reclaimable memory; os.sysconf's available pages where there is no /proc), capped
    by this process's cgroup limit; None when the system says nothing."""
    avail, cap = _meminfo_available(), _cgroup_limit()
    if avail is None:
        return cap
    return avail if cap is None else min(avail, cap)


def check_memory(what: str, *, host: int = 0, device=None, device_total: int = 0,
                 device_buffer: int = 0) -> None:
    """Raise before reading or allocating when a step does not fit.

    ``what`` names the step and the size that declares it (a file and its dataset, a
    parameter and its value); ``host``: host bytes it needs; ``device``: a
    ``pyopencl.Device`` with ``device_total`` bytes in all and ``device_buffer`` bytes in
    its largest single buffer. Host shortfalls raise MemoryLimitError, device ones
    DeviceMemoryError (a DeviceCapabilityError)."""
    if host > 0:
        avail = host_available_bytes()
        if avail is not None and host > avail:
            raise MemoryLimitError(f"{what} needs {format_bytes(host)} of host memory; "
                                   f"{format_bytes(avail)} is available")
    if device is None:
        return
    name, mib = device.name.strip(), 2**20
    if device_buffer > device.max_mem_alloc_size:
        raise DeviceMemoryError(
            f"{what} needs {device_buffer / mib:.1f} MiB in one buffer but device {name!r} "
            f"allows {device.max_mem_alloc_size / mib:.1f} MiB per buffer "
            f"({device.global_mem_size / mib:.1f} MiB in all); use a smaller grid")
    total = max(device_total, device_buffer)
    if total > device.global_mem_size:
        raise DeviceMemoryError(
            f"{what} needs {total / mib:.1f} MiB of device memory but device {name!r} has "
            f"{device.global_mem_size / mib:.1f} MiB; use a smaller grid")


# what the running command will do with the capture being read (see capture_use)
_CAPTURE_USE: contextvars.ContextVar[Callable | None] = contextvars.ContextVar(
    "clnlos_capture_use", default=None)


@contextlib.contextmanager
def capture_use(check: Callable) -> Iterator[None]:
    """While the block runs, every capture reader calls ``check(shape, bin_width_s,
    start_s)`` with the declared transient shape [t, y, x] and the file's time axis (bin
    width None where the file does not store it) before it reads the data."""
    token = _CAPTURE_USE.set(check)
    try:
        yield
    finally:
        _CAPTURE_USE.reset(token)


def declared_capture(path, shape, itemsize: int, *, bin_width_s: float | None = None,
                     start_s: float = 0.0) -> None:
    """Called by a capture reader with its dataset's declared shape (in [t, y, x] order)
    and item size, before it reads it: the host must hold the
    read (the stored values, a float32 copy and the validation's masks), then the check of
    :func:`capture_use`, if any, runs."""
    n = 1
    for s in shape:
        n *= int(s)
    dims = " x ".join(str(int(s)) for s in shape)
    check_memory(f"{path}: reading its transient ({dims}, {itemsize} B per value)",
                 host=n * (int(itemsize) + READ_EXTRA_BYTES))
    use = _CAPTURE_USE.get()
    if use is not None:
        use(tuple(int(s) for s in shape), bin_width_s, start_s)
