"""Regularised iterative inversion of the confocal light-cone model (``method = "iterative"``).

Given the hidden-side transient I [t, y, x] (the capture after the slab's Wiener
deconvolution, :mod:`clnlos.forward.blur`; the capture itself without a slab), solve

    min_{rho >= 0}  1/2 || L rho - I ||^2  +  l1 sum(rho)  +  tv TV(rho)

with L the light-cone transport of :mod:`clnlos.forward.transport` (the physics of
``clnlos simulate``: Lambertian voxels facing the scan plane, z^4 / (pi r^8) falloff), by
FISTA with gradient restart and working-set steps, stopped where the objective stops
falling (:mod:`clnlos.inverse.solvers`), warm-started from LCT. The solver's
variable is xi = rho / (z / R)^4 (R the deepest depth), which gives every depth a column of
similar norm (p = 4, ``falloff``, for Lambertian voxels: xi = rho / (z / R)^p); the volume
returned is rho >= 0 on the reconstruction grid [z, y, x].

Regularisation weights are relative: l1 = ``l1_weight`` * max(L^T I) and
tv = ``tv_weight`` * max(L^T I) on the support (max(L^T I) is the smallest L1 weight for
which rho = 0 is the solution), so they do not depend on the units or the scale of I. The
support starts at ``depth_min_m`` (the reconstruction pipeline takes it from the capture's
first arrival, :mod:`clnlos.inverse.snr`).

``l1_weight = "auto"`` takes the L1 weight from the noise of the data: given a realisation
n of the noise of I (the reconstruction pipeline carries the capture's Poisson noise through
its own linear steps),

    l1 = L1_NOISE_FACTOR * max(L^T n),   L1_NOISE_FACTOR = 2,

the lasso's noise condition l1 >= 2 ||L^T n||_inf of the oracle inequalities of Bickel,
Ritov & Tsybakov (Ann. Stat. 2009, "Simultaneous analysis of Lasso and Dantzig
selector"): the smallest weight for which noise alone leaves (with high probability) no
voxel on; a larger one only removes signal. Without a noise realisation (data that are not
counts, noise-free simulations) it is FIXED_L1_WEIGHT * max(L^T I), today's constant. On
the oracle table (:mod:`clnlos.bench.oracle`) it gave 0.02-0.09 of max(L^T I) where the
constant was 0.1, and higher IoU on 6 of 7 captures. The discrepancy principle (stop, or
weigh, where ||L rho - I||^2 reaches E||n||^2) was measured and does not apply: at l1 = 0
and 200 iterations the residual is still twice the noise energy (1.3e4 of noise, 2.5e4 of
residual on the seed geometry at 0.5 s) -- model error, not noise, sets its floor.

Stopping (plain NLOS, photon counts, an "auto" light-cone SNR). The iteration count of a
gradient method is itself a regularisation: k accelerated (FISTA) iterations pass the
components of the normal operator with eigenvalue above about L / k^2 (L = ||L^T L||) and
damp those below, as Tikhonov regularisation of weight alpha = L / k^2 does (Engl, Hanke &
Neubauer, "Regularization of Inverse Problems", 1996, ch. 6: alpha ~ k^-2 for semi-
iterative methods). The Wiener filter of the LCT warm start, conj(H) / (|H|^2 + 1 / SNR)
with max |H| = 1, is Tikhonov with alpha = L / SNR. So where the data chose that SNR (UPRE
on the capture's own noise, :func:`clnlos.inverse.lct.choose_lightcone_snr`), the solver
stops after

    k = ceil(sqrt(SNR))                                       (:func:`snr_matched_iterations`)

iterations (``iterations`` stays the upper bound; a count the user sets is used as given):
the iterations refine the warm start where the data carry signal and stop before they fit
the photon noise (measured on the light-cone transform release:
docs/validation/lct-release.md). Behind a slab the tolerance rule stays (the model is
Phi L and the oracle table was measured with it).

The voxels' radial falloff (``falloff``, :mod:`clnlos.forward.transport`): 1/r^4 for
Lambertian voxels (the default); 2 for a retroreflector whose cone the scanned spot holds,
the published (t/T)^2 model, which a capture format can suggest
(:mod:`clnlos.inverse.capture_defaults`). The solver's variable is then xi = rho / (z / R)^p.

The slab in the model (``slab_model = "influence"``, the default). Behind a slab, I is the
Wiener deconvolution W tau of the capture tau = B I_true + n (:mod:`clnlos.forward.blur`),
whose expectation is not I_true but Phi I_true, with Phi = W B the filter's influence
(:meth:`clnlos.operators.spectral.SpectralFilter.influence`: phi_k = |H_k|^2 / (|H_k|^2 +
1/SNR), the slab's frequencies the deconvolution could not restore damped). Fitting L rho to
I takes that smoothing for light from the hidden side; the default fits

    min_{rho >= 0}  1/2 || Phi L rho - W tau ||^2  +  l1 sum(rho)  +  tv TV(rho),

the slab inside the model, B L, with the Wiener filter as the left preconditioner (W B L rho
against W tau): Phi is real with norm below 1, so the step size of L alone stays valid (no
power iteration of its own), where least squares on B L rho - tau converged far slower
(issue 24: 0.57 IoU after 84 s against 0.82 in 8 s). It costs one more filter pair per
iteration (about 2x the time). On the oracle table (:mod:`clnlos.bench.oracle`, one noise
seed) it raised the IoU on 7 of 10 captures (the 0.7 m deep '+' 0.73 -> 0.80, the 0.8 m deep
'UT' 0.72 -> 0.75, the wide 'UT' 0.91 -> 0.94) and lowered it on the three seed-geometry
captures at 1e7-6e8 photons (0.65 -> 0.60 at 1e7), where neither reads the letters.
``"none"`` is Wiener first (L alone), the method before. For a tail-filled window
(:mod:`clnlos.inverse.tail_fill`) Phi is the plain filter's.

The voxels' reflectance (``brdf``, :mod:`clnlos.brdf.lobes`): Lambertian by default (the
physics of LCT and f-k); a preset, a texture or a fitted model makes L the light-cone
transport with that BRDF's retro lobe (:mod:`clnlos.physics.lobe`: the lobe averaged over
each voxel's cell, as K separable light cones), and ``"auto"`` chooses the lobe from the
capture (:mod:`clnlos.inverse.brdf_choice`). The slab's footprint is not folded into the
lobe: against the bistatic transport it did not bring the model closer (docs/brdf.md).

Left out: the surface orientation (voxels face the scan plane; a tilted specular voxel is
reconstructed where its lobe meets the scan plane, displaced by about z tan(tilt)),
occlusion.
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
import pyopencl.array as cla

from clnlos.physics.constants import C0
from clnlos.checks import integer, real
from clnlos.config import DEPTH_GUARD_M, FALLOFF_RANGE, ITERATIONS_RANGE, WEIGHT_RANGE
from clnlos.brdf.lobes import AUTO, retro_lobe
from clnlos.forward.transport import LAMBERTIAN_FALLOFF, LightConeTransport
from clnlos.physics.lobe import INVERSION_LOBE_TOLERANCE, SEARCH_LOBE_TOLERANCE, RetroLobe
from clnlos.inverse.lct import (
    DEFAULT_SNR,
    LCT,
    choose_lightcone_snr,
    initial_inversion_snr,
    lightcone_snr_params,
)
from clnlos.inverse.methods import Inversion, InversionGrid
from clnlos.inverse.solvers import DEFAULT_TOL, fista, lipschitz
from clnlos.operators.base import LinearOperator
from clnlos.runtime.buffers import Scratch
from clnlos.runtime.device import get_queue, require_dtype

DEPTH_QUANTUM_M = 0.05  # support starts are rounded down to this, so plans are reused
L1_NOISE_FACTOR = 2.0   # "auto" L1 weight: this times max(L^T n) (module docstring)
FIXED_L1_WEIGHT = 0.1   # "auto" without a noise realisation, relative to max(L^T I)


@dataclass
class SolveReport:
    iterations: int
    restarts: int
    lipschitz: float
    l1: float
    tv: float
    depth_min_m: float
    objective: list
    change: list
    lam_max: float = 0.0  # max(L^T I) on the support: the weights are relative to it
    rounds: list = field(default_factory=list)  # working-set updates (solvers.FistaResult)
    brdf: str = "lambertian"   # the retro lobe the model assumed
    lobe_terms: int = 1        # its separable terms K
    lobe_error: float = 0.0    # their weighted relative error (clnlos.physics.lobe)
    falloff: float = LAMBERTIAN_FALLOFF  # the voxels' radial falloff 1/r^p the model took

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


class IterativeInversion:
    """Plan for transients of one shape [t, y, x] (bin 0 at t = 0), precision and device.

    Parameters: shape; bin_width_s; scan_width_m; iterations (at most); l1_weight and
    tv_weight (relative, see module docstring; their defaults are those of
    :class:`clnlos.config.ReconstructionConfig`); tv_depth_scale (weight of the depth
    difference in TV; 0 = lateral TV only); warm_snr (Wiener SNR of the LCT warm start);
    tol (relative decrease of the objective that stops the solver,
    :mod:`clnlos.inverse.solvers`); scratch (work
    buffers shared with a plan's other stages, :class:`clnlos.runtime.buffers.Scratch`); cache
    (on-disk spectra of the warm start, :class:`clnlos.runtime.spectrum_cache.SpectrumCache`);
    lobe (the voxels' retro lobe, :class:`clnlos.physics.lobe.RetroLobe`, default Lambertian)
    and lobe_terms (its separable terms K, default by tolerance):
    :mod:`clnlos.forward.transport`.
    """

    def __init__(self, shape, *, bin_width_s: float, scan_width_m: float,
                 iterations: int, l1_weight: float, tv_weight: float,
                 tv_depth_scale: float = 1.0, warm_snr: float = DEFAULT_SNR,
                 tol: float = DEFAULT_TOL, dtype=np.float32, queue=None, scratch=None,
                 cache=None, lobe: RetroLobe | None = None, lobe_terms: int | None = None,
                 falloff: float = LAMBERTIAN_FALLOFF):
        self.queue = get_queue(queue)
        self.dtype = require_dtype(self.queue.device, dtype)
        self.shape = tuple(int(s) for s in shape)
        self.bin_width_s, self.scan_width_m = float(bin_width_s), float(scan_width_m)
        integer("iterations", iterations, *ITERATIONS_RANGE)
        self.l1_auto = l1_weight == "auto"
        if self.l1_auto:
            l1_weight = FIXED_L1_WEIGHT
        for name, v in (("l1_weight", l1_weight), ("tv_weight", tv_weight),
                        ("tv_depth_scale", tv_depth_scale)):
            real(name, v, *WEIGHT_RANGE)
        self.iterations, self.tol = int(iterations), float(tol)
        self.working_set = True  # the solver's working-set steps (tools/solver_check.py: off)
        self.l1_weight, self.tv_weight = float(l1_weight), float(tv_weight)
        self.tv_depth_scale = float(tv_depth_scale)
        nt = self.shape[0]
        dz = C0 * self.bin_width_s / 2
        self.depth_m = (np.arange(nt) + 0.5) * dz
        real("falloff", falloff, *FALLOFF_RANGE)
        self.falloff = float(falloff)
        self.depth_ratio = self.depth_m / (nt * dz)  # z / R: rho = xi (z / R)^p
        self.scratch = Scratch(self.queue) if scratch is None else scratch
        self.warm = LCT(self.shape, bin_width_s=bin_width_s, scan_width_m=scan_width_m,
                        snr=warm_snr, falloff=self.falloff, dtype=self.dtype, queue=self.queue,
                        scratch=self.scratch, cache=cache)
        self._ops: dict[tuple, tuple[LightConeTransport, int, float]] = {}
        self.report: SolveReport | None = None
        self.lobe = RetroLobe.lambert() if lobe is None else lobe
        self.lobe_terms = lobe_terms
        # the error "auto" terms stop at (at least the lobe's own tolerance; the lobe
        # search's candidates take SEARCH_LOBE_TOLERANCE, IterativeMethod.iteration_budget)
        self.lobe_tolerance: float = INVERSION_LOBE_TOLERANCE

    def set_lobe(self, lobe: RetroLobe) -> None:
        """The retro lobe the next calls assume (operators kept per lobe and support)."""
        self.lobe = lobe

    def lobe_falloff(self, lobe: RetroLobe) -> float:
        """The radial falloff exponent the transport takes with ``lobe``: the plan's, but
        the Lambertian 4 for a retroreflector's lobe, whose spot factor carries its own r
        dependence (:mod:`clnlos.physics.lobe`)."""
        return LAMBERTIAN_FALLOFF if lobe.cone is not None else self.falloff

    @property
    def scale(self) -> np.ndarray:
        """(z / R)^p per depth bin for the current lobe's falloff p: rho = xi * scale."""
        return self.depth_ratio ** self.lobe_falloff(self.lobe)

    def transport(self, depth_min_m: float, lobe_terms: int | None = None
                  ) -> LightConeTransport:
        """The model in xi for a support from ``depth_min_m`` (rounded down to a
        DEPTH_QUANTUM_M step) with the current lobe: ``lobe_terms`` separable terms (default
        the plan's; "auto": the fewest within :attr:`lobe_tolerance`, or the lobe's own
        tolerance where that is larger)."""
        step = int(math.floor(max(0.0, depth_min_m) / DEPTH_QUANTUM_M))
        terms = self.lobe_terms if lobe_terms is None else lobe_terms
        tol = max(self.lobe_tolerance, self.lobe.tolerance)
        return LightConeTransport(self.shape, bin_width_s=self.bin_width_s,
                                  scan_width_m=self.scan_width_m, margin=0,
                                  depth_min_m=step * DEPTH_QUANTUM_M, depth_weight=self.scale,
                                  dtype=self.dtype, queue=self.queue, scratch=self.scratch,
                                  lobe=self.lobe, lobe_terms=terms, lobe_tolerance=tol,
                                  falloff=self.lobe_falloff(self.lobe))

    def operator(self, depth_min_m: float, setup=None) -> tuple[LinearOperator, int, float]:
        """(model in xi, first support row, Lipschitz constant) for a support from
        ``depth_min_m``, built once per DEPTH_QUANTUM_M step (:meth:`transport`);
        ``setup(step)`` names each step of a build as it starts."""
        step = int(math.floor(max(0.0, depth_min_m) / DEPTH_QUANTUM_M))
        key = (step, self.lobe.name, self.lobe_terms, self.lobe_tolerance,
               self.lobe_falloff(self.lobe))
        hit = self._ops.get(key)
        if hit is None:
            if setup is not None:
                setup("light-cone operator" + ("" if self.lobe.lambertian
                                               else f" ({self.lobe.name} lobe)"))
            lc = self.transport(depth_min_m)
            power = None if setup is None else (
                lambda k, n: setup(f"step size (power iteration {k}/{n})"))
            hit = (lc, lc.k_min, lipschitz(lc, progress=power))
            self._ops[key] = hit
        return hit

    def __call__(self, tau, *, depth_min_m: float = 0.0, callback=None, setup=None,
                 noise=None, slab_influence: LinearOperator | None = None,
                 iterations: int | None = None):
        """Albedo volume rho [z, y, x] >= 0 from a transient [t, y, x] (device or numpy).
        ``callback(k, x)`` follows the solver's iterations (:func:`clnlos.inverse.solvers.fista`),
        ``setup(step)`` the steps before them (operator, step size, warm start); ``noise``
        (device, shape of ``tau``): a realisation of tau's noise, for ``l1_weight="auto"``
        (module docstring); ``slab_influence``: the slab deconvolution's influence Phi on
        tau's grid (:meth:`clnlos.operators.spectral.SpectralFilter.influence`), fitted as
        Phi o L (module docstring), or None (L alone); ``iterations``: at most this many
        (default the plan's)."""
        on_device = isinstance(tau, cla.Array)
        q, dt = self.queue, self.dtype
        y = tau if on_device else cla.to_device(q, np.ascontiguousarray(tau, dt))
        op, row_min, L = self.operator(depth_min_m, setup)
        lobe = op.lobe
        scale = self.scale
        if slab_influence is not None:
            op = slab_influence @ op  # ||Phi|| < 1: L still bounds ||(Phi L)^T Phi L||
        if setup is not None:
            setup("LCT warm start")
        # warm start: LCT, rescaled to xi and to the best fit along its direction
        x0 = self.warm(y).get().astype(np.float64)
        x0[:row_min] = 0.0
        x0 /= scale[:, None, None]
        x0_g = cla.to_device(q, x0.astype(dt))
        ax = op.apply_device(x0_g)
        den = float(cla.dot(ax, ax).get())
        alpha = float(cla.dot(ax, y).get()) / den if den > 0 else 0.0
        x0_g *= dt.type(max(alpha, 0.0))
        lam_max = float(cla.max(op.adjoint_device(y)).get())
        l1 = self.l1_weight * max(lam_max, 0.0)
        self.l1_rule = "fixed"
        if self.l1_auto and noise is not None:
            l1 = L1_NOISE_FACTOR * max(float(cla.max(op.adjoint_device(noise)).get()), 0.0)
            self.l1_rule = "noise"
        tv = self.tv_weight * max(lam_max, 0.0)
        res = fista(op, y, x0_g, l1=l1, tv=tv, wz=self.tv_depth_scale, row_min=row_min,
                    iterations=self.iterations if iterations is None
                    else min(self.iterations, int(iterations)), tol=self.tol, lipschitz_const=L,
                    working_set=self.working_set,
                    callback=callback)
        self.report = SolveReport(res.iterations, res.restarts, L, l1, tv,
                                  row_min * C0 * self.bin_width_s / 2, res.objective,
                                  res.change, max(lam_max, 0.0), res.rounds, lobe.name,
                                  lobe.terms, lobe.errors[lobe.terms - 1],
                                  self.lobe_falloff(self.lobe))
        vol = res.x
        vol *= cla.to_device(q, np.broadcast_to(scale[:, None, None],
                                                 self.shape).astype(dt))
        return vol if on_device else vol.get()


def snr_matched_iterations(snr: float) -> int:
    """Iterations of the solver that regularise as a Wiener filter of light-cone SNR ``snr``
    does: ceil(sqrt(snr)) (module docstring, "Stopping")."""
    return max(1, int(math.ceil(math.sqrt(max(float(snr), 1.0)))))


def iterative_falloff(config) -> float:
    """The voxels' radial falloff exponent p (1/r^p, :mod:`clnlos.forward.transport`): the
    config's, else the Lambertian 4 (a ``brdf`` lobe carries its own r-dependence)."""
    return LAMBERTIAN_FALLOFF if config.falloff is None else float(config.falloff)


def configured_lobe(config) -> RetroLobe | None:
    """The retro lobe ``config.brdf`` names (None for "auto": chosen per capture,
    :mod:`clnlos.inverse.brdf_choice`; Lambertian until then)."""
    return None if config.brdf == AUTO else retro_lobe(config.brdf)


def support_depth_m(noise, config) -> float:
    """Shallowest depth of the iterative method's support (m): the configured depth, or for
    "auto" the capture's first arrival (:attr:`clnlos.inverse.snr.NoiseEstimate.
    nearest_depth_m`) less DEPTH_GUARD_M."""
    if config.depth_min_m != "auto":
        return float(config.depth_min_m)
    first = noise.nearest_depth_m
    return 0.0 if first is None else max(0.0, first - DEPTH_GUARD_M)


class IterativeMethod(Inversion):
    """``method = "iterative"`` (:class:`IterativeInversion` behind the inversion contract of
    :mod:`clnlos.inverse.methods`): the warm start's light-cone SNR and the support's depth
    are chosen from the data."""

    name = "iterative"
    forward_model = True
    lightcone_filter = True  # its LCT warm start

    def __init__(self, grid: InversionGrid, config, *, dtype, queue, scratch=None,
                 cache=None):
        super().__init__(grid, config, dtype=dtype, queue=queue, scratch=scratch, cache=cache)
        self.solver = IterativeInversion(grid.shape, iterations=config.iterations,
                                         l1_weight=config.l1_weight, tv_weight=config.tv_weight,
                                         warm_snr=initial_inversion_snr(config), cache=cache,
                                         lobe=configured_lobe(config),
                                         lobe_terms=None if config.brdf_terms == "auto"
                                         else int(config.brdf_terms),
                                         falloff=iterative_falloff(config), **self.geometry())
        self.depth_min_m = 0.0
        self.noise_g = None
        self.slab_influence = None
        self.stop_iterations: int | None = None  # the SNR-matched stop (snr_matched_iterations)

    def configure(self, tau_g, noise, rule_snr: float, timed, probe=None,
                  slab_influence=None, rule: str | None = None) -> dict:
        snr, rule = choose_lightcone_snr(self.solver.warm, self.config, noise, tau_g, rule_snr,
                                         timed, probe, rule)
        self.solver.warm.set_snr(snr)
        self.depth_min_m = support_depth_m(noise, self.config)
        # "auto" L1 weight: from a realisation of the noise (photon counts), else fixed
        self.noise_g = probe() if self.config.l1_weight == "auto" and probe else None
        use = self.config.slab_model == "influence" and slab_influence is not None
        self.slab_influence = slab_influence() if use else None
        self.stop_iterations = (snr_matched_iterations(snr) if rule is not None
                                and slab_influence is None
                                and "iterations" not in self.config.user_fields else None)
        return {**lightcone_snr_params(snr, rule),
                "slab_model_used": "influence" if use else "none"}

    def __call__(self, tau_g, *, progress=None, setup=None):
        n = self.solver.iterations
        if self.stop_iterations is not None:
            n = min(n, self.stop_iterations)
        cb = None if progress is None else (lambda k, _x: progress(k + 1, n))
        return self.solver(tau_g, depth_min_m=self.depth_min_m, callback=cb, setup=setup,
                           noise=self.noise_g, slab_influence=self.slab_influence,
                           iterations=n)

    def report(self) -> dict | None:
        return self.solver.report.as_dict()

    def set_lobe(self, lobe: RetroLobe) -> None:
        """The retro lobe of the next reconstructions (``brdf = "auto"``'s choice)."""
        self.solver.set_lobe(lobe)

    @contextmanager
    def iteration_budget(self, iterations: int):
        """At most ``iterations`` iterations inside the block (a search's reconstructions),
        each lobe's terms within SEARCH_LOBE_TOLERANCE (the held-out scores compare models:
        the cheaper terms of INVERSION_LOBE_TOLERANCE are for the reconstruction a lobe is
        chosen for)."""
        keep = self.solver.iterations, self.solver.lobe_tolerance
        self.solver.iterations = min(keep[0], int(iterations))
        self.solver.lobe_tolerance = SEARCH_LOBE_TOLERANCE
        try:
            yield
        finally:
            self.solver.iterations, self.solver.lobe_tolerance = keep

    def predict(self, volume: np.ndarray) -> cla.Array:
        """L rho: the light-cone transport of an albedo volume [z, y, x] on the support of
        the last call (the slab's influence not applied), on the device."""
        op, _, _ = self.solver.operator(self.depth_min_m)
        xi = np.asarray(volume, dtype=np.float64) / self.solver.scale[:, None, None]
        return op.apply_device(cla.to_device(self.queue, xi.astype(self.dtype)))

    def used(self) -> dict:
        r = self.solver.report
        return {"iterations_rule": "snr" if self.stop_iterations is not None else "config",
                "iterations_stop": self.stop_iterations,
                "falloff_used": r.falloff,
                "l1_rule": self.solver.l1_rule,
                "l1_weight_used": r.l1 / r.lam_max if r.lam_max > 0 else None,
                "brdf_used": r.brdf, "brdf_terms_used": r.lobe_terms,
                "brdf_terms_error": r.lobe_error}
