"""Devices: selection, contexts, queues, capability checks.

Only this module touches platforms and contexts; :mod:`clnlos.runtime.programs` builds
programs. Everything else asks it for a queue (:func:`get_queue`).

Device selection never prompts. A *device spec* is, in order of precedence, the explicit
argument (``--device`` on the command line), the environment variable ``CLNLOS_DEVICE``,
or the default (the first GPU found, else the first device of the first platform).
Spec forms:

``"P:D"``          platform index P, device index D (as ``clnlos devices`` numbers them)
``"name"``         first device whose platform or device name or version contains ``name``
                   (case-insensitive), e.g. ``pocl``, ``nvidia``, ``intel``
``"name:K"``       the K-th such device, e.g. ``nvidia:1``
``"cpu"``/``"gpu"`` first device of that type
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass
from functools import cache

import numpy as np
import pyopencl as cl
from pyopencl.characterize import get_pocl_version

from clnlos.errors import DeviceCapabilityError, DeviceError
from clnlos.runtime.caches import CACHES
from clnlos.runtime.limits import check_memory
from clnlos.settings import Settings, resolve


def host_threads(settings: Settings | None = None) -> int:
    """Host threads this process may use (:meth:`clnlos.settings.Settings.host_threads`)."""
    return resolve(settings).host_threads()


# --------------------------------------------------------------------------- devices
@dataclass(frozen=True)
class DeviceInfo:
    platform_index: int
    device_index: int
    platform: str
    name: str
    version: str
    driver: str
    type: str
    compute_units: int
    global_mem_bytes: int
    max_alloc_bytes: int
    fp64: bool
    images: bool

    @property
    def spec(self) -> str:
        return f"{self.platform_index}:{self.device_index}"


def _all_devices() -> list[tuple[int, int, cl.Platform, cl.Device]]:
    try:
        platforms = cl.get_platforms()
    except cl.Error as exc:  # no ICD loader or no platform at all
        raise DeviceError(
            f"no OpenCL platform found ({exc}); install an OpenCL driver "
            "(e.g. Debian pocl-opencl-icd for the CPU)"
        ) from None
    out = []
    for ip, p in enumerate(platforms):
        try:
            devs = p.get_devices()
        except cl.Error:
            continue
        for idv, d in enumerate(devs):
            out.append((ip, idv, p, d))
    if not out:
        raise DeviceError("OpenCL platforms found but no devices")
    return out


def has_fp64(device: cl.Device) -> bool:
    return "cl_khr_fp64" in device.extensions or device.double_fp_config != 0


def device_info(ip: int, idv: int, p: cl.Platform, d: cl.Device) -> DeviceInfo:
    return DeviceInfo(
        platform_index=ip,
        device_index=idv,
        platform=p.name.strip(),
        name=d.name.strip(),
        version=d.version.strip(),
        driver=d.driver_version.strip(),
        type=cl.device_type.to_string(d.type),
        compute_units=int(d.max_compute_units),
        global_mem_bytes=int(d.global_mem_size),
        max_alloc_bytes=int(d.max_mem_alloc_size),
        fp64=has_fp64(d),
        images=bool(d.image_support),
    )


def list_devices() -> list[DeviceInfo]:
    """Every OpenCL device on this machine, numbered ``platform:device``."""
    return [device_info(*row) for row in _all_devices()]


def _default_index(rows) -> int:
    for k, (_, _, _, d) in enumerate(rows):
        if d.type & cl.device_type.GPU:
            return k
    return 0


def resolve_device_spec(spec: str | None = None, settings: Settings | None = None) -> str:
    """The effective spec string: explicit argument, else ``$CLNLOS_DEVICE``, else ``""``."""
    if spec is None or str(spec).strip() == "":
        spec = resolve(settings).device
    return str(spec).strip()


def select_device(spec: str | None = None, settings: Settings | None = None) -> cl.Device:
    """Pick one device from a spec (see module docstring); never prompts."""
    rows = _all_devices()
    s = resolve_device_spec(spec, settings)
    avail = ", ".join(f"{ip}:{idv} ({d.name.strip()})" for ip, idv, _, d in rows)
    if s == "":
        return rows[_default_index(rows)][3]
    m = re.fullmatch(r"(\d+):(\d+)", s)
    if m:
        ip, idv = int(m.group(1)), int(m.group(2))
        for rip, ridv, _, d in rows:
            if (rip, ridv) == (ip, idv):
                return d
        raise DeviceError(f"no OpenCL device {s!r}; available: {avail}")
    m = re.fullmatch(r"([^:]+?)(?::(\d+))?", s)
    if not m:
        raise DeviceError(f"cannot parse device spec {s!r}; use P:D, NAME or NAME:K")
    name, k = m.group(1).lower(), int(m.group(2) or 0)
    if name in ("cpu", "gpu", "accelerator"):
        want = getattr(cl.device_type, name.upper())
        hits = [d for _, _, _, d in rows if d.type & want]
    else:
        hits = [d for _, _, p, d in rows
                if any(name in text.lower() for text in (p.name, p.version, d.name, d.version))]
    if k >= len(hits):
        raise DeviceError(f"no OpenCL device matches {s!r}; available: {avail}")
    return hits[k]


@cache
def _context_for(device: cl.Device) -> cl.Context:
    return cl.Context([device])


@cache
def _queue_for(device: cl.Device, profiling: bool) -> cl.CommandQueue:
    props = cl.command_queue_properties.PROFILING_ENABLE if profiling else 0
    return cl.CommandQueue(_context_for(device), properties=props)


CACHES.register("OpenCL contexts", _context_for.cache_clear)
CACHES.register("OpenCL queues", _queue_for.cache_clear)


def get_queue(device: str | cl.CommandQueue | None = None, *, profiling: bool = False,
              settings: Settings | None = None) -> cl.CommandQueue:
    """A cached in-order queue for a device spec (None: ``settings.device``, see the module
    docstring); a queue passed in is returned as is."""
    if isinstance(device, cl.CommandQueue):
        return device
    return _queue_for(select_device(device, settings), profiling)


# --------------------------------------------------------------------------- capabilities
def require_dtype(device: cl.Device, dtype) -> np.dtype:
    """Check the device can compute in ``dtype`` (float32 or float64) and return it."""
    dt = np.dtype(dtype)
    if dt not in (np.float32, np.float64):
        raise DeviceCapabilityError(f"dtype must be float32 or float64, got {dt}")
    if dt == np.float64 and not has_fp64(device):
        raise DeviceCapabilityError(
            f"float64 requested but device {device.name.strip()!r} has no cl_khr_fp64; "
            "use dtype=float32 or choose another device (clnlos devices)"
        )
    return dt


def require_memory(device: cl.Device, nbytes: int, what: str) -> None:
    """Raise before allocating when one buffer of ``nbytes`` cannot fit on the device
    (:func:`clnlos.runtime.limits.check_memory`)."""
    check_memory(what, device=device, device_total=nbytes, device_buffer=nbytes)


def pocl_version(device: cl.Device) -> tuple[int, int] | None:
    """PoCL (major, minor) of the device's platform, or None if it is not PoCL."""
    return get_pocl_version(device.platform)








_warned: set[str] = set()


def warn_once(msg: str) -> None:
    if msg not in _warned:
        _warned.add(msg)
        warnings.warn(msg, RuntimeWarning, stacklevel=3)
























def is_oclgrind(device: cl.Device) -> bool:
    return "oclgrind" in device.platform.name.lower()






















def group_size(kernel, device, cap: int = 256) -> int:
    """A work-group size: the kernel's preferred multiple, grown while it fits ``cap`` and the
    kernel's and device's maxima."""
    wg = cl.kernel_work_group_info
    mult = max(1, kernel.get_work_group_info(wg.PREFERRED_WORK_GROUP_SIZE_MULTIPLE, device))
    most = min(cap, kernel.get_work_group_info(wg.WORK_GROUP_SIZE, device),
               device.max_work_group_size)
    size = mult
    while size * 2 <= most:
        size *= 2
    return max(1, min(size, most))
