"""3D FFT plans on an OpenCL queue: pyvkfft where it is safe, a host FFT fallback elsewhere.

The backend is chosen once per plan by :func:`fft_backend` (host FFT on CPU
devices and on PoCL >= 7, which miscompiles VkFFT, pocl issue 2069; VkFFT on GPUs;
``CLNLOS_FFT=host|vkfft`` overrides, ``numpy`` is an alias of ``host``) and recorded in
``plan.backend``. The host FFT is scipy.fft (pocketfft,
all cores) on mapped device buffers (no copy on a CPU device; see
:func:`clnlos.runtime.buffers.host_view`). Conventions are numpy's: forward
unnormalised, inverse divided by N.

``RealFFT3``: real (n0, n1, n2) <-> half spectrum (n0, n1, n2//2 + 1) (the spectral filters).
``ComplexFFT3``: complex (n0, n1, n2) in place (f-k migration needs the full spectrum).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import pyopencl as cl
import pyopencl.array as cla
import scipy.fft as sfft

from clnlos.errors import DeviceError
from clnlos.runtime.buffers import host_view
from clnlos.runtime.caches import CACHES
from clnlos.runtime.device import get_queue, pocl_version, require_dtype, require_memory, warn_once
from clnlos.settings import ENV_FFT, Settings, resolve

COMPLEX_OF = {np.dtype(np.float32): np.dtype(np.complex64),
              np.dtype(np.float64): np.dtype(np.complex128)}


@lru_cache(maxsize=64)
def _vkfft_app(shape: tuple, dtype: np.dtype, queue, r2c: bool):
    """VkFFT apps are costly to build (kernel generation and compilation): one per
    (shape, dtype, queue, kind), shared by every plan, as pyvkfft's own fft module does."""
    from pyvkfft.opencl import VkFFTApp

    return VkFFTApp(shape, dtype, queue, ndim=3, inplace=not r2c, r2c=r2c, norm=1)


CACHES.register("VkFFT apps", _vkfft_app.cache_clear)


def _backend(queue) -> str:
    choice = fft_backend(queue)
    if choice.warn:
        warn_once(f"clnlos: host FFT fallback: {choice.reason}")
    return choice.backend


def _workers() -> int:
    """Threads of the host FFT: ``CLNLOS_THREADS`` (a study worker pins it), else every core."""
    return resolve(None).host_threads()


def _pocketfft():
    """scipy's pocketfft binding, whose r2c/c2r write into a given array (scipy.fft's public
    functions do not take ``out=``: their result is a 270 MB temporary at 128 x 128 x 512,
    then copied); None when this scipy does not have it (the public functions are used).

    Where the binding is there, its errors propagate: the pruned transforms write part of
    their output (and :func:`_c2r_pruned` overwrites its input) before a later pass could
    fail, so no fallback could start again from what they were given."""
    try:
        from scipy.fft._pocketfft import pypocketfft as pp
    except ImportError:
        return None
    return pp if hasattr(pp, "r2c") and hasattr(pp, "c2r") else None


def _lateral_forward(pp, x: np.ndarray, out: np.ndarray, n0: int, n1: int) -> None:
    """out[:n0] <- the 2D rfft over (y, x) of the planes x[:n0] that are zero outside
    x[:n0, :n1] (along x only on the rows that hold data, along y on the n0 planes)."""
    w = _workers()
    pp.r2c(x[:n0, :n1], (2,), True, 0, out[:n0, :n1], w)
    out[:n0, n1:] = 0
    pp.c2c(out[:n0], (1,), True, 0, out[:n0], w)


def _lateral_inverse(pp, s: np.ndarray, n2: int, out: np.ndarray, n0: int, n1: int) -> None:
    """out[:n0, :n1] <- the 2D irfft over (y, x) of the planes s[:n0] (divided by n1' n2,
    s[:n0] overwritten), computed for the rows out[:n0, :n1] only."""
    w = _workers()
    pp.c2c(s[:n0], (1,), False, 2, s[:n0], w)
    pp.c2r(s[:n0, :n1], (2,), n2, False, 2, out[:n0, :n1], w)


def _r2c_pruned(pp, x: np.ndarray, out: np.ndarray, n0: int, n1: int) -> None:
    """rfftn of x that is zero outside x[:n0, :n1]: the transform along x only on the rows
    that hold data, along y only on the planes that do, along t everywhere (a zero-padded
    grid with data in its 1/8 costs about 0.58 of the full transform)."""
    _lateral_forward(pp, x, out, n0, n1)
    out[n0:] = 0
    pp.c2c(out, (0,), True, 0, out, _workers())


def _c2r_pruned(pp, s: np.ndarray, n2: int, out: np.ndarray, n0: int, n1: int) -> None:
    """out[:n0, :n1] <- irfftn(s)[:n0, :n1] (s overwritten; the rest of ``out`` untouched):
    the inverse along t everywhere, along y only on the planes kept, along x only on the
    rows kept."""
    pp.c2c(s, (0,), False, 2, s, _workers())
    _lateral_inverse(pp, s, n2, out, n0, n1)


def _block(shape, block) -> tuple[int, int] | None:
    """(n0, n1) of a low-corner block of ``shape`` that prunes something, else None."""
    if block is None:
        return None
    n0, n1 = (min(int(b), int(s)) for b, s in zip(block[:2], shape[:2], strict=True))
    return None if (n0, n1) == tuple(shape[:2]) else (n0, n1)


def host_rfftn(x: np.ndarray, out: np.ndarray, nonzero=None) -> None:
    """out <- rfftn(x) (unnormalised), written in place when the binding allows.

    ``nonzero``: (n0, n1, ...) when x is zero outside x[:n0, :n1] (a zero-padded grid):
    the transform skips the lines that are zero (:func:`_r2c_pruned`)."""
    pp = _pocketfft()
    block = _block(x.shape, nonzero)
    if pp is None:
        out[...] = sfft.rfftn(x, workers=_workers())
    elif block is None:
        pp.r2c(x, (0, 1, 2), True, 0, out, _workers())
    else:
        _r2c_pruned(pp, x, out, *block)


def host_irfftn(s: np.ndarray, shape, out: np.ndarray, needed=None) -> None:
    """out <- irfftn(s, shape) (divided by N), written in place when the binding allows.

    ``needed``: (n0, n1, ...) when only out[:n0, :n1] is used (a crop follows): only that
    block is computed and written (:func:`_c2r_pruned`); ``s`` is then overwritten."""
    pp = _pocketfft()
    block = _block(shape, needed)
    if pp is None:
        out[...] = sfft.irfftn(s, s=shape, axes=(0, 1, 2), workers=_workers())
    elif block is None:
        pp.c2r(s, (0, 1, 2), int(shape[-1]), False, 2, out, _workers())
    else:
        _c2r_pruned(pp, s, int(shape[-1]), out, *block)


def host_fftn_inplace(a: np.ndarray, forward: bool, block=None) -> None:
    """a <- fftn(a) or ifftn(a) (divided by N) in place; ``block`` = (n0, n1, ...): forward,
    a is zero outside a[:n0, :n1]; inverse, only a[:n0, :n1] is used afterwards (the rest
    is left partly transformed)."""
    pp = _pocketfft()
    b = _block(a.shape, block)
    if pp is not None and b is not None:
        w, norm = _workers(), 0 if forward else 2
        n0, n1 = b
        passes = [(2, a[:n0, :n1]), (1, a[:n0]), (0, a)]  # the forward order
        for axis, v in (passes if forward else passes[::-1]):
            pp.c2c(v, (axis,), forward, norm, v, w)
        return
    f = sfft.fftn if forward else sfft.ifftn
    _store(a, f(a, workers=_workers(), overwrite_x=True))


LOW_ROWS_BLOCK = 1 << 22  # complex values per block of the zero-padded pass along t (32 MB)


def _c2c_inverse(v: np.ndarray, axis: int) -> None:
    """v <- ifft(v) along ``axis`` (divided by its length), in place where the binding allows."""
    pp = _pocketfft()
    if pp is None:
        v[...] = sfft.ifft(v, axis=axis, workers=_workers())
    else:
        pp.c2c(v, (axis,), False, 2, v, _workers())


def host_ifftn_low_rows(a: np.ndarray, n0: int, needed) -> None:
    """a[:t0, :t1, :t2] <- ifftn(S)[:t0, :t1, :t2] (divided by N) for the (n0, n1, n2)
    spectrum S whose rows a.shape[0]..n0-1 are zero, ``a`` holding its rows 0..m-1 (m >= t0;
    (t0, t1, t2) = ``needed``): along x on every row, along y on the kept columns, then along
    t zero padded to n0 a block of columns at a time (a temporary of LOW_ROWS_BLOCK values),
    so the spectrum's zero rows are never stored. ``a`` is overwritten."""
    m, n1, n2 = a.shape
    t0, t1, t2 = (min(int(b), int(s)) for b, s in zip(needed, (m, n1, n2), strict=True))
    _c2c_inverse(a, 2)
    _c2c_inverse(a[:, :, :t2], 1)
    step = max(1, LOW_ROWS_BLOCK // max(1, n0 * t2))
    for y0 in range(0, t1, step):
        y1 = min(t1, y0 + step)
        blk = np.zeros((n0, y1 - y0, t2), a.dtype)
        blk[:m] = a[:, y0:y1, :t2]
        _c2c_inverse(blk, 0)
        a[:t0, y0:y1, :t2] = blk[:t0]


def _store(a: np.ndarray, result: np.ndarray) -> None:
    """Put an in-place transform's result in ``a`` (pocketfft already did when it could)."""
    if not np.shares_memory(a, result):
        a[...] = result


class RealFFT3:
    """Real-to-complex 3D FFT plan for a fixed shape and precision on one queue."""

    def __init__(self, shape: tuple[int, int, int], dtype=np.float32, queue=None):
        self.queue = get_queue(queue)
        self.dtype = require_dtype(self.queue.device, dtype)
        self.cdtype = COMPLEX_OF[self.dtype]
        self.shape = tuple(int(s) for s in shape)
        self.spec_shape = self.shape[:-1] + (self.shape[-1] // 2 + 1,)
        require_memory(self.queue.device, int(np.prod(self.spec_shape)) * self.cdtype.itemsize,
                       f"FFT of shape {self.shape}")
        self.backend = _backend(self.queue)
        self._app = None
        if self.backend == "vkfft":
            self._app = _vkfft_app(self.shape, self.dtype, self.queue, True)

    def empty_spectrum(self) -> cla.Array:
        return cla.empty(self.queue, self.spec_shape, self.cdtype)

    def forward(self, x_g: cla.Array, out_g: cla.Array | None = None, *,
                nonzero=None) -> cla.Array:
        """Half spectrum of the real array ``x_g`` (not modified). ``nonzero`` = (n0, n1,
        n2): x is zero outside its low-corner block of that shape (zero padding), which the
        host FFT uses to skip lines of zeros."""
        out_g = self.empty_spectrum() if out_g is None else out_g
        if self._app is not None:
            self._app.fft(x_g, out_g)
        else:
            with host_view(x_g) as x, host_view(out_g, write=True, read=False) as out:
                host_rfftn(x, out, nonzero)
        return out_g

    def inverse(self, s_g: cla.Array, out_g: cla.Array | None = None, *,
                needed=None) -> cla.Array:
        """Real array from a half spectrum; ``s_g`` is overwritten (VkFFT C2R does).
        ``needed`` = (n0, n1, n2): only the low-corner block of that shape is used (a crop
        follows); the host FFT then writes only that block."""
        out_g = cla.empty(self.queue, self.shape, self.dtype) if out_g is None else out_g
        if self._app is not None:
            self._app.ifft(s_g, out_g)
        else:
            with host_view(s_g) as s, host_view(out_g, write=True, read=False) as out:
                host_irfftn(s, self.shape, out, needed)
        return out_g


    @property
    def split_axes(self) -> bool:
        """Whether the plan transforms the lateral axes and the time axis apart
        (:meth:`forward_lateral`, :meth:`time_pass`, :meth:`inverse_lateral`): the host FFT
        (pocketfft along one axis at a time); a VkFFT plan is the whole 3D transform."""
        return self._app is None and _pocketfft() is not None

    def _split_host(self, what: str):
        if self._app is not None:
            raise ValueError(f"{what} on a VkFFT plan of {self.shape}: the split transforms "
                             "are the host FFT's (split_axes)")
        pp = _pocketfft()
        if pp is None:
            raise ValueError(f"{what} needs scipy's pocketfft binding (scipy.fft._pocketfft)")
        return pp

    def forward_lateral(self, x_g: cla.Array, out_g: cla.Array, *, rows: int,
                        nonzero_y: int) -> cla.Array:
        """out[:rows] <- the 2D half spectrum over (y, x) of the planes x[:rows] (x real of
        the plan's shape, zero outside x[:rows, :nonzero_y]; ``out_g`` complex, at least
        ``rows`` planes of (n1, n2 // 2 + 1)): the first two passes of :meth:`forward`."""
        pp = self._split_host("forward_lateral")
        keep = out_g.shape[0] > rows  # planes past ``rows`` kept; else all of it written
        with host_view(x_g) as x, host_view(out_g, write=True, read=keep) as out:
            _lateral_forward(pp, x, out, int(rows), int(nonzero_y))
        return out_g

    def time_pass(self, s_g: cla.Array, *, inverse: bool) -> cla.Array:
        """s <- its FFT along t (the first axis; the inverse divided by n0), in place, on a
        half-spectrum array of the plan's spectrum shape: the last pass of :meth:`forward`,
        the first of :meth:`inverse`."""
        pp = self._split_host("time_pass")
        with host_view(s_g, write=True) as s:
            pp.c2c(s, (0,), not inverse, 2 if inverse else 0, s, _workers())
        return s_g

    def inverse_lateral(self, s_g: cla.Array, out_g: cla.Array, *, rows: int,
                        needed_y: int) -> cla.Array:
        """out[:rows, :needed_y] <- the 2D inverse over (y, x) of the planes s[:rows]
        (divided by n1 n2; s overwritten there): the last two passes of :meth:`inverse`."""
        pp = self._split_host("inverse_lateral")
        with host_view(s_g, write=True) as s, host_view(out_g, write=True) as out:
            _lateral_inverse(pp, s, self.shape[2], out, int(rows), int(needed_y))
        return out_g


class ComplexFFT3:
    """In-place complex 3D FFT plan for a fixed shape and precision on one queue."""

    def __init__(self, shape: tuple[int, int, int], dtype=np.float32, queue=None):
        self.queue = get_queue(queue)
        self.dtype = require_dtype(self.queue.device, dtype)
        self.cdtype = COMPLEX_OF[self.dtype]
        self.shape = tuple(int(s) for s in shape)
        require_memory(self.queue.device, int(np.prod(self.shape)) * self.cdtype.itemsize,
                       f"FFT of shape {self.shape}")
        self.backend = _backend(self.queue)
        self._app = None
        if self.backend == "vkfft":
            self._app = _vkfft_app(self.shape, self.cdtype, self.queue, False)
        # :meth:`inverse_low_rows` takes the low rows alone (the host FFT pads them itself)
        self.low_rows = self._app is None

    def forward(self, a_g: cla.Array, *, nonzero=None) -> cla.Array:
        """In-place FFT; ``nonzero`` as for :meth:`RealFFT3.forward`."""
        if self._app is not None:
            self._app.fft(a_g)
        else:
            with host_view(a_g, write=True) as a:
                host_fftn_inplace(a, True, nonzero)
        return a_g

    def inverse(self, a_g: cla.Array, *, needed=None) -> cla.Array:
        """In-place inverse FFT (divided by N); ``needed`` as for :meth:`RealFFT3.inverse`
        (outside that block the array holds partial transforms)."""
        if self._app is not None:
            self._app.ifft(a_g)
        else:
            with host_view(a_g, write=True) as a:
                host_fftn_inplace(a, False, needed)
        return a_g

    def inverse_low_rows(self, a_g: cla.Array, *, needed) -> cla.Array:
        """The inverse FFT (divided by N) of a spectrum of the plan's shape whose rows past
        ``a_g.shape[0]`` are zero, ``a_g`` holding its low rows (the rest never stored):
        afterwards ``a_g[:t0, :t1, :t2]`` holds the inverse's low-corner block ``needed`` =
        (t0, t1, t2), t0 <= a_g.shape[0] (the rest of ``a_g`` is overwritten). With VkFFT
        (:attr:`low_rows` False) ``a_g`` must hold every row: :meth:`inverse`."""
        if tuple(a_g.shape) == self.shape:
            return self.inverse(a_g, needed=needed)
        if not self.low_rows:
            raise ValueError(f"inverse_low_rows of {a_g.shape} rows on a VkFFT plan of "
                             f"{self.shape}: VkFFT needs the whole grid")
        with host_view(a_g, write=True) as a:
            host_ifftn_low_rows(a, self.shape[0], needed)
        return a_g


POCL_VKFFT_ISSUE = "https://github.com/pocl/pocl/issues/2069"


@dataclass(frozen=True)
class FFTChoice:
    """The FFT backend of a queue: ``"vkfft"`` (pyvkfft on the device) or ``"host"``
    (scipy.fft on the host, on mapped buffers), why, and whether the reason deserves a warning."""

    backend: str
    reason: str
    warn: bool = False


def fft_backend(queue: cl.CommandQueue, settings: Settings | None = None) -> FFTChoice:
    """The FFT backend for this queue's device.

    ``CLNLOS_FFT`` (``auto`` by default) overrides: ``host`` (alias ``numpy``) or ``vkfft``
    (an error when pyvkfft's OpenCL backend cannot be imported). ``auto``: the host FFT on CPU
    devices (there the FFT runs on the same cores either way, and scipy's pocketfft measured
    1.3-1.6x faster than VkFFT on PoCL: ``clnlos bench --only reconstruction_process``), and
    on PoCL >= 7, which miscompiles VkFFT (pocl issue 2069); VkFFT elsewhere (GPUs), falling
    back to the host with a warning when pyvkfft is missing.
    """
    s = resolve(settings)
    choice = s.fft
    if choice == "host":
        return FFTChoice("host", f"{ENV_FFT}={s.fft_written}")
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
            raise DeviceError(vkfft_missing(vk_error))
        return FFTChoice("vkfft", f"{ENV_FFT}=vkfft")
    if vk_error is not None:
        return FFTChoice("host", f"pyvkfft (OpenCL backend) not importable: {vk_error}",
                         warn=True)
    return FFTChoice("vkfft", "pyvkfft on the device")


def vkfft_missing(why: str) -> str:
    """The one-line message of CLNLOS_FFT=vkfft without pyvkfft's OpenCL backend."""
    return (f"{ENV_FFT}=vkfft but pyvkfft's OpenCL backend is not importable ({why}); install "
            "the extra: pip install 'clnlos[vkfft]' (VKFFT_BACKEND=opencl), or unset " + ENV_FFT)


def check_vkfft_importable() -> None:
    """A DeviceError (one line) when pyvkfft's OpenCL backend cannot be imported."""
    try:
        import pyvkfft.opencl  # noqa: F401  (optional dependency, imported only when asked)
    except Exception as exc:
        raise DeviceError(vkfft_missing(f"{type(exc).__name__}: {exc}")) from None
