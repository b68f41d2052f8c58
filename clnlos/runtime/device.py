"""The one OpenCL runtime module: device selection, contexts, queues, program cache, checks.

Only this module touches platforms and program builds. Everything else asks it for a
queue (:func:`get_queue`) and for compiled kernels (:func:`get_kernels`).

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

import contextlib

import hashlib
import importlib.resources
import os
import re
import warnings
from dataclasses import dataclass
from functools import cache

import numpy as np
import pyopencl as cl

from clnlos.errors import DeviceCapabilityError, DeviceError, KernelBuildError, ShapeError

ENV_DEVICE = "CLNLOS_DEVICE"
ENV_THREADS = "CLNLOS_THREADS"  # host threads (FFT) of this process; PoCL: POCL_MAX_PTHREAD_COUNT
ENV_FFT = "CLNLOS_FFT"  # "auto" (default), "vkfft" or "host" ("numpy" is an alias)
POCL_VKFFT_ISSUE = "https://github.com/pocl/pocl/issues/2069"


def host_threads() -> int:
    """Host threads this process may use: ``CLNLOS_THREADS`` if set (> 0), else the cores
    available to it."""
    raw = os.environ.get(ENV_THREADS, "").strip()
    if raw:
        try:
            n = int(raw)
        except ValueError:
            raise DeviceError(f"invalid {ENV_THREADS}={raw!r}: a positive integer") from None
        if n < 1:
            raise DeviceError(f"invalid {ENV_THREADS}={raw!r}: a positive integer")
        return n
    try:
        return len(os.sched_getaffinity(0)) or 1
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


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


def resolve_device_spec(spec: str | None = None) -> str:
    """The effective spec string: explicit argument, else ``$CLNLOS_DEVICE``, else ``""``."""
    if spec is None or str(spec).strip() == "":
        spec = os.environ.get(ENV_DEVICE, "")
    return str(spec).strip()


def select_device(spec: str | None = None) -> cl.Device:
    """Pick one device from a spec (see module docstring); never prompts."""
    rows = _all_devices()
    s = resolve_device_spec(spec)
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


def get_context(spec: str | None = None) -> cl.Context:
    """The (cached) context of the selected device."""
    return _context_for(select_device(spec))


def get_queue(device: str | cl.CommandQueue | None = None, *, profiling: bool = False
              ) -> cl.CommandQueue:
    """A cached in-order queue for a device spec; a queue passed in is returned as is."""
    if isinstance(device, cl.CommandQueue):
        return device
    return _queue_for(select_device(device), profiling)


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
    (:func:`clnlos.limits.check_memory`)."""
    from clnlos.runtime.limits import check_memory

    check_memory(what, device=device, device_total=nbytes, device_buffer=nbytes)


def pocl_version(device: cl.Device) -> tuple[int, int] | None:
    """PoCL (major, minor) of the device's platform, or None if it is not PoCL."""
    from pyopencl.characterize import get_pocl_version

    return get_pocl_version(device.platform)


def check_environment() -> None:
    """Validate the CLNLOS_* environment variables up front (before any work): a bad value
    is a one-line DeviceError naming the variable."""
    choice = os.environ.get(ENV_FFT, "auto").strip().lower() or "auto"
    if choice not in ("auto", "vkfft", "host", "numpy"):
        raise DeviceError(f"invalid {ENV_FFT}={choice!r}: allowed auto, vkfft, host")
    if choice == "vkfft":
        try:
            import pyvkfft.opencl  # noqa: F401
        except Exception as exc:
            raise DeviceError(f"{ENV_FFT}=vkfft but pyvkfft's OpenCL backend is not "
                              f"importable ({type(exc).__name__}: {exc}); install the extra: "
                              "pip install 'clnlos[vkfft]' (VKFFT_BACKEND=opencl), or unset "
                              + ENV_FFT) from None
    host_threads()
    from clnlos.runtime.caches import PIPELINES

    PIPELINES.budget()  # CLNLOS_PLAN_CACHE_MB
    from clnlos.runtime.spectrum_cache import SpectrumCache, budget_bytes

    budget_bytes()  # CLNLOS_SPECTRUM_CACHE_MB
    cache = SpectrumCache.from_env()  # CLNLOS_SPECTRUM_CACHE: a writable folder
    if cache is not None:
        cache.check()


@dataclass(frozen=True)
class FFTChoice:
    """The FFT backend of a queue: ``"vkfft"`` (pyvkfft on the device) or ``"host"``
    (scipy.fft on the host, on mapped buffers), why, and whether the reason deserves a warning."""

    backend: str
    reason: str
    warn: bool = False


def fft_backend(queue: cl.CommandQueue) -> FFTChoice:
    """The FFT backend for this queue's device.

    ``CLNLOS_FFT`` (``auto`` by default) overrides: ``host`` (alias ``numpy``) or ``vkfft``
    (an error when pyvkfft's OpenCL backend cannot be imported). ``auto``: the host FFT on CPU
    devices (there the FFT runs on the same cores either way, and scipy's pocketfft measured
    1.3-1.6x faster than VkFFT on PoCL, tools/results/bench_reconstruct.csv), and on PoCL >= 7,
    which miscompiles VkFFT (pocl issue 2069); VkFFT elsewhere (GPUs), falling back to the host
    with a warning when pyvkfft is missing.
    """
    choice = os.environ.get(ENV_FFT, "auto").strip().lower() or "auto"
    if choice not in ("auto", "vkfft", "host", "numpy"):
        raise DeviceError(f"invalid {ENV_FFT}={choice!r}: allowed auto, vkfft, host")
    if choice in ("host", "numpy"):
        return FFTChoice("host", f"{ENV_FFT}={choice}")
    if choice == "auto":  # decided before importing pyvkfft (0.09 s) where it is not used
        ver = pocl_version(queue.device)
        if ver is not None and ver >= (7, 0):
            return FFTChoice("host", f"PoCL {ver[0]}.{ver[1]} miscompiles VkFFT "
                                     f"({POCL_VKFFT_ISSUE})", warn=True)
        if queue.device.type & cl.device_type.CPU:
            return FFTChoice("host", "CPU device: the host FFT is faster than VkFFT there")
    try:
        import pyvkfft.opencl  # noqa: F401

        vk_error = None
    except Exception as exc:  # not installed, or built without the OpenCL backend
        vk_error = f"{type(exc).__name__}: {exc}"
    if choice == "vkfft":
        if vk_error is not None:
            raise DeviceError(f"{ENV_FFT}=vkfft but pyvkfft's OpenCL backend is not importable "
                              f"({vk_error}); install the extra: pip install "
                              "'clnlos[vkfft]' (VKFFT_BACKEND=opencl), or unset " + ENV_FFT)
        return FFTChoice("vkfft", f"{ENV_FFT}=vkfft")
    if vk_error is not None:
        return FFTChoice("host", f"pyvkfft (OpenCL backend) not importable: {vk_error}",
                         warn=True)
    return FFTChoice("vkfft", "pyvkfft on the device")


_warned: set[str] = set()


def warn_once(msg: str) -> None:
    if msg not in _warned:
        _warned.add(msg)
        warnings.warn(msg, RuntimeWarning, stacklevel=3)


# --------------------------------------------------------------------------- programs
def kernel_dir():
    """The packaged kernel folder (``clnlos.kernels``) as an importlib.resources Traversable."""
    return importlib.resources.files("clnlos.kernels")


_INCLUDE_RE = re.compile(r'^\s*#\s*include\s+"([^"]+)"', re.MULTILINE)


def _read_kernel(name: str) -> str:
    res = kernel_dir() / name
    if not res.is_file():
        raise KernelBuildError(f"kernel source {name!r} not found in package clnlos.kernels")
    return res.read_text(encoding="utf-8")


def _source_with_headers(family: str) -> tuple[str, str]:
    """Source of ``family.cl`` and a hash over it and every local header it includes."""
    src = _read_kernel(f"{family}.cl")
    h = hashlib.sha256(src.encode())
    seen, todo = set(), _INCLUDE_RE.findall(src)
    while todo:
        inc = todo.pop()
        if inc in seen or not (kernel_dir() / inc).is_file():
            continue  # system headers such as pyopencl-complex.h come from -I paths
        seen.add(inc)
        text = _read_kernel(inc)
        h.update(inc.encode() + text.encode())
        todo.extend(_INCLUDE_RE.findall(text))
    return src, h.hexdigest()


def _include_options() -> list[str]:
    from pyopencl import _find_pyopencl_include_path

    with importlib.resources.as_file(kernel_dir()) as kdir:
        return [f"-I{kdir}", f"-I{_find_pyopencl_include_path()}"]


class KernelSet:
    """The kernels of one built program, each ``cl.Kernel`` fetched once (attribute access)."""

    def __init__(self, program: cl.Program, family: str, options: tuple[str, ...]):
        self.program, self.family, self.options = program, family, options
        self._k = {k.function_name: k for k in program.all_kernels()}

    def __getattr__(self, name: str) -> cl.Kernel:
        try:
            return self.__dict__["_k"][name]
        except KeyError:
            raise AttributeError(f"kernel {name!r} not in {self.family}.cl") from None


_program_cache: dict[tuple, KernelSet] = {}


def format_defines(defines: dict | None) -> tuple[str, ...]:
    out = []
    for k, v in sorted((defines or {}).items()):
        if v is None or v is False:
            continue
        out.append(f"-D{k}" if v is True else f"-D{k}={v}")
    return tuple(out)


def physical_defines() -> dict:
    """Constants every kernel may use, from their one Python statement (``clnlos.C0``)."""
    from clnlos import C0

    return {"C0_LIGHT": repr(float(C0))}


def get_kernels(ctx_or_queue, family: str, defines: dict | None = None) -> KernelSet:
    """Build (once) ``kernels/<family>.cl`` with ``-D`` defines and return its kernels.

    Cached by (context, source hash including local headers, build options).
    """
    ctx = ctx_or_queue.context if isinstance(ctx_or_queue, cl.CommandQueue) else ctx_or_queue
    src, digest = _source_with_headers(family)
    options = format_defines({**physical_defines(), **(defines or {})}) + tuple(
        _include_options())
    key = (ctx, digest, options)
    hit = _program_cache.get(key)
    if hit is not None:
        return hit
    dev = ctx.devices[0]
    try:
        prg = cl.Program(ctx, src).build(options=list(options))
    except cl.RuntimeError as exc:
        raise KernelBuildError(
            f"building kernels/{family}.cl failed on device {dev.name.strip()!r} "
            f"with options {' '.join(options)}:\n{exc}"
        ) from None
    ks = KernelSet(prg, family, options)
    _program_cache[key] = ks
    return ks


def real_defines(dtype) -> dict:
    """``-D`` defines selecting the real type of a kernel family."""
    dt = np.dtype(dtype)
    return {"REAL_T": "double" if dt == np.float64 else "float",
            "USE_FP64": dt == np.float64}


def is_oclgrind(device: cl.Device) -> bool:
    return "oclgrind" in device.platform.name.lower()


def download(a_g) -> np.ndarray:
    """Blocking copy of a device array to a new host array.

    Unlike ``Array.get()``, the copy's event is not appended to ``a_g.events``: pyopencl keeps
    up to 12 events per array and each holds its host buffer, so a plan buffer copied to
    and from the host on every call retained 12 copies of itself (1 GiB more per call at
    128x128x512 with the host FFT).
    """
    out = np.empty(a_g.shape, a_g.dtype)
    cl.enqueue_copy(a_g.queue, out, a_g.base_data, src_offset=a_g.offset,
                    wait_for=a_g.events, is_blocking=True)
    return out


def upload_into(a_g, host: np.ndarray) -> None:
    """Blocking copy of ``host`` (same shape and dtype) into the device array ``a_g``."""
    host = np.ascontiguousarray(host, a_g.dtype)
    if host.shape != a_g.shape:
        raise ShapeError(f"upload of {host.shape} into a device array of {a_g.shape}")
    cl.enqueue_copy(a_g.queue, a_g.base_data, host, dst_offset=a_g.offset,
                    wait_for=a_g.events, is_blocking=True)


@contextlib.contextmanager
def host_view(a_g, write: bool = False, read: bool = True):
    """The device array ``a_g`` as a numpy array for the duration of a ``with`` block.

    clEnqueueMapBuffer: on a CPU device (PoCL) the buffer's own memory, no copy; elsewhere
    the driver copies. ``write`` and not ``read``: the old contents are not needed
    (CL_MAP_WRITE_INVALIDATE_REGION). Unmapped, and the queue finished, on leaving.
    """
    flags = 0
    if read:
        flags |= cl.map_flags.READ
    if write:
        flags |= cl.map_flags.WRITE if read else cl.map_flags.WRITE_INVALIDATE_REGION
    ary, _ = cl.enqueue_map_buffer(a_g.queue, a_g.base_data, flags, a_g.offset, a_g.shape,
                                   a_g.dtype, wait_for=a_g.events, is_blocking=True)
    try:
        yield ary
    finally:
        ary.base.release(a_g.queue)
        a_g.queue.finish()


def fill_zero(queue: cl.CommandQueue, a_g, offset_bytes: int = 0, nbytes: int | None = None):
    """Set (part of) a device array to zero with a memset (clEnqueueFillBuffer).

    pyopencl's ``Array.fill`` runs a kernel and was 9x slower on PoCL. Oclgrind does not
    mark fill-buffer contents as initialised (nor, after a read-write map, copied ones), so
    there a kernel writes the zeros (``kernels/fill.cl``), which keeps its
    uninitialised-read checks meaningful.
    """
    nbytes = a_g.nbytes - offset_bytes if nbytes is None else nbytes
    if nbytes <= 0:
        return
    if is_oclgrind(queue.device):
        get_kernels(queue, "fill").zero_bytes(queue, (round_up(nbytes, 64),), None,
                                              a_g.base_data,
                                              np.uint64(a_g.offset + offset_bytes),
                                              np.uint64(nbytes))
    else:
        cl.enqueue_fill_buffer(queue, a_g.base_data, np.uint8(0), a_g.offset + offset_bytes,
                               nbytes)


def copy_rows(queue: cl.CommandQueue, src_g, dst_g, *, rows: int, src_row: int = 0,
              dst_row: int = 0) -> None:
    """dst[dst_row:dst_row + rows] <- src[src_row:src_row + rows] along the first axis of two
    C-contiguous device arrays with the same trailing shape and dtype (one buffer copy)."""
    if src_g.shape[1:] != dst_g.shape[1:] or src_g.dtype != dst_g.dtype:
        raise ValueError(f"copy_rows: {src_g.shape} {src_g.dtype} -> {dst_g.shape} "
                         f"{dst_g.dtype}: trailing shapes and dtypes differ")
    row = int(np.prod(src_g.shape[1:], dtype=np.int64)) * src_g.dtype.itemsize
    if rows <= 0 or row == 0:
        return
    cl.enqueue_copy(queue, dst_g.base_data, src_g.base_data, byte_count=rows * row,
                    src_offset=src_g.offset + src_row * row,
                    dst_offset=dst_g.offset + dst_row * row)


def zeros(queue: cl.CommandQueue, shape, dtype):
    """A zeroed device array (see :func:`fill_zero`)."""
    import pyopencl.array as cla

    a = cla.empty(queue, shape, dtype)
    fill_zero(queue, a)
    return a


class Scratch:
    """Device work buffers shared by the stages of one plan, which run one after another on
    one queue (a plan is never shared across threads, :mod:`clnlos.plans`).

    A stage reserves the bytes it needs in a named slot when it is built and asks for an
    array view of that slot on every call; stages whose work arrays are not live at the same
    time share a slot, so a reconstruction holds two padded-grid work buffers, not two per
    stage, and touches their pages once (the first touch of 270 MB costs about 0.1 s on a
    CPU device). Contents do not survive from one call to the next.
    """

    def __init__(self, queue: cl.CommandQueue):
        self.queue = queue
        self._need: dict[str, int] = {}
        self._bufs: dict[str, cl.Buffer] = {}

    def reserve(self, slot: str, shape, dtype) -> None:
        nbytes = int(np.prod(shape)) * np.dtype(dtype).itemsize
        self._need[slot] = max(self._need.get(slot, 0), nbytes)

    def array(self, slot: str, shape, dtype):
        """A ``shape``/``dtype`` view of the slot (reserved first if it was not)."""
        import pyopencl.array as cla

        self.reserve(slot, shape, dtype)
        buf = self._bufs.get(slot)
        if buf is None or buf.size < self._need[slot]:
            # arrays handed out earlier keep the old buffer alive until they are dropped
            buf = self._bufs[slot] = cl.Buffer(self.queue.context, cl.mem_flags.READ_WRITE,
                                              max(self._need[slot], 1))
        return cla.Array(self.queue, tuple(int(v) for v in shape), dtype, data=buf)

    @property
    def nbytes(self) -> int:
        """Bytes of the work buffers: reserved, allocated or not yet."""
        return sum(max(need, self._bufs[s].size if s in self._bufs else 0)
                   for s, need in self._need.items())


INT32_MAX = (1 << 31) - 1


def kernel_int(value, what: str = "size") -> np.int32:
    """A size or index for a kernel's ``int`` argument, checked against its range (kernels
    index memory with size_t products; their per-axis sizes are 32-bit)."""
    v = int(value)
    if not 0 <= v <= INT32_MAX:
        raise DeviceCapabilityError(f"{what} = {v} exceeds the kernels' 32-bit size range "
                                    f"(at most {INT32_MAX}); use a smaller grid")
    return np.int32(v)


def round_up(n: int, m: int) -> int:
    return ((n + m - 1) // m) * m
