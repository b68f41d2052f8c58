"""HDF5 datasets compressed in parallel: HDF5's own shuffle + deflate (gzip) filters,
computed by threads, written as raw chunks.

h5py compresses chunk by chunk in the calling thread; a 32 MB reconstruction takes
0.15-0.4 s that way (gzip level 1 + shuffle), alone on one core. Here the chunks are
shuffled and deflated by a thread pool (``zlib`` releases the GIL), started as soon as the
array exists, so the work runs beside whatever the caller does next (drawing the figure) and
on every core; the chunks are then written with ``write_direct_chunk``. The file is an
ordinary HDF5 file with the standard filter pipeline: any HDF5 reader decompresses it.
Arrays that would not shrink by a quarter (judged on one probe chunk) are stored
uncompressed instead.
"""

from __future__ import annotations

import zlib
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

from clnlos.settings import current as current_settings

GZIP_LEVEL = 1  # fast; with the shuffle filter smaller than level 4 without it on volumes
CHUNK_BYTES = 1 << 20  # chunks of about 1 MB along the first axis
MIN_PARALLEL_BYTES = 4 * CHUNK_BYTES  # smaller arrays go through h5py directly
# a probe chunk that deflates to more than this fraction of its size: the array is stored
# uncompressed (dense float noise, e.g. an f-k volume: 0.81 at 70 MB/s per core, 0.25 s
# of two cores for 19% of 33 MB; an LCT volume deflates to 0.1 at 300 MB/s)
RAW_ABOVE_RATIO = 0.75


def chunk_shape(shape: tuple[int, ...], itemsize: int) -> tuple[int, ...]:
    """Chunks of whole trailing planes, about CHUNK_BYTES each."""
    plane = int(np.prod(shape[1:], dtype=np.int64)) * itemsize
    rows = max(1, min(int(shape[0]), CHUNK_BYTES // max(plane, 1)))
    return (rows,) + tuple(int(s) for s in shape[1:])


def shuffle_deflate(block: np.ndarray, level: int = GZIP_LEVEL) -> bytes:
    """HDF5's shuffle filter (byte k of every element, for k = 0..itemsize-1, one after the
    other) followed by deflate: the bytes of one stored chunk."""
    b = np.ascontiguousarray(block)
    planes = b.view(np.uint8).reshape(-1, b.dtype.itemsize).T
    return zlib.compress(np.ascontiguousarray(planes).tobytes(), level)


class DeflatedArray:
    """An array whose chunks are being compressed in background threads; :meth:`write`
    stores it as a dataset (chunked, shuffle + gzip ``level``)."""

    def __init__(self, array: np.ndarray, *, level: int = GZIP_LEVEL, threads: int | None = None):
        self.array = np.ascontiguousarray(array)
        self.level = int(level)
        a = self.array
        self.chunks = chunk_shape(a.shape, a.dtype.itemsize)
        rows = self.chunks[0]
        starts = list(range(0, a.shape[0], rows))
        probe_at = starts[len(starts) // 2]
        probe = self._chunk(probe_at, rows)
        self.compressed = len(probe) <= RAW_ABOVE_RATIO * rows * (a.nbytes // a.shape[0])
        self._parts = []
        if self.compressed:
            pool = ThreadPoolExecutor(max_workers=threads or current_settings().host_threads())
            done = Future()
            done.set_result(probe)
            self._parts = [(r0, done if r0 == probe_at else pool.submit(self._chunk, r0, rows))
                           for r0 in starts]
            pool.shutdown(wait=False)

    def _chunk(self, r0: int, rows: int) -> bytes:
        part = self.array[r0:r0 + rows]
        if part.shape[0] < rows:  # the last chunk is stored whole: pad it with zeros
            part = np.concatenate([part, np.zeros((rows - part.shape[0],) + part.shape[1:],
                                                  part.dtype)])
        return shuffle_deflate(part, self.level)

    def write(self, f, name: str):
        """Create dataset ``name`` in the open h5py file ``f`` and store the chunks (or the
        array uncompressed, when deflating it did not pay)."""
        a = self.array
        if not self.compressed:
            return f.create_dataset(name, data=a)
        dset = f.create_dataset(name, shape=a.shape, dtype=a.dtype, chunks=self.chunks,
                                compression="gzip", compression_opts=self.level,
                                shuffle=True)
        zeros = (0,) * (a.ndim - 1)
        for r0, fut in self._parts:
            dset.id.write_direct_chunk((r0,) + zeros, fut.result())
        return dset


def write_dataset(f, name: str, data) -> None:
    """Store ``data`` (an array or a :class:`DeflatedArray`) as dataset ``name``: large
    numeric arrays deflated in parallel, others through h5py (gzip + shuffle as well)."""
    if isinstance(data, DeflatedArray):
        data.write(f, name)
        return
    arr = np.asarray(data)
    if (arr.ndim >= 1 and arr.nbytes >= MIN_PARALLEL_BYTES
            and arr.dtype.kind in "fiuc" and not arr.dtype.hasobject):
        DeflatedArray(arr).write(f, name)
    elif arr.ndim == 0 or arr.size == 0:
        f.create_dataset(name, data=arr)
    else:
        f.create_dataset(name, data=arr, compression="gzip", compression_opts=GZIP_LEVEL,
                         shuffle=True)
