"""Mass-conserving resampling along the first axis (time / depth), run by ``kernels/resample.cl``.

A histogram is resampled by bin overlaps, never by point sampling: source bin k with
edges [a_k, a_{k+1}] sends the fraction |[a_k, a_{k+1}] & [b_j, b_{j+1}]| / (a_{k+1} - a_k)
of its content to destination bin j (edges b), both measured in one common coordinate.
Sums are conserved where the destination covers the source. The matrix is built on the host
(float64, scipy CSR) once per plan and applied on the device for every (y, x) column.
"""

from __future__ import annotations

import numpy as np
import pyopencl.array as cla
import scipy.sparse as sp

from clnlos.errors import ShapeError
from clnlos.operators.base import LinearOperator
from clnlos.runtime.buffers import kernel_int, round_up, zeros
from clnlos.runtime.device import get_queue, require_dtype
from clnlos.runtime.programs import get_kernels, real_defines


def overlap_matrix(src_edges, dst_edges) -> sp.csr_matrix:
    """CSR matrix (n_dst, n_src) of the fraction of each source bin inside each destination bin.

    Edges must be increasing and in the same coordinate. Empty source bins (zero width)
    map to nothing.
    """
    a = np.asarray(src_edges, np.float64)
    b = np.asarray(dst_edges, np.float64)
    if a.ndim != 1 or b.ndim != 1 or a.size < 2 or b.size < 2:
        raise ShapeError("bin edges must be 1D with at least two entries")
    if np.any(np.diff(a) < 0) or np.any(np.diff(b) < 0):
        raise ShapeError("bin edges must be non-decreasing")
    rows, cols, vals = [], [], []
    width = np.diff(a)
    for j in range(b.size - 1):
        lo, hi = b[j], b[j + 1]
        k0 = max(int(np.searchsorted(a, lo, side="right")) - 1, 0)
        k1 = min(int(np.searchsorted(a, hi, side="left")), a.size - 1)
        for k in range(k0, k1):
            ov = min(hi, a[k + 1]) - max(lo, a[k])
            if ov > 0 and width[k] > 0:
                rows.append(j)
                cols.append(k)
                vals.append(ov / width[k])
    return sp.csr_matrix((vals, (rows, cols)), shape=(b.size - 1, a.size - 1))


def rebin_matrix(n_in: int, n_out: int) -> sp.csr_matrix:
    """Sum n_in bins into n_out equal bins covering the same span (mass-conserving)."""
    return overlap_matrix(np.linspace(0, 1, n_in + 1), np.linspace(0, 1, n_out + 1))


class AxisResample(LinearOperator):
    """y[r, y, x] = sum_k A[r, k] x[k, y, x] for a fixed sparse A, on the device.

    The matrix acts on a block of ``plane = (ny, nx)`` columns. By default input and output
    planes are that block: input (n_in, ny, nx) -> output (n_out, ny, nx). ``in_plane`` with
    ``in_offset`` reads the block from a larger input plane (a crop); ``out_plane`` with
    ``out_offset`` writes it into a larger zero-padded output plane and ``out_rows`` makes a
    taller output (rows past n_out are zero): so padding and cropping for FFTs cost no extra
    pass. The adjoint uses A^T, reads the block where the forward wrote it and writes it where
    the forward read it (zero elsewhere).
    """

    name = "axis_resample"

    def __init__(self, matrix, plane: tuple[int, int], *, dtype=np.float32, queue=None,
                 out_plane: tuple[int, int] | None = None, out_rows: int | None = None,
                 in_plane: tuple[int, int] | None = None,
                 in_offset: tuple[int, int] = (0, 0), out_offset: tuple[int, int] = (0, 0)):
        self.queue = get_queue(queue)
        self.dtype = require_dtype(self.queue.device, dtype)
        A = sp.csr_matrix(matrix, dtype=np.float64)
        self.matrix = A
        ny, nx = (int(v) for v in plane)
        oy, ox = (int(v) for v in (out_plane if out_plane is not None else (ny, nx)))
        iy, ix = (int(v) for v in (in_plane if in_plane is not None else (ny, nx)))
        self.in_offset = tuple(int(v) for v in in_offset)
        self.out_offset = tuple(int(v) for v in out_offset)
        n_out = A.shape[0] if out_rows is None else int(out_rows)
        if (oy < ny + self.out_offset[0] or ox < nx + self.out_offset[1]
                or iy < ny + self.in_offset[0] or ix < nx + self.in_offset[1]
                or min(self.in_offset + self.out_offset) < 0 or n_out < A.shape[0]):
            raise ShapeError(f"block {ny}x{nx} at input offset {self.in_offset} / output offset "
                             f"{self.out_offset} does not fit the planes {(iy, ix)} / "
                             f"{(oy, ox)} (or out_rows {n_out} < {A.shape[0]} matrix rows)")
        self.plane, self.in_plane, self.out_plane = (ny, nx), (iy, ix), (oy, ox)
        self.n_rows_out = n_out
        self.in_shape = (A.shape[1], iy, ix)
        self.out_shape = (n_out, oy, ox)
        self._k = get_kernels(self.queue, "resample", real_defines(self.dtype))
        self._fwd = self._upload(A)
        self._adj = self._upload(A.T.tocsr())

    def _upload(self, A: sp.csr_matrix):
        q = self.queue
        return (A.shape[0], cla.to_device(q, A.indptr.astype(np.int32)),
                cla.to_device(q, np.maximum(A.indices, 0).astype(np.int32) if A.nnz else
                              np.zeros(1, np.int32)),
                cla.to_device(q, A.data.astype(self.dtype) if A.nnz else
                              np.zeros(1, self.dtype)))

    def _launch(self, mats, x_g, in_plane, in_off, out_g, out_plane, out_off):
        n_rows, ptr, col, val = mats
        ny, nx = self.plane
        if n_rows and ny and nx:
            i32 = kernel_int
            self._k.csr_resample(
                self.queue, (round_up(nx, 8), round_up(ny, 8), n_rows), None,
                ptr.data, col.data, val.data,
                x_g.data, i32(in_plane[0]), i32(in_plane[1]), i32(in_off[0]), i32(in_off[1]),
                out_g.data, i32(out_plane[0]), i32(out_plane[1]), i32(out_off[0]),
                i32(out_off[1]), i32(n_rows), i32(ny), i32(nx))
        return out_g

    def _pads_output(self, forward: bool) -> bool:
        if forward:
            return (self.out_plane != self.plane or self.n_rows_out != self.matrix.shape[0])
        return self.in_plane != self.plane

    def apply_into(self, x_g: cla.Array, out_g: cla.Array) -> cla.Array:
        """Forward into an existing output buffer of ``out_shape`` (must be zeroed where padded)."""
        return self._launch(self._fwd, x_g, self.in_plane, self.in_offset, out_g,
                            self.out_plane, self.out_offset)

    def adjoint_into(self, y_g: cla.Array, out_g: cla.Array) -> cla.Array:
        """Adjoint into an existing buffer of ``in_shape`` (must be zeroed outside the block)."""
        return self._launch(self._adj, y_g, self.out_plane, self.out_offset, out_g,
                            self.in_plane, self.in_offset)

    def _apply(self, x_g):
        out_g = (zeros if self._pads_output(True) else cla.empty)(self.queue, self.out_shape,
                                                                   self.dtype)
        return self.apply_into(x_g, out_g)

    def _adjoint(self, y_g):
        out_g = (zeros if self._pads_output(False) else cla.empty)(self.queue, self.in_shape,
                                                                    self.dtype)
        return self.adjoint_into(y_g, out_g)
