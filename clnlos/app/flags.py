"""What several sub-commands share: the precision, --force and slab flags, and the one-line
check of an optional dependency before any work."""

from __future__ import annotations

import importlib.util

import numpy as np

from clnlos.errors import MissingDependencyError

DTYPES = {"float32": np.float32, "float64": np.float64}

# optional dependencies: import name -> (extra, what needs it)
EXTRAS = {"torch": ("ml", "the torch CPU wheel: pip install torch==2.13.0"),
          "dask": ("study", "dask[distributed]"),
          "distributed": ("study", "dask[distributed]")}


def require(module: str, what: str) -> None:
    """One line naming the extra when an optional dependency is missing."""
    if importlib.util.find_spec(module) is None:
        extra, hint = EXTRAS[module]
        raise MissingDependencyError(
            f"{what} needs {module!r}, which is not installed: pip install 'clnlos[{extra}]' "
            f"({hint})")


def add_force(p) -> None:
    p.add_argument("--force", action="store_true",
                   help="replace an existing file at a path written beside the output (or "
                        "in the output folder) that clnlos did not write; inputs are never "
                        "replaced")


def add_precision(p) -> None:
    p.add_argument("--dtype", choices=sorted(DTYPES), default="float32",
                   help="kernel precision (default %(default)s)")


def add_slab_flags(p, default: str, no_slab: str) -> None:
    """The slab's flags (``--slab-thickness``, ``--mu-a``, ``--mu-s-prime``, ``--n``,
    ``--no-slab``); ``default`` says where an absent one comes from, ``no_slab`` what
    ``--no-slab`` does."""
    p.add_argument("--slab-thickness", type=float, help=f"slab thickness (m) {default}")
    p.add_argument("--mu-a", type=float, help=f"slab absorption coefficient (1/m) {default}")
    p.add_argument("--mu-s-prime", type=float,
                   help=f"slab reduced scattering coefficient (1/m) {default}")
    p.add_argument("--n", type=float, help=f"slab refractive index (relative) {default}")
    p.add_argument("--no-slab", action="store_true", help=no_slab)
