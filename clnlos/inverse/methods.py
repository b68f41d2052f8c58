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

The registry names each method's module and class, so this module (read by the config, the
CLI flags, the study, the demo and the bench) imports no OpenCL code; :func:`method_class`
imports the one asked for. Adding a method: one module with its class, one line here.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # annotations only: this module imports no OpenCL code
    import numpy as np
    import pyopencl.array as cla


@dataclass(frozen=True)
class InversionGrid:
    """The grid an inversion runs on: transient shape [t, y, x], bin width (s), scan width (m)."""

    shape: tuple[int, int, int]
    bin_width_s: float
    scan_width_m: float


@dataclass(frozen=True)
class MethodEntry:
    """A registered method: where its class lives, its default radiometric falloff (the
    power of 1/r applied per bin before the inversion; None: the method has its own model),
    a one-line summary for the CLI help, the split search that can choose its SNRs on
    photon counts its slab model fits exactly (``split_rule``): "thinning" (a forward model
    scores held-out photons, :mod:`clnlos.inverse.thinning`) or "reproducibility" (the
    halves' thresholded images must agree, :mod:`clnlos.inverse.reproducibility`), and
    what ``snr_rule = "auto"`` stands for there (``auto_snr_rule``: that search, or "gcv"
    where the search does not earn its cost: the iterative method, whose thinning search
    costs 2-3 more reconstructions for +0.001 mean IoU on the oracle table,
    :mod:`clnlos.inverse.thinning`)."""

    module: str
    cls: str
    falloff: float | None
    summary: str
    split_rule: str = "reproducibility"  # a method without a forward model has only this
    auto_snr_rule: str = "gcv"
    # the config fields of the inversion that only some methods read which this one reads
    # (a user who sets one for a method that does not read it is told so: clnlos.config)
    reads: tuple[str, ...] = ()
    # the most time bins the method inverts when ``bins`` is not set: a longer capture's bins
    # are summed in pairs until it fits (clnlos.inverse.pipeline.bins_for); None: all of them
    max_bins: int | None = None

    def __post_init__(self):
        if self.split_rule not in ("thinning", "reproducibility"):
            raise ValueError(f"split_rule {self.split_rule!r}: \"thinning\" or "
                             "\"reproducibility\"")
        if self.auto_snr_rule not in ("gcv", self.split_rule):
            raise ValueError(f"auto_snr_rule {self.auto_snr_rule!r}: \"gcv\" or "
                             f"{self.split_rule!r}")


# the iterative method's default time grid: at most 512 bins, the published LCT code's grid of
# the 2048-bin captures of O'Toole et al. (4 ps bins summed to 16 ps); each iteration costs
# light-cone FFTs on a grid twice the bins deep (a 64 x 64 x 2048 capture took minutes)
ITERATIVE_MAX_BINS = 512

METHODS: dict[str, MethodEntry] = {
    "lct": MethodEntry("clnlos.inverse.lct", "LCTMethod", 4.0,
                       "light-cone transform with a Wiener filter (O'Toole et al. 2018)",
                       "reproducibility", "reproducibility",
                       ("falloff", "inversion_snr", "brdf")),
    "fk": MethodEntry("clnlos.inverse.fk", "FKMethod", 2.0,
                      "f-k (Stolt) migration (Lindell et al. 2019)", "reproducibility",
                      "reproducibility", ("falloff", "brdf")),
    "iterative": MethodEntry("clnlos.inverse.iterative", "IterativeMethod", None,
                             "FISTA on the light-cone transport, L1 + TV, warm-started by "
                             "LCT", "thinning", "gcv",
                             ("inversion_snr", "iterations", "l1_weight", "tv_weight",
                              "depth_min_m", "slab_model", "brdf", "brdf_terms"),
                             ITERATIVE_MAX_BINS),
}


# LCT's and f-k's retroreflective variant (O'Toole et al. 2018, cnlos_reconstruction.m
# ``isdiffuse = 0``): the radiometric exponent of a retroreflector whose cone the scanned spot
# holds (1/r^2; clnlos.physics.retroreflector); ``brdf = "retroreflective"`` asks for it
RETROREFLECTIVE_FALLOFF = 2.0
# the reflectances LCT and f-k take (``brdf``): their falloff is all they model of it
CLOSED_FORM_BRDFS = ("lambertian", "retroreflective")


def method_names() -> tuple[str, ...]:
    return tuple(METHODS)


def auto_snr_rule(name: str) -> str:
    """The rule ``snr_rule = "auto"`` stands for with the registered method ``name`` (on
    photon counts its slab model fits exactly; :class:`MethodEntry`)."""
    return METHODS[name].auto_snr_rule


def methods_reading(field: str) -> tuple[str, ...]:
    """The registered methods that read the method-specific config ``field``
    (:attr:`MethodEntry.reads`; every method when no method lists it: a common field)."""
    listed = tuple(n for n, e in METHODS.items() if field in e.reads)
    if not listed and not any(field in e.reads for e in METHODS.values()):
        return tuple(METHODS)
    return listed


def split_rule(name: str) -> str:
    """The split search valid for the registered method ``name`` (``snr_rule`` by name;
    :class:`MethodEntry`)."""
    return METHODS[name].split_rule


def default_falloffs() -> dict[str, float]:
    """The falloff of each method that has one (``--falloff`` default per method)."""
    return {name: e.falloff for name, e in METHODS.items() if e.falloff is not None}


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
