"""Linear operators on device arrays (ODL-style contract).

An operator has ``in_shape``, ``out_shape``, ``dtype`` and a ``queue``. The public call
checks shape and dtype (raising :class:`~clnlos.errors.ShapeError`) and accepts numpy arrays
(returned as numpy) or ``pyopencl.array.Array`` (kept on the device); subclasses
implement ``_apply``/``_adjoint`` on device arrays, which ``apply_device``/``adjoint_device``
expose unchecked to other operators and solvers. ``A @ B`` composes (B first) and
``(A @ B).adjoint == B.adjoint @ A.adjoint``. :func:`dot_test` checks <A x, y> = <x, A* y>.
"""

from __future__ import annotations

import numpy as np
import pyopencl.array as cla

from clnlos.errors import ShapeError


class LinearOperator:
    in_shape: tuple[int, ...]
    out_shape: tuple[int, ...]
    dtype: np.dtype
    queue = None
    name = "operator"

    # -- computed by subclasses, on device arrays of the declared shapes
    def _apply(self, x_g: cla.Array) -> cla.Array:
        raise NotImplementedError

    def _adjoint(self, y_g: cla.Array) -> cla.Array:
        raise NotImplementedError(f"{self.name} has no adjoint")

    # -- public, unchecked: device arrays of the declared shapes (solvers' inner loops)
    def apply_device(self, x_g: cla.Array) -> cla.Array:
        """A x for a device array of ``in_shape`` (no shape or dtype check)."""
        return self._apply(x_g)

    def adjoint_device(self, y_g: cla.Array) -> cla.Array:
        """A* y for a device array of ``out_shape`` (no shape or dtype check)."""
        return self._adjoint(y_g)

    # -- public, checked
    def _check(self, x, shape, what):
        if tuple(x.shape) != tuple(shape):
            raise ShapeError(f"{self.name} {what}: expected shape {tuple(shape)}, got "
                             f"{tuple(x.shape)}")
        if np.dtype(x.dtype) != self.dtype:
            raise ShapeError(f"{self.name} {what}: expected dtype {self.dtype}, got {x.dtype}")

    def _run(self, fn, x, shape, what):
        if isinstance(x, cla.Array):
            self._check(x, shape, what)
            return fn(x)
        x = np.asarray(x)
        self._check(x, shape, what)
        return fn(cla.to_device(self.queue, np.ascontiguousarray(x))).get()

    def __call__(self, x):
        return self._run(self._apply, x, self.in_shape, "input")

    def apply_adjoint(self, y):
        return self._run(self._adjoint, y, self.out_shape, "adjoint input")

    @property
    def adjoint(self) -> LinearOperator:
        return _Adjoint(self)

    def __matmul__(self, other: LinearOperator) -> LinearOperator:
        return Composition(self, other)


class _Adjoint(LinearOperator):
    def __init__(self, op: LinearOperator):
        self.op = op
        self.in_shape, self.out_shape = op.out_shape, op.in_shape
        self.dtype, self.queue, self.name = op.dtype, op.queue, f"{op.name}.adjoint"

    def _apply(self, x_g):
        return self.op.adjoint_device(x_g)

    def _adjoint(self, y_g):
        return self.op.apply_device(y_g)

    @property
    def adjoint(self):
        return self.op


class Composition(LinearOperator):
    """``outer @ inner``: apply ``inner`` first."""

    def __init__(self, outer: LinearOperator, inner: LinearOperator):
        if tuple(inner.out_shape) != tuple(outer.in_shape):
            raise ShapeError(f"cannot compose {outer.name} after {inner.name}: "
                             f"{inner.out_shape} != {outer.in_shape}")
        if inner.dtype != outer.dtype:
            raise ShapeError(f"cannot compose {outer.name} ({outer.dtype}) after "
                             f"{inner.name} ({inner.dtype})")
        self.outer, self.inner = outer, inner
        self.in_shape, self.out_shape = inner.in_shape, outer.out_shape
        self.dtype, self.queue = inner.dtype, inner.queue
        self.name = f"({outer.name} @ {inner.name})"

    def _apply(self, x_g):
        return self.outer.apply_device(self.inner.apply_device(x_g))

    def _adjoint(self, y_g):
        return self.inner.adjoint_device(self.outer.adjoint_device(y_g))


def dot_test(op: LinearOperator, rng: np.random.Generator | None = None) -> float:
    """Normalised adjoint mismatch |<A x, y> - <x, A* y>| / (|A x| |y| + |x| |A* y|)."""
    rng = np.random.default_rng(0) if rng is None else rng
    x = rng.standard_normal(op.in_shape).astype(op.dtype)
    y = rng.standard_normal(op.out_shape).astype(op.dtype)
    ax = np.asarray(op(x), np.float64)
    aty = np.asarray(op.apply_adjoint(y), np.float64)
    lhs = float(np.vdot(ax, y.astype(np.float64)))
    rhs = float(np.vdot(x.astype(np.float64), aty))
    scale = np.linalg.norm(ax) * np.linalg.norm(y) + np.linalg.norm(x) * np.linalg.norm(aty)
    return abs(lhs - rhs) / (scale if scale > 0 else 1.0)
