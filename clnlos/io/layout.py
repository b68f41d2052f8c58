"""The layout of a stored transient: which stored axis is time, which y and which x, and
which run backwards (pure numpy: the config validates ``axes`` with it).

A layout is written as the stored axes in order, comma-separated, each ``t``, ``y`` or ``x``
once, with a leading minus for an axis stored reversed: ``t,y,x`` (clnlos's own [t, y, x]),
``x,y,t``, ``t,-y,x`` (rows stored top to bottom). "Stored" is the order the file's reader
returns: numpy's for ``.npy`` and HDF5, MATLAB's (i, j, k) for ``.mat`` of any version (h5py
returns a v7.3 array with its axes reversed; the readers turn it back first).

The result is always clnlos's [t, y, x], seen from the scan plane looking into the hidden
volume: x increases with the column index (to the right of the front view), y with the row
index (up the front view, the figures draw row 0 at the bottom).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clnlos.errors import ParameterError

AXIS_NAMES = ("t", "y", "x")
AXES_ALLOWED = ("three comma-separated axis names, t, y and x each once, in the order they are "
                "stored, with a leading minus for a reversed axis (e.g. t,y,x or x,-y,t)")


@dataclass(frozen=True)
class Layout:
    """Stored axes in order (``names``) and whether each is stored reversed."""

    names: tuple[str, str, str]
    reversed: tuple[bool, bool, bool]

    def __str__(self) -> str:
        return ",".join(("-" if r else "") + n for n, r in zip(self.names, self.reversed,
                                                               strict=True))

    @property
    def time_axis(self) -> int:
        """The stored axis that is time."""
        return self.names.index("t")

    def to_tyx(self, stored: np.ndarray) -> np.ndarray:
        """The stored 3-D array as [t, y, x] (a view where numpy can)."""
        a = np.asarray(stored)
        flips = tuple(k for k, r in enumerate(self.reversed) if r)
        if flips:
            a = np.flip(a, axis=flips)
        return np.transpose(a, [self.names.index(n) for n in AXIS_NAMES])

    def from_tyx(self, tyx: np.ndarray) -> np.ndarray:
        """[t, y, x] back to the stored order (the inverse of :meth:`to_tyx`; for writing
        test files and exchanging data)."""
        a = np.transpose(np.asarray(tyx), [AXIS_NAMES.index(n) for n in self.names])
        flips = tuple(k for k, r in enumerate(self.reversed) if r)
        return np.flip(a, axis=flips) if flips else a

    def scan_to_yx(self, stored: np.ndarray) -> np.ndarray:
        """A per-scan-point 2-D array stored with this layout's two scan axes in their order
        (an f-k ``tofgrid`` beside its ``meas``) as [y, x]."""
        keep = [k for k, n in enumerate(self.names) if n != "t"]
        names = [self.names[k] for k in keep]
        a = np.asarray(stored)
        flips = tuple(i for i, k in enumerate(keep) if self.reversed[k])
        if flips:
            a = np.flip(a, axis=flips)
        return a if names == ["y", "x"] else a.T

    def shape_tyx(self, stored_shape) -> tuple[int, int, int]:
        """The [t, y, x] shape of a stored shape (sizes checked before the data are read)."""
        return tuple(int(stored_shape[self.names.index(n)]) for n in AXIS_NAMES)

    def describe(self, stored_shape) -> str:
        """The layout in words for a note: each stored axis, its size and where it goes."""
        where = {"t": "time", "y": "up the front view", "x": "to the right of the front "
                 "view"}
        parts = []
        for k, (n, r) in enumerate(zip(self.names, self.reversed, strict=True)):
            way = where[n] if not r else {"t": "time, reversed", "y": "down the front view",
                                          "x": "to the left of the front view"}[n]
            parts.append(f"axis {k} ({int(stored_shape[k])}) {way}")
        return "; ".join(parts)


def parse_axes(text, name: str = "axes") -> Layout:
    """A layout from its text (module docstring); a ParameterError naming ``name`` else."""
    if isinstance(text, Layout):
        return text
    if not isinstance(text, str):
        raise ParameterError(name, text, AXES_ALLOWED)
    parts = [p.strip().lower() for p in text.split(",")]
    names = tuple(p.removeprefix("-").strip() for p in parts)
    if len(parts) != 3 or sorted(names) != sorted(AXIS_NAMES):
        raise ParameterError(name, text, AXES_ALLOWED)
    return Layout(names, tuple(p.startswith("-") for p in parts))  # type: ignore[arg-type]


def assumed_layout(stored_shape) -> Layout:
    """The layout assumed for a 3-D array that records none: time on the first axis unless
    another axis is strictly longer (a histogram has more bins than a scan has points per
    side), then the longest; the two scan axes in their stored order as y (rows), x (columns),
    none reversed."""
    shape = [int(s) for s in stored_shape]
    t = 0 if shape[0] >= max(shape[1:]) else int(np.argmax(shape))
    rest = iter(("y", "x"))
    names = tuple("t" if k == t else next(rest) for k in range(3))
    return Layout(names, (False, False, False))  # type: ignore[arg-type]
