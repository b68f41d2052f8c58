"""Device buffers: host views and copies, zero fills, shared work buffers (Scratch), kernel
sizes."""

from __future__ import annotations

import contextlib

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from clnlos.errors import DeviceCapabilityError, ShapeError
from clnlos.runtime.device import is_oclgrind
from clnlos.runtime.programs import get_kernels


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


def upload_rows(a_g, r0: int, rows: np.ndarray) -> None:
    """Blocking copy of ``rows`` into rows r0:r0 + len(rows) of the device array ``a_g``."""
    rows = np.ascontiguousarray(rows, a_g.dtype)
    row_bytes = int(np.prod(a_g.shape[1:])) * a_g.dtype.itemsize
    cl.enqueue_copy(a_g.queue, a_g.base_data, rows, dst_offset=a_g.offset + r0 * row_bytes,
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
    a = cla.empty(queue, shape, dtype)
    fill_zero(queue, a)
    return a


class Scratch:
    """Device work buffers shared by the stages of one plan, which run one after another on
    one queue (a plan is never shared across threads, :mod:`clnlos.runtime.caches`).

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
        # views handed out per slot: what a stage left in a slot is still there while this
        # count has not moved (SpectralFilter's kept spectrum)
        self.requests: dict[str, int] = {}

    def reserve(self, slot: str, shape, dtype) -> None:
        nbytes = int(np.prod(shape)) * np.dtype(dtype).itemsize
        self._need[slot] = max(self._need.get(slot, 0), nbytes)

    def array(self, slot: str, shape, dtype):
        """A ``shape``/``dtype`` view of the slot (reserved first if it was not)."""
        self.reserve(slot, shape, dtype)
        self.requests[slot] = self.requests.get(slot, 0) + 1
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

    reserved_nbytes = nbytes  # what a plan cache counts (clnlos.runtime.caches.device_bytes)


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
