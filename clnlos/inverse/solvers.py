"""Regularised least squares by accelerated proximal gradient (FISTA) on device arrays.

Problem, for a linear operator A (:mod:`clnlos.operators.base`) and data y::

    min_x  1/2 || A x - y ||_W^2  +  l1 sum(x)  +  tv TV(x)   s.t.  x >= 0 on the support

(W an optional diagonal weight; the support is the depth rows k >= ``row_min``; TV the
isotropic total variation with forward differences, the depth difference scaled by ``wz``).
Since x >= 0 the L1 norm is the linear term l1 sum(x).

FISTA (Beck & Teboulle 2009) with the gradient restart of O'Donoghue & Candes (2015): the
momentum is reset whenever <z - x_{k+1}, x_{k+1} - x_k> > 0, which keeps the monotone decay
of a plain gradient method on ill-conditioned problems and the O(1/k^2) rate elsewhere. The
step is 1/L with L = ||A^T W A|| from a power iteration. The prox of
step (l1 sum + tv TV + i(x >= 0)) is prox_{step tv TV + i}(v - step l1) (the L1 term is
linear on the non-negative orthant), computed by the fast dual projection (FGP) of Beck &
Teboulle (2009), warm-started from the previous dual; without TV it is max(v - step l1, 0).

Stopping rule: ``iterations`` at most; earlier when the relative change
||x_{k+1} - x_k|| / ||x_{k+1}||, checked every CHECK_EVERY iterations, is below ``tol`` at two
checks in a row.
Element-wise updates run in ``kernels/prox.cl``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from clnlos.operators.base import LinearOperator
from clnlos.runtime.buffers import fill_zero, round_up, zeros
from clnlos.runtime.programs import get_kernels, real_defines

TV_INNER_ITERATIONS = 10  # FGP iterations per prox (warm-started from the last dual)
POWER_ITERATIONS = 15
CHECK_EVERY = 10  # data term and relative change are evaluated every this many iterations


def _launch1(queue, n: int) -> tuple[int]:
    return (round_up(max(n, 1), 256),)


def lipschitz(op: LinearOperator, weights: cla.Array | None = None, *,
              iterations: int = POWER_ITERATIONS, seed: int = 0, progress=None) -> float:
    """Upper estimate of ||A^T W A|| by power iteration (+5%), on the device;
    ``progress(k, iterations)`` is called as power iteration k (from 1) starts."""
    q = op.queue
    x = cla.to_device(q, np.random.default_rng(seed).random(op.in_shape).astype(op.dtype))
    est = 0.0
    for k in range(iterations):
        if progress is not None:
            progress(k + 1, iterations)
        ax = op.apply_device(x)
        if weights is not None:
            ax *= weights
        y = op.adjoint_device(ax)
        ny = float(cla.dot(y, y).get()) ** 0.5
        nx = float(cla.dot(x, x).get()) ** 0.5
        if ny == 0 or nx == 0:
            return 0.0
        est = ny / nx
        x = y * op.dtype.type(1.0 / ny)
    return 1.05 * est


@dataclass
class FistaResult:
    x: cla.Array
    iterations: int
    restarts: int
    objective: list = field(default_factory=list)  # (iteration, data term) every CHECK_EVERY
    change: list = field(default_factory=list)     # (iteration, relative change) likewise


class ProxKernels:
    """The prox.cl kernels for one volume shape and precision."""

    def __init__(self, queue, shape, dtype):
        self.queue, self.shape, self.dtype = queue, tuple(int(s) for s in shape), np.dtype(dtype)
        self.n = int(np.prod(self.shape))
        self.k = get_kernels(queue, "prox", real_defines(self.dtype))

    def prox_step(self, z, g, x0, x1, r, step, shift, row_min):
        nz, ny, nx = self.shape
        ul = np.uint64
        self.k.prox_step(self.queue, _launch1(self.queue, self.n), None, z.data, g.data,
                         x0.data, x1.data, r.data, self.dtype.type(step),
                         self.dtype.type(shift), ul(row_min), ul(ny * nx), ul(self.n))

    def gradient_step(self, z, g, v, step, shift):
        self.k.gradient_step(self.queue, _launch1(self.queue, self.n), None, z.data, g.data,
                             v.data, self.dtype.type(step), self.dtype.type(shift),
                             np.uint64(self.n))

    def restart_terms(self, z, x1, x0, r):
        self.k.restart_terms(self.queue, _launch1(self.queue, self.n), None, z.data, x1.data,
                             x0.data, r.data, np.uint64(self.n))

    def momentum(self, x1, x0, z, beta):
        self.k.momentum(self.queue, _launch1(self.queue, self.n), None, x1.data, x0.data,
                        z.data, self.dtype.type(beta), np.uint64(self.n))

    def tv_prox(self, v, lam, wz, row_min, p, out, iterations=TV_INNER_ITERATIONS):
        """out = argmin 1/2||x - v||^2 + lam TV(x), x >= 0 on the support (FGP); ``p`` is
        the dual [3, nz, ny, nx], warm start in and result out."""
        nz, ny, nx = self.shape
        ul, r = np.uint64, self.dtype.type
        g3 = (round_up(nx, 8), round_up(ny, 8), nz)
        q = p.copy()
        p1 = cla.empty_like(p)
        t = 1.0
        scale = 1.0 / (lam * (8.0 + 4.0 * wz * wz))
        for _ in range(iterations):
            self.k.tv_primal(self.queue, g3, None, v.data, q.data, out.data, r(lam), r(wz),
                             ul(nz), ul(ny), ul(nx), ul(row_min))
            t1 = (1 + math.sqrt(1 + 4 * t * t)) / 2
            self.k.tv_dual(self.queue, g3, None, out.data, p.data, p1.data, q.data, r(scale),
                           r((t - 1) / t1), r(wz), ul(nz), ul(ny), ul(nx))
            p, p1 = p1, p
            t = t1
        self.k.tv_primal(self.queue, g3, None, v.data, p.data, out.data, r(lam), r(wz),
                         ul(nz), ul(ny), ul(nx), ul(row_min))
        return p

    def weighted_residual(self, a, y, w, out):
        n = a.size
        self.k.weighted_residual(self.queue, _launch1(self.queue, n), None, a.data, y.data,
                                 (w if w is not None else a).data, out.data,
                                 np.int32(w is not None), np.uint64(n))


def fista(op: LinearOperator, y: cla.Array, x0: cla.Array, *, l1: float = 0.0,
          tv: float = 0.0, wz: float = 1.0, weights: cla.Array | None = None,
          row_min: int = 0, iterations: int, tol: float = 1e-4,
          lipschitz_const: float | None = None, callback=None) -> FistaResult:
    """Minimise the problem of the module docstring from ``x0`` (device arrays, op's dtype).

    ``callback(k, x)`` is called after every iteration (x on the device) for monitoring.
    """
    q, dt = op.queue, op.dtype
    L = lipschitz(op, weights) if lipschitz_const is None else float(lipschitz_const)
    if not L > 0:
        return FistaResult(x0.copy(), 0, 0)
    step = 1.0 / L
    pk = ProxKernels(q, op.in_shape, dt)
    x = x0.copy()
    z = x0.copy()
    x1 = cla.empty_like(x0)
    r = cla.empty_like(x0)
    v = cla.empty_like(x0) if tv > 0 else None
    p = zeros(q, (3,) + tuple(op.in_shape), dt) if tv > 0 else None
    res = cla.empty(q, op.out_shape, dt)
    t, restarts, quiet = 1.0, 0, 0
    out = FistaResult(x, 0, 0)
    for k in range(iterations):
        check = (k + 1) % CHECK_EVERY == 0 or k + 1 == iterations
        az = op.apply_device(z)
        pk.weighted_residual(az, y, weights, res)
        if check:
            out.objective.append((k + 1, 0.5 * float(cla.dot(res, az - y).get())))
        g = op.adjoint_device(res)
        if tv > 0:
            pk.gradient_step(z, g, v, step, step * l1)
            p = pk.tv_prox(v, step * tv, wz, row_min, p, x1)
            pk.restart_terms(z, x1, x, r)
        else:
            pk.prox_step(z, g, x, x1, r, step, step * l1, row_min)
        restart = float(cla.sum(r).get()) > 0
        if check:
            dx = x1 - x
            nrm = float(cla.dot(x1, x1).get()) ** 0.5
            change = float(cla.dot(dx, dx).get()) ** 0.5 / nrm if nrm > 0 else 0.0
            out.change.append((k + 1, change))
            quiet = quiet + 1 if change < tol else 0
        if restart:
            t1, restarts = 1.0, restarts + 1
            cla_copy(z, x1)
        else:
            t1 = (1 + math.sqrt(1 + 4 * t * t)) / 2
            pk.momentum(x1, x, z, (t - 1) / t1)
        x, x1 = x1, x
        t = t1
        out.iterations = k + 1
        if callback is not None:
            callback(k, x)
        if quiet >= 2:
            break
    out.x, out.restarts = x, restarts
    return out


def cla_copy(dst: cla.Array, src: cla.Array) -> None:
    """Device-to-device copy of equal-sized arrays."""
    cl.enqueue_copy(dst.queue, dst.base_data, src.base_data, byte_count=src.nbytes,
                    src_offset=src.offset, dst_offset=dst.offset)


__all__ = ["fista", "lipschitz", "FistaResult", "ProxKernels", "fill_zero"]
