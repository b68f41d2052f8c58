"""Regularised least squares by accelerated proximal gradient (FISTA) on device arrays.

Problem, for a linear operator A (:mod:`clnlos.operators.base`) and data y::

    min_x  1/2 || A x - y ||_W^2  +  l1 sum(x)  +  tv TV(x)   s.t.  x >= 0 on the support

(W an optional diagonal weight; the support is the depth rows k >= ``row_min``; TV the
isotropic total variation with forward differences, the depth difference scaled by ``wz``).
Since x >= 0 the L1 norm is the linear term l1 sum(x).

FISTA (Beck & Teboulle 2009) with the gradient restart of O'Donoghue & Candes (2015): the
momentum is reset whenever <z - x_{k+1}, x_{k+1} - x_k> > 0, which keeps the monotone decay
of a plain gradient method on ill-conditioned problems and the O(1/k^2) rate elsewhere. The
prox of step (l1 sum + tv TV + i(x >= 0)) is prox_{step tv TV + i}(v - step l1) (the L1 term
is linear on the non-negative orthant), computed by the fast dual projection (FGP) of Beck &
Teboulle (2009), warm-started from the previous dual; without TV it is max(v - step l1, 0).

Working set (without TV, ``working_set=True``). The step of a proximal gradient method is
1/L, L = ||A^T W A|| (a power iteration), and L is set by the direction in which every
variable moves together -- for a blur, its DC response. A sparse solution never moves that
way: once the non-zero variables are known, only those (and the zeros whose gradient
would lift them, g_i + l1 < 0: the violated KKT conditions) are free, and the problem
restricted to that working set S has the much smaller constant L_S = ||P_S A^T W A P_S||
(P_S the restriction). The solver runs rounds: the first CHECK_EVERY iterations on the
whole support with step 1/L; then S = {x > 0} U {x = 0, g + l1 < 0} from the full
gradient at the current point, L_S by a power iteration on A P_S (warm-started from the
last round's vector, times WORKING_SET_SAFETY), and FISTA with step 1/L_S on S (the prox
holds the rest at 0) until it converges on S or WORKING_SET_ROUND iterations pass; then
the KKT conditions are checked on the whole support again. The restricted problems share
the minimiser of the full one once S contains its support, which the check sees: the
solver stops only where the rule below is met on S *and* no variable outside S violates
its KKT condition. A round whose objective rises past its start by more than
WORKING_SET_DIVERGENCE of it (an underestimated L_S) restarts from that start with L_S
doubled. (Working sets for the Lasso: e.g. Johnson & Guestrin 2015, "Blitz"; Massias,
Gramfort & Salmon 2018, "Celer".)

Stopping rule: ``iterations`` at most; earlier where the objective F = data term + l1
sum(x), evaluated every CHECK_EVERY iterations, fell by less than ``tol`` of itself since
the last evaluation (with a working set: on S, and no KKT violation outside it; with TV,
whose objective is not evaluated, the iterate's relative change over the window instead).
The minimiser is not the aim: the L1 solution grows spikier the closer FISTA gets to it,
so the rule stops where the objective has stopped falling quickly -- after as many
iterations as the capture needs, where a constant count fits none of them. How DEFAULT_TOL
and the working set's constants were chosen, and what they cost and earn on the oracle
captures: docs/performance.md.

No host round trip inside an iteration: the restart test sums on the device and the
momentum sequence (t, beta, restarts) lives in a device buffer (``kernels/prox.cl``
``fista_state``). Scalars come back every CHECK_EVERY iterations (the data term and the
change, for the stopping rule) and at each working-set update (its size, the violations,
the power iteration's norms).
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
POWER_ITERATIONS = 8  # from a seeded uniform start, 0.96 of the norm or more on every grid measured
#                        (the 5% margin covers it; tools/power_iteration_check.py, docs/performance.md)
CHECK_EVERY = 10  # data term and relative change are evaluated every this many iterations
WORKING_SET_ROUND = 40  # iterations at most between two working-set updates
WORKING_SET_POWER_ITERATIONS = 4  # power iterations for L_S, warm-started from the last
WORKING_SET_SAFETY = 1.3  # L_S is taken this much above its power estimate
WORKING_SET_SHRINK = 0.5  # S is rebuilt (and L_S re-estimated) once it could halve
WORKING_SET_DIVERGENCE = 0.5  # a round's objective above its start by this fraction: L_S x 2
DEFAULT_TOL = 1e-3  # relative decrease of the objective over CHECK_EVERY iterations: stop


def _launch1(queue, n: int) -> tuple[int]:
    return (round_up(max(n, 1), 256),)


def lipschitz(op: LinearOperator, weights: cla.Array | None = None, *,
              iterations: int = POWER_ITERATIONS, seed: int = 0, progress=None) -> float:
    """Upper estimate of ||A^T W A|| by power iteration (+5%), on the device;
    ``progress(k, iterations)`` is called as power iteration k (from 1) starts."""
    x = cla.to_device(op.queue,
                      np.random.default_rng(seed).random(op.in_shape).astype(op.dtype))
    return 1.05 * power_norm(op, x, iterations, weights, progress)[0]


def power_norm(op: LinearOperator, x: cla.Array, iterations: int,
               weights: cla.Array | None = None, progress=None) -> tuple[float, cla.Array]:
    """(||A^T W A|| estimated from below by ``iterations`` power iterations from ``x``, the
    last iterate, normalised: the start of a later estimate of a nearby operator).

    Each step takes x to unit norm, then A x to unit norm before the adjoint, and multiplies
    the two norms in float64 on the host: ||A^T W A x|| = ||A x|| ||A^T W (A x / ||A x||)||.
    So no device array holds more than ||A|| ||W|| times a unit vector: the light cone's
    weights (z^4 into u, r^-(4+p) out of it) give ||A^T A|| past float32's range on a long
    window whose support reaches the scan plane, though A x and A^T y of the solve do not."""
    est = 0.0
    nx = device_norm(x)
    if not math.isfinite(nx):
        raise FloatingPointError(f"the power iteration of {op.name} starts from a vector that "
                                 f"is not finite (||x|| ~ {nx})")
    if nx == 0:
        return 0.0, x
    x = x * op.dtype.type(1.0 / nx)
    for k in range(iterations):
        if progress is not None:
            progress(k + 1, iterations)
        ax = op.apply_device(x)
        if weights is not None:
            ax *= weights
        na = device_norm(ax)
        if na == 0:
            return 0.0, x
        if not math.isfinite(na):
            est = na
            break
        ax *= op.dtype.type(1.0 / na)
        y = op.adjoint_device(ax)
        ny = device_norm(y)
        est = na * ny
        if ny == 0 or not math.isfinite(ny):
            break
        x = y * op.dtype.type(1.0 / ny)
    if not math.isfinite(est):
        raise FloatingPointError(f"the step size of {op.name} is not finite (||A^T A|| "
                                 f"~ {est}): the operator's weights overflow {op.dtype}")
    return est, x


def device_norm(x: cla.Array) -> float:
    """||x||_2 of a device array without overflow in its precision: scaled by max |x| (a
    float32 sum of squares overflows past 1.8e19, the power iteration's iterates on a support
    that reaches the scan plane, where the light cone's z^4 / r^8 peaks)."""
    m = float(cla.max(abs(x)).get())
    if not m > 0 or not math.isfinite(m):
        return m if m == m else float("nan")
    xs = x * x.dtype.type(1.0 / m)
    return m * float(cla.dot(xs, xs).get()) ** 0.5


class Restricted(LinearOperator):
    """A P_S: the operator ``op`` on the variables of a working set S only (``ws``, a uchar
    device array of op's input shape, 1 in S); its adjoint is P_S A^T."""

    def __init__(self, op: LinearOperator, ws: cla.Array, kernels: ProxKernels):
        self.op, self.ws, self.k = op, ws, kernels
        self.in_shape, self.out_shape = op.in_shape, op.out_shape
        self.dtype, self.queue, self.name = op.dtype, op.queue, f"{op.name}|S"

    def _apply(self, x_g):
        return self.op.apply_device(self.k.masked(x_g, self.ws))

    def _adjoint(self, y_g):
        return self.k.masked(self.op.adjoint_device(y_g), self.ws)


@dataclass
class FistaResult:
    x: cla.Array
    iterations: int
    restarts: int
    objective: list = field(default_factory=list)  # (iteration, data term) every CHECK_EVERY
    change: list = field(default_factory=list)     # (iteration, relative change) likewise
    rounds: list = field(default_factory=list)     # (iteration, |S| / n, violations, L_S / L)
    diverged: int = 0  # rounds restarted with L_S doubled


class ProxKernels:
    """The prox.cl kernels for one volume shape and precision."""

    def __init__(self, queue, shape, dtype):
        self.queue, self.shape, self.dtype = queue, tuple(int(s) for s in shape), np.dtype(dtype)
        self.n = int(np.prod(self.shape))
        self.k = get_kernels(queue, "prox", real_defines(self.dtype))
        self._no_ws = None  # a one-byte stand-in for the working set when there is none

    def prox_step(self, z, g, x0, x1, r, step, shift, row_min, ws=None):
        nz, ny, nx = self.shape
        ul = np.uint64
        if ws is None and self._no_ws is None:
            self._no_ws = cla.zeros(self.queue, 1, np.uint8)
        self.k.prox_step(self.queue, _launch1(self.queue, self.n), None, z.data, g.data,
                         x0.data, x1.data, r.data, (self._no_ws if ws is None else ws).data,
                         np.int32(ws is not None), self.dtype.type(step),
                         self.dtype.type(shift), ul(row_min), ul(ny * nx), ul(self.n))

    def gradient_step(self, z, g, v, step, shift):
        self.k.gradient_step(self.queue, _launch1(self.queue, self.n), None, z.data, g.data,
                             v.data, self.dtype.type(step), self.dtype.type(shift),
                             np.uint64(self.n))

    def restart_terms(self, z, x1, x0, r):
        self.k.restart_terms(self.queue, _launch1(self.queue, self.n), None, z.data, x1.data,
                             x0.data, r.data, np.uint64(self.n))

    def new_state(self) -> cla.Array:
        """The momentum state (t, beta, restarts) = (1, 0, 0) on the device."""
        return cla.to_device(self.queue, np.array([1.0, 0.0, 0.0], self.dtype))

    def reset_state(self, state: cla.Array) -> None:
        """t = 1, beta = 0 (a restart that is not counted): the start of a new round."""
        cl.enqueue_copy(self.queue, state.base_data, np.array([1.0, 0.0], self.dtype),
                        dst_offset=state.offset, is_blocking=True)

    def momentum(self, r, state, x1, x0, z):
        """The restart test and the momentum step on the device: state from sum(r), then
        z = x1 + beta (x1 - x0)."""
        self.k.fista_state(self.queue, (1,), None, state.data, cla.sum(r).data)
        self.k.momentum_state(self.queue, _launch1(self.queue, self.n), None, x1.data,
                              x0.data, z.data, state.data, np.uint64(self.n))

    def working_set(self, x, g, old, ws, shift, row_min) -> tuple[int, int]:
        """ws = the working set at x given the gradient g (kernels/prox.cl); (its size, the
        KKT violations outside ``old``)."""
        nz, ny, nx = self.shape
        viol = cla.empty(self.queue, self.shape, self.dtype)
        self.k.working_set(self.queue, _launch1(self.queue, self.n), None, x.data, g.data,
                           old.data, ws.data, viol.data, self.dtype.type(shift),
                           np.uint64(row_min), np.uint64(ny * nx), np.uint64(self.n))
        size = int(cla.sum(ws, dtype=np.int64).get())
        return size, int(round(float(cla.sum(viol).get())))

    def masked(self, x, ws) -> cla.Array:
        out = cla.empty_like(x)
        self.k.masked_copy(self.queue, _launch1(self.queue, self.n), None, x.data, ws.data,
                           out.data, np.uint64(self.n))
        return out

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


def _norm(a: cla.Array) -> float:
    return float(cla.dot(a, a).get()) ** 0.5


class _Objective:
    """The smooth part's gradient A^T W (A x - y) and its data term 1/2 ||A x - y||_W^2 at a
    point (for the working-set updates and their divergence check)."""

    def __init__(self, op, y, weights, pk):
        self.op, self.y, self.w, self.pk = op, y, weights, pk
        self.res = cla.empty(op.queue, op.out_shape, op.dtype)

    def gradient(self, x) -> tuple[cla.Array, float]:
        ax = self.op.apply_device(x)
        self.pk.weighted_residual(ax, self.y, self.w, self.res)
        data = 0.5 * float(cla.dot(self.res, ax - self.y).get())
        return self.op.adjoint_device(self.res), data


def fista(op: LinearOperator, y: cla.Array, x0: cla.Array, *, l1: float = 0.0,
          tv: float = 0.0, wz: float = 1.0, weights: cla.Array | None = None,
          row_min: int = 0, iterations: int, tol: float = DEFAULT_TOL,
          lipschitz_const: float | None = None, callback=None,
          working_set: bool = True) -> FistaResult:
    """Minimise the problem of the module docstring from ``x0`` (device arrays, op's dtype;
    ``x0`` >= 0 and zero off the support). ``working_set``: restricted step sizes (module
    docstring; without TV only). ``callback(k, x)`` is called after every iteration (x on
    the device) for monitoring.
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
    mark = x0.copy()  # the iterate at the last check: the window's change
    v = cla.empty_like(x0) if tv > 0 else None
    p = zeros(q, (3,) + tuple(op.in_shape), dt) if tv > 0 else None
    res = cla.empty(q, op.out_shape, dt)
    state = pk.new_state()
    rounds = _Rounds(op, y, weights, l1, row_min, L, pk) if working_set and tv == 0 else None
    out = FistaResult(x, 0, 0)
    last_f = math.inf
    for k in range(iterations):
        check = (k + 1) % CHECK_EVERY == 0 or k + 1 == iterations
        az = op.apply_device(z)
        pk.weighted_residual(az, y, weights, res)
        if check:
            data = 0.5 * float(cla.dot(res, az - y).get())
            f = data + l1 * float(cla.sum(z).get()) + (0.0 if tv == 0 else math.nan)
            out.objective.append((k + 1, data))
        g = op.adjoint_device(res)
        if tv > 0:
            pk.gradient_step(z, g, v, step, step * l1)
            p = pk.tv_prox(v, step * tv, wz, row_min, p, x1)
            pk.restart_terms(z, x1, x, r)
        else:
            pk.prox_step(z, g, x, x1, r, step, step * l1, row_min,
                         None if rounds is None else rounds.ws)
        pk.momentum(r, state, x1, x, z)
        x, x1 = x1, x
        out.iterations = k + 1
        if callback is not None:
            callback(k, x)
        if not check:
            continue
        nrm = _norm(x)
        change = _norm(x - mark) / nrm if nrm > 0 else 0.0
        cla_copy(mark, x)
        out.change.append((k + 1, change))
        # converged: the objective fell by less than tol of itself over the window (the
        # volume's change where TV's objective is not evaluated)
        decrease = (last_f - f) / abs(f) if f != 0 and math.isfinite(last_f) else math.inf
        converged = (0.0 <= decrease < tol) if not math.isnan(f) else change < tol
        last_f = f
        if rounds is None:
            if converged:
                break
            continue
        new_step, restore = rounds.update(k + 1, x, data, converged, out,
                                          last=k + 1 == iterations)
        if new_step is None:
            break  # converged on S with no KKT violation outside it
        if new_step != step or restore is not None:  # a new round: the momentum restarts
            if restore is not None:
                cla_copy(x, restore)
            step = new_step
            pk.reset_state(state)
            cla_copy(z, x)
            cla_copy(mark, x)
            last_f = math.inf
    out.x, out.restarts = x, int(round(float(state[2].get())))
    return out


class _Rounds:
    """The working-set rounds of :func:`fista` (module docstring): S is rebuilt (and L_S
    re-estimated, the momentum restarted) where variables outside S violate their KKT
    condition, or where S could shrink to WORKING_SET_SHRINK of itself (a longer step);
    otherwise a round's end changes nothing."""

    def __init__(self, op, y, weights, l1, row_min, L, pk: ProxKernels):
        self.op, self.weights, self.l1, self.row_min, self.L = op, weights, l1, row_min, L
        self.pk = pk
        self.objective = _Objective(op, y, weights, pk)
        self.ws: cla.Array | None = None  # None: the first round, on the whole support
        self.size = 0                      # |S|
        self.start = 0                     # iteration the round began at
        self.anchor: cla.Array | None = None  # the round's start point and its data term
        self.anchor_data = math.inf
        self.vec: cla.Array | None = None  # the power iteration's last vector
        self.L_ws = L

    def update(self, k: int, x, data_term: float, converged: bool, out: FistaResult,
               last: bool = False) -> tuple[float | None, cla.Array | None]:
        """At the check after iteration k (``data_term`` there, ``converged``: the stopping
        rule met on S): (the step to go on with, None where the solver has converged; a
        point to restore, where the round diverged). A step other than the last one starts
        a new round. ``last``: no iteration follows (the divergence check only: a new set
        and its power iteration would go unused)."""
        if self.anchor is not None and (data_term > self.anchor_data + WORKING_SET_DIVERGENCE
                                        * abs(self.anchor_data)):
            self.L_ws = min(self.L, 2.0 * self.L_ws)  # L_S underestimated: it diverged
            self.start = k
            out.diverged += 1
            return 1.0 / self.L_ws, self.anchor
        first = self.ws is None
        step = 1.0 / (self.L if first else self.L_ws)
        if last:
            return step, None
        if not (converged or first or k - self.start >= WORKING_SET_ROUND):
            return step, None
        g, data = self.objective.gradient(x)
        old = self.ws if self.ws is not None else _ones(self.pk)
        ws = cla.empty(x.queue, x.shape, np.uint8)
        size, entering = self.pk.working_set(x, g, old, ws, self.l1, self.row_min)
        if (converged and (entering == 0 or first)) or size == 0:
            return None, None  # converged (size 0: nothing may move, x = 0 is the solution)
        self.start = k
        if not first and entering == 0 and size > WORKING_SET_SHRINK * self.size:
            return step, None  # S holds: the round goes on, momentum and all
        self.ws, self.size = ws, size
        start = self.pk.masked(self.vec if self.vec is not None else x, ws)
        if not _norm(start) > 0:
            start = self.pk.masked(x, ws)
        est, self.vec = power_norm(Restricted(self.op, ws, self.pk), start,
                                   WORKING_SET_POWER_ITERATIONS, self.weights)
        self.L_ws = min(self.L, WORKING_SET_SAFETY * est) if est > 0 else self.L
        self.anchor, self.anchor_data = x.copy(), data
        out.rounds.append((k, size / x.size, entering, self.L_ws / self.L))
        return 1.0 / self.L_ws, None


def _ones(pk: ProxKernels) -> cla.Array:
    a = cla.empty(pk.queue, pk.shape, np.uint8)
    cl.enqueue_fill_buffer(pk.queue, a.base_data, np.uint8(1), a.offset, a.nbytes)
    return a


def cla_copy(dst: cla.Array, src: cla.Array) -> None:
    """Device-to-device copy of equal-sized arrays."""
    cl.enqueue_copy(dst.queue, dst.base_data, src.base_data, byte_count=src.nbytes,
                    src_offset=src.offset, dst_offset=dst.offset)


__all__ = ["fista", "lipschitz", "power_norm", "Restricted", "FistaResult", "ProxKernels",
           "fill_zero"]
