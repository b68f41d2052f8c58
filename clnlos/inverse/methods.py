"""The inversion methods: one contract, one registry (:data:`METHODS`).

Every method is a class with the same constructor, ``Method(grid, config, *, dtype, queue,
scratch=None, cache=None)``:

* ``grid`` (:class:`InversionGrid`): the deconvolved transient's shape [t, y, x] (bin 0 at
  t = 0), bin width (s) and scan width (m);
* ``config``: the :class:`clnlos.config.ReconstructionConfig` (the method reads its own
  fields: falloff, iterations, weights, ...);
* ``dtype``/``queue``: precision and OpenCL queue; ``scratch``/``cache``: work buffers shared
  with the pipeline's other stages and the optional on-disk spectrum cache.

``configure(tau_g, noise, rule_snr, timed, probe=None, slab_influence=None) -> dict`` sets
what the method chooses from the data (e.g. the light-cone SNR by the unbiased predictive
risk or cross-validation, :mod:`clnlos.inverse.gcv`; ``rule_snr`` is the photon rule's value,
:func:`clnlos.inverse.snr.lightcone_snr`; ``probe()`` a realisation of the noise of
``tau_g`` for photon counts, None otherwise; ``slab_influence()`` the slab deconvolution's
influence operator on ``tau_g``'s grid, :meth:`clnlos.operators.spectral.SpectralFilter.
influence`, for a method that models what the deconvolution leaves, None without a slab)
and returns the parameters it chose (recorded in the volume's ``params``);
``timed(name, fn, *args)`` runs a step and records its time. A method with a light-cone
Wiener filter (``lightcone_filter = True``) also takes ``rule=``: the name of the pipeline's
rule that chose ``rule_snr`` (the reproducibility search), which it then uses as given.
Class attributes the pipeline reads: ``slab_snr_min``, ``slab_snr_toward_photons``,
``forward_model`` (:meth:`predict` exists), ``lightcone_filter``; the registry entry's
``auto_snr_rule`` says what ``snr_rule = "auto"`` stands for with it.
``__call__(tau_g, *, progress=None, setup=None)`` returns the volume [z, y, x] on the
device; ``report()`` what the solver did (or None); ``used()`` parameters settled during
the call (recorded in ``params``).

The registry (:data:`METHODS`, :class:`MethodEntry` and the questions asked of it) is a
table of the configuration, stated in :mod:`clnlos.config` (which checks a config's
``method`` against it without importing this package) and re-exported here; it names each
method's module and class, and :func:`method_class` imports the one asked for. Adding a
method: one module with its class, one line in ``clnlos.config.METHODS``.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import TYPE_CHECKING

from clnlos.config import (
    CLOSED_FORM_BRDFS,
    ITERATIVE_SUM_BINS_ABOVE,
    METHODS,
    RETROREFLECTIVE_FALLOFF,
    MethodEntry,
    auto_snr_rule,
    default_falloffs,
    method_names,
    methods_reading,
    split_rule,
)

if TYPE_CHECKING:  # annotations only: this module imports no OpenCL code
    import numpy as np
    import pyopencl.array as cla

# the registry, stated in clnlos.config, read here by the pipeline, the CLI, the study, the bench
__all__ = ["CLOSED_FORM_BRDFS", "ITERATIVE_SUM_BINS_ABOVE", "METHODS", "RETROREFLECTIVE_FALLOFF",
           "Inversion", "InversionGrid", "MethodEntry", "auto_snr_rule", "default_falloffs",
           "method_class", "method_names", "methods_reading", "split_rule"]


@dataclass(frozen=True)
class InversionGrid:
    """The grid an inversion runs on: transient shape [t, y, x], bin width (s), scan width (m)."""

    shape: tuple[int, int, int]
    bin_width_s: float
    scan_width_m: float


def method_class(name: str) -> type:
    """The class of the registered method ``name`` (its module imported on first use)."""
    entry = METHODS[name]
    return getattr(importlib.import_module(entry.module), entry.cls)


class Inversion:
    """Base of the methods (see the module docstring); ``name`` is the registry key."""

    name = ""
    # the least slab Wiener SNR the method takes where the pipeline chooses it from the data
    # (None: the cross-validated one as it is); a method that takes the deconvolved transient
    # for the slab-free one asks for a deeper deconvolution (clnlos.inverse.pipeline)
    slab_snr_min: float | None = None
    # whether the method's slab SNR moves from GCV's pick towards the photon rule's (their
    # geometric mean where the photon rule's is higher): f-k, which regularises nothing itself
    slab_snr_toward_photons: bool = False
    # whether the method can predict a transient from its volume (:meth:`predict`): what the
    # slab SNR's cross-validation by Poisson thinning scores (clnlos.inverse.thinning)
    forward_model: bool = False
    # whether the method has a light-cone Wiener filter whose SNR the config sets
    # (``inversion_snr``; the candidates of the reproducibility search, clnlos.inverse.pipeline,
    # which hands its choice to :meth:`configure` as ``rule``: such a method accepts it)
    lightcone_filter: bool = False

    def __init__(self, grid: InversionGrid, config, *, dtype, queue, scratch=None,
                 cache=None):
        self.grid, self.config = grid, config
        self.dtype, self.queue, self.scratch, self.cache = dtype, queue, scratch, cache

    def geometry(self) -> dict:
        """The keyword arguments every plan of the package takes for this grid."""
        return dict(bin_width_s=self.grid.bin_width_s, scan_width_m=self.grid.scan_width_m,
                    dtype=self.dtype, queue=self.queue, scratch=self.scratch)

    def falloff(self) -> dict:
        """``{"falloff": x}`` when the config sets one, else RETROREFLECTIVE_FALLOFF for
        ``brdf = "retroreflective"``, else ``{}`` (the method's default)."""
        if self.config.falloff is not None:
            return {"falloff": self.config.falloff}
        if self.config.brdf == "retroreflective":
            return {"falloff": RETROREFLECTIVE_FALLOFF}
        return {}

    def configure(self, tau_g, noise, rule_snr: float, timed, probe=None,
                  slab_influence=None, rule: str | None = None) -> dict:
        """Set up for the transient ``tau_g``: ``rule_snr`` is the light-cone SNR of the
        config or the photon rule, or where ``rule`` names the pipeline's choice (the
        reproducibility search) that choice, used as given; the method's own data rule
        (UPRE, GCV) otherwise. Returns what the volume records of it."""
        return {}

    def __call__(self, tau_g, *, progress=None, setup=None):
        raise NotImplementedError

    def report(self) -> dict | None:
        return None

    def predict(self, volume: np.ndarray) -> cla.Array:
        """The transient [t, y, x] the method's model predicts for ``volume`` [z, y, x] (on
        the device; the support of the last call), for methods with ``forward_model``."""
        raise NotImplementedError(f"method {self.name!r} has no forward model")

    def used(self) -> dict:
        """What the method chose that the volume records: for a method with a falloff (its
        registry entry), ``falloff_used`` (the config's, the ``brdf``'s or its own)."""
        entry = METHODS.get(self.name)
        if entry is None or entry.falloff is None:
            return {}
        return {"falloff_used": self.falloff().get("falloff", entry.falloff)}
