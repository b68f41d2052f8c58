"""The parameters a reconstruction chooses from the data (:mod:`clnlos.inverse.pipeline`): the
"auto" SNRs from the noise estimate and cross-validation (:func:`auto_snrs`), the slab
model's accuracy, the noise realisation or law of the light-cone UPRE (:class:`NoiseProbe`),
the split searches by held-out photons and split-half reproducibility and the retro lobe's
search (:class:`ParameterSearches`, a mixin of the pipeline), and what their candidates
share (:class:`PreparedCapture`). Which rule runs where: docs/parameters.md and
docs/validation/parameter-rules.md."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

import numpy as np
import pyopencl.array as cla

from clnlos.brdf.lobes import auto_challengers, auto_ladder
from clnlos.config import ReconstructionConfig
from clnlos.inverse.brdf_choice import (
    LOBE_NOT_SEARCHED,
    LOBE_SEARCH_ITERATIONS,
    both_margins,
    challenge,
    choose_lobe,
    score_margin,
    search_factors,
    surface_of,
)
from clnlos.inverse.reproducibility import (
    LIGHTCONE_SNRS,
    candidate_order,
    first_reproducible,
    kappa_min,
    mask_agreement,
    otsu_mask,
    search_block,
    slab_snrs,
)
from clnlos.inverse.snr import (
    MEASURED_MODEL_SNR,
    SNR_MAX,
    NoiseEstimate,
    combined_snr,
    is_counts,
    lightcone_snr,
)
from clnlos.inverse.tail_fill import TailFilledDeconvolution
from clnlos.inverse.thinning import (
    CV_FACTOR_RANGE,
    CV_FOLDS,
    CV_NOISE_RUNS,
    CV_SIGNIFICANCE,
    CV_STEP,
    descend_factor,
    fitted_residual,
    scaled_fit,
    thin_counts,
)
from clnlos.io.capture import Capture
from clnlos.physics.grid import block_sums, grid_label
from clnlos.physics.lobe import RetroLobe


NOISE_PROBE_SEED = 0     # the noise realisation of ReconstructionPipeline._noise_like


class NoiseProbe:
    """A realisation of the inverted transient's noise, computed on the first call (the
    methods that need it: :mod:`clnlos.inverse.methods`); where that noise went through
    steps along t alone (no slab deconvolution), also its law: ``columns()`` = (K, d), the
    noise n = K e of every scan column, K (sparse, inverted bins x raw bins) the
    preprocessing with the normalisation, e independent of variance d (the raw bins'
    Poisson variance summed over the scan points, float64): enough for its expected power
    spectrum without a realisation (:meth:`clnlos.inverse.lct.LCT.upre_snr`)."""

    def __init__(self, make, columns=None):
        self.make, self.value, self.columns = make, None, columns

    def __call__(self):
        if self.value is None:
            self.value = self.make()
        return self.value

DECONVOLVED_KEPT = 4  # slab SNRs whose deconvolution a prepared capture keeps (a search's)


@dataclass
class PreparedCapture:
    """A capture preprocessed once for every reconstruction made of it (the candidates of a
    split search: :meth:`ReconstructionPipeline.reproducibility_snrs`,
    :meth:`ReconstructionPipeline.thinning_factor`, the lobes of
    :meth:`ReconstructionPipeline.brdf_lobe`): the raw counts and their noise
    estimate, the preprocessed and normalised transient ``tau`` (device, guard bins kept;
    never changed), its scan-summed profile and the normalisation ``scale``; filled in as
    the candidates need them: the slab GCV pick, the deconvolutions by slab SNR (the last
    DECONVOLVED_KEPT, with what each added to a volume's params and notes), the tail fills
    of the data and of the noise realisation (:class:`TailFilledDeconvolution` memos), and
    the noise realisation preprocessed (:meth:`ReconstructionPipeline._probe`)."""

    transient: np.ndarray
    noise: NoiseEstimate
    tau: cla.Array
    profile: np.ndarray
    scale: float
    gcv_snr: float | None = None
    deconvolved: dict = field(default_factory=dict)
    fills: dict = field(default_factory=dict)
    noise_fills: dict = field(default_factory=dict)
    noise_tau: cla.Array | None = None

    def keep(self, snr: float, entry: tuple) -> tuple:
        """Keep the deconvolution at ``snr`` (the oldest dropped past DECONVOLVED_KEPT)."""
        self.deconvolved[snr] = entry
        while len(self.deconvolved) > DECONVOLVED_KEPT:
            self.deconvolved.pop(next(iter(self.deconvolved)))
        return entry


def model_snr_for(capture: Capture, config: ReconstructionConfig) -> float:
    """The slab model's accuracy as an SNR (:mod:`clnlos.inverse.snr`): the configured number, or
    for "auto" infinite when the capture was simulated by clnlos with this very slab (the
    model made the data) and MEASURED_MODEL_SNR otherwise."""
    if config.model_snr != "auto":
        return float(config.model_snr)
    if config.slab is None:  # no deconvolution: the recorded slab is not read (--no-slab)
        return math.inf
    recorded = capture.recorded_slab()
    if recorded is not None and recorded[0] == config.slab:
        return math.inf
    return MEASURED_MODEL_SNR


def method_slab_snr(gcv_snr: float, slab_snr_min: float | None,
                    photon_snr: float | None = None) -> float:
    """The data's slab SNR for a method: cross-validation's ``gcv_snr``; where
    ``photon_snr`` (the photon rule's, :mod:`clnlos.inverse.snr`) is given and higher, the
    geometric mean sqrt(gcv_snr photon_snr); at least the method's ``slab_snr_min`` where it
    has one (:attr:`clnlos.inverse.methods.Inversion.slab_snr_min`). Before the model's
    accuracy is combined with it (:func:`auto_snrs`, which also clips to SNR_MAX)."""
    snr = gcv_snr
    if photon_snr is not None and photon_snr > gcv_snr:
        snr = math.sqrt(gcv_snr * photon_snr)
    return snr if slab_snr_min is None else max(snr, float(slab_snr_min))


def auto_snrs(noise: NoiseEstimate, config: ReconstructionConfig,
              model_snr: float = math.inf, *, data_snr: float | None = None,
              data_inversion_snr: float | None = None) -> tuple[float, float]:
    """(deconvolution SNR, light-cone SNR) of a capture: the configured numbers, or for
    "auto" the data's own (``data_snr`` for the slab, combined with ``model_snr``;
    ``data_inversion_snr`` for the light cone: :mod:`clnlos.inverse.gcv`) where given, else the
    photon rule of :mod:`clnlos.inverse.snr` (photon count and model accuracy;
    :func:`lightcone_snr`)."""
    if config.snr != "auto":
        snr = float(config.snr)
    else:
        snr = combined_snr(noise.snr if data_snr is None else data_snr, model_snr)
    if config.inversion_snr != "auto":
        inv = float(config.inversion_snr)
    else:
        inv = lightcone_snr(snr) if data_inversion_snr is None else float(data_inversion_snr)
    return snr, inv


# what a split search records where a half of the split holds no counts (the GCV rule kept)
SPLIT_EMPTY_REASON = "a half of the split holds no counts"
SPLIT_EMPTY = f"gcv ({SPLIT_EMPTY_REASON})"


class ParameterSearches:
    """The searches of :class:`clnlos.inverse.pipeline.ReconstructionPipeline` that choose a
    capture's parameters from its own counts (the retro lobe of ``brdf = "auto"``, the
    thinning factor, the reproducibility SNRs) and the noise realisation the light-cone UPRE
    and the "auto" L1 weight use: each candidate is one run of the pipeline's own stages
    on a prepared capture (:class:`PreparedCapture`), so a mixin of the pipeline."""

    # the factors on GCV's slab SNR the thinning search may reach (clnlos.inverse.thinning;
    # a measurement may widen it: tools/snr_rule_check.py --both-ways)
    thinning_factor_range = CV_FACTOR_RANGE

    def brdf_lobe(self, transient: np.ndarray, noise: NoiseEstimate, model_snr: float,
                  setup=None) -> tuple[RetroLobe, dict]:
        """(the retro lobe ``brdf = "auto"`` takes for this capture, the params recording the
        search): the lobe of :func:`clnlos.brdf.lobes.auto_ladder` whose reconstruction from
        one half of a binomial split of the counts best predicts the other half, from its
        whole volume and from its surface (:mod:`clnlos.inverse.brdf_choice`); the Lambertian
        lobe where the capture is not counts or a half is empty (:data:`LOBE_NOT_SEARCHED`).
        A capture larger than the search's grid is searched on a pipeline of that grid
        (:meth:`_lobe_search_plan`)."""
        counts = (noise.photon_counts and not noise.noise_free
                  and is_counts(np.asarray(transient)))
        plan = self._lobe_search_plan(transient.shape) if counts else None
        if plan is not None:
            small, f = plan
            y = block_sums(transient, f)
            lobe, params = small.brdf_lobe(y, small.raw_noise(y), model_snr, setup)
            return lobe, {**params, "brdf_search_grid": grid_label(small.shape)}
        halves = self._split(transient) if counts else None
        if halves is None:
            return RetroLobe.lambert(), {"brdf_rule_used": LOBE_NOT_SEARCHED}
        train, test = halves
        held, phi, noise_runs = self._held_out_prediction_target(test)
        prep = self.prepare(train)  # once: every lobe reconstructs the same half
        resampled = self.resampling_snr(None)
        fits: dict[str, np.ndarray] = {}
        surface_fits: dict[str, np.ndarray] = {}

        def predicted(volume: np.ndarray) -> np.ndarray:
            pred = self.invert.predict(volume)
            return scaled_fit((pred if phi is None else phi.apply_device(pred)).get(), held)

        def score(cand: RetroLobe) -> float:
            if setup is not None:
                setup(f"BRDF lobe by thinning: {cand.name}")
            self.invert.set_lobe(cand)
            with self.invert.iteration_budget(LOBE_SEARCH_ITERATIONS):  # predicted by the
                rec = self._reconstruct(prep, {}, model_snr=model_snr, slab_snr_factor=1.0,
                                        resampled=resampled)
                fits[cand.name] = predicted(rec.volume)  # operator that reconstructed it
                surface_fits[cand.name] = predicted(surface_of(rec.volume))
            return fitted_residual(fits[cand.name], held, scaled=True)

        def margin(new: RetroLobe, best: RetroLobe) -> float:
            a, b = surface_fits[new.name], surface_fits[best.name]
            gain = (fitted_residual(b, held, scaled=True)
                    - fitted_residual(a, held, scaled=True))
            return both_margins(gain, score_margin(fits[new.name], fits[best.name], held,
                                                   noise_runs),
                                score_margin(a, b, held, noise_runs))

        chosen, tried = choose_lobe(auto_ladder(), score, margin)
        chosen, tried = challenge(chosen, tried, auto_challengers(), score, margin)
        surface = {c: fitted_residual(q, held, scaled=True) for c, q in surface_fits.items()}
        return chosen, {"brdf_rule_used": "thinning", "brdf_chosen": chosen.name,
                        "brdf_tried": json.dumps([[c, v] for c, v in tried]),
                        "brdf_tried_surface": json.dumps([[c, surface[c]] for c, _ in tried]),
                        "brdf_search_grid": grid_label(self.shape)}

    def _lobe_search_plan(self, shape_in) -> tuple | None:
        """(a pipeline of this one's config on the lobe search's grid, the scan points it
        sums per side) for captures of ``shape_in`` (raw [t, y, x]); None where this
        pipeline's grid is the search's already (:func:`search_factors`)."""
        return self._search_plan(shape_in, *search_factors(self.shape))

    def _split_search_plan(self, shape_in) -> tuple | None:
        """:meth:`_lobe_search_plan` for the reproducibility search: the scan points summed
        per side by :func:`clnlos.inverse.reproducibility.search_block`, the time axis
        kept."""
        return self._search_plan(shape_in, search_block(*self.shape[1:]), 1)

    def _drop_search_plans(self) -> None:
        """Free the search grids' pipelines (:meth:`_search_plan`; rebuilt on next use)."""
        self.__dict__.pop("_search_plans", None)

    def _search_plan(self, shape_in, f: int, ft: int) -> tuple | None:
        """(a pipeline of this one's config for captures of ``shape_in`` (raw [t, y, x]) with
        their scan points summed in f x f blocks and ft bins per bin, f), built once per
        grid; None where f = ft = 1 (this pipeline is that grid)."""
        if f == 1 and ft == 1:
            return None
        key = (tuple(shape_in), f, ft)
        plans = self.__dict__.setdefault("_search_plans", {})
        if key not in plans:
            nt_in, ny, nx = shape_in
            bins = max(1, round(self.shape[0] / ft))
            config = self.config if ft == 1 else self.config.replace(bins=bins)
            plans[key] = (type(self)((nt_in, ny // f, nx // f),
                                     bin_width_s=self.raw_bin_width_s,
                                     start_s=self.raw_start_s, scan_width_m=self.scan_width_m,
                                     config=config, dtype=self.dtype, queue=self.queue), f)
        return plans[key]

    def _held_out_prediction_target(self, y2: np.ndarray):
        """(the held-out half as the inversion sees it, host; the slab's influence Phi2 that a
        prediction goes through, or None without a slab; realisations of its noise): with a
        slab, :meth:`_held_out` (deconvolved at its own GCV SNR); without, less its
        background floor (as the reconstructed half, :meth:`prepare`), preprocessed and
        divided by its peak."""
        if self.deconv is not None:
            held, snr, noise_runs = self._held_out(y2)
            return held, self._slab_influence(snr), noise_runs
        tau = self.pre(self.without_floor(y2))
        _, peak = self._profile_peak(tau)
        scale = 1.0 / peak if peak > 0 else 1.0
        if peak > 0:
            self._scale_inplace(tau, scale)
        noise_runs = [self._noise_like(y2, scale, None, 0.0, NOISE_PROBE_SEED + 1 + j).get()
                      for j in range(CV_NOISE_RUNS)]
        return tau.get(), None, noise_runs

    def _thinning_applies(self, transient: np.ndarray, noise: NoiseEstimate,
                          model_snr: float) -> bool:
        """Whether an "auto" slab SNR is chosen by thinning: the config's rule is thinning
        (:attr:`clnlos.config.ReconstructionConfig.thinning`), with a slab, a method with a
        forward model and a capture of photon counts (``noise``: the raw capture's,
        :meth:`raw_noise`); under ``snr_rule = "auto"`` also only where the slab model is
        exact (``model_snr`` infinite: a capture clnlos simulated with this slab). The score
        takes Phi2 L rho for the held-out photons' mean: on a measured capture the model's
        own error (MEASURED_MODEL_SNR, 1e4) exceeds the photon noise it would judge by, and
        the combined SNR is capped at it anyway."""
        return self.invert.forward_model and self._split_search_applies(
            self.config.thinning, transient, noise, model_snr)

    def _reproducibility_applies(self, transient: np.ndarray, noise: NoiseEstimate,
                                 model_snr: float) -> bool:
        """Whether "auto" SNRs are chosen by split-half reproducibility: the config's rule
        is it (:attr:`clnlos.config.ReconstructionConfig.reproducibility`: LCT and f-k under
        "auto"), with a slab, an "auto" slab SNR and a capture of photon counts; under
        ``snr_rule = "auto"`` also only where the slab model is exact (``model_snr``
        infinite). On a measured capture the model's error is the same in both halves: they
        would agree on it, and the combined SNR is capped at MEASURED_MODEL_SNR anyway."""
        return self._split_search_applies(self.config.reproducibility, transient, noise,
                                          model_snr)

    def _split_search_applies(self, rule_on: bool, transient: np.ndarray,
                              noise: NoiseEstimate, model_snr: float) -> bool:
        """The gate both split searches share: their rule on (``rule_on``), not under
        ``snr_rule = "auto"`` where the slab model is inexact (``model_snr`` finite), an
        "auto" slab SNR, a slab, and a capture of photon counts (``noise``: the raw
        capture's, :meth:`raw_noise`) with light above its background (the halves of a
        capture of noise alone agree on nothing: every candidate would be tried for none,
        the GCV rule stands, and a note says the capture holds no light)."""
        c = self.config
        if not rule_on or (c.snr_rule == "auto" and math.isfinite(model_snr)):
            return False
        return (c.snr == "auto" and self.deconv is not None and noise.photon_counts
                and not noise.noise_free and noise.first_arrival_s is not None
                and is_counts(np.asarray(transient)))

    def _split(self, transient: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """The binomial split of the counts (:func:`clnlos.inverse.thinning.thin_counts`),
        or None where a half holds no counts in the kept window (the searches then keep
        the GCV rule, recorded as :data:`SPLIT_EMPTY`)."""
        halves = thin_counts(np.asarray(transient))
        k0, k1 = self.raw_window
        return halves if all(np.any(h[k0:k1]) for h in halves) else None

    def reproducibility_candidates(self) -> list[tuple[float, float | None]]:
        """The (slab SNR, light-cone SNR) settings the search tries, least regularised first
        (:func:`clnlos.inverse.reproducibility.candidate_order`): the light-cone SNRs where
        the method has a light-cone filter and the config leaves its SNR to "auto"."""
        lc = (LIGHTCONE_SNRS if self.invert.lightcone_filter
              and self.config.inversion_snr == "auto" else (None,))
        return candidate_order(slab_snrs(self.invert.lightcone_filter), lc)

    def reproducibility_snrs(self, transient: np.ndarray, model_snr: float = math.inf,
                             setup=None, *, resampled: float = math.inf
                             ) -> tuple[tuple[float, float | None] | None, dict]:
        """((slab SNR, light-cone SNR or None), the params recording the search): the first
        of :meth:`reproducibility_candidates` at which the two halves of a binomial split of
        the counts (:func:`clnlos.inverse.thinning.thin_counts`) give Otsu masks of their
        max-intensity projections that agree with Cohen's kappa >= the method's bar
        (:func:`clnlos.inverse.reproducibility.kappa_min`), else the most
        reproducible candidate (:mod:`clnlos.inverse.reproducibility`; a note says so). The
        candidates are used as given: on a measured capture (``snr_rule`` by name) the
        model's accuracy is not combined with them. Where a half holds no counts in the
        window, the method's GCV rule stands (None, and a note). A capture larger than the
        search's grid (:func:`clnlos.inverse.reproducibility.search_block`) is searched on a
        pipeline of its counts summed over blocks of scan points (:meth:`_split_search_plan`;
        the params record ``reproducibility_grid``), and again on its own grid where no
        candidate's halves agreed there (the fallback, the most reproducible candidate, is
        decided on the capture's own grid; ``reproducibility_block_grid`` and
        ``reproducibility_block_tried`` record the block sums' search)."""
        plan = self._split_search_plan(transient.shape)
        if plan is not None:
            small, f = plan
            snrs, cv = small.reproducibility_snrs(block_sums(transient, f), model_snr, setup,
                                                  resampled=resampled)
            del small, plan
            self._drop_search_plans()  # its buffers freed before the capture's own stages
            if cv.get("reproducibility_agreed") is not False:
                return snrs, cv
            # no candidate agreed on the block sums: the most reproducible one is chosen
            # among kappas that all fall short, which the capture's own grid decides
            block = {"reproducibility_block_grid": cv["reproducibility_grid"],
                     "reproducibility_block_tried": cv["reproducibility_tried"]}
        else:
            block = {}
        halves = self._split(transient)
        if halves is None:
            return None, {"snr_rule_used": SPLIT_EMPTY, **block}
        prepared = [self.prepare(h) for h in halves]

        def agreement(cand: tuple[float, float | None]) -> float:
            if setup is not None:
                lc = "" if cand[1] is None else f", light cone {cand[1]:.3g}"
                setup(f"SNRs by reproducibility: slab {cand[0]:.3g}{lc}")
            masks = [otsu_mask(self._reconstruct(h, {}, model_snr=model_snr, snrs=cand,
                                                 resampled=resampled).volume)
                     for h in prepared]
            return mask_agreement(*masks)

        bar = kappa_min(self.invert.lightcone_filter)
        chosen, tried, agreed = first_reproducible(self.reproducibility_candidates(),
                                                   agreement, bar)
        kappa = dict(tried)[chosen]
        return chosen, {"snr_rule_used": "reproducibility", "reproducibility_kappa": kappa,
                        "reproducibility_kappa_min": bar,
                        "reproducibility_agreed": agreed,
                        "reproducibility_grid": grid_label(self.shape),
                        "reproducibility_tried": json.dumps([[c[0], c[1], k]
                                                             for c, k in tried]), **block}

    def thinning_factor(self, transient: np.ndarray, model_snr: float = math.inf,
                        setup=None, *, resampled: float = math.inf) -> tuple[float, dict]:
        """(factor on GCV's slab SNR, the params recording the search) by cross-validation
        on a binomial split of the counts (:mod:`clnlos.inverse.thinning`): for each
        candidate the first half is reconstructed at that factor on its own GCV pick and its
        prediction Phi2 L rho scored against the second half deconvolved at that half's own
        GCV SNR (with CV_FOLDS = 2 also the other way round, the score the folds' mean).
        Where a half holds no counts in the window, GCV's pick (factor 1) stands."""
        halves = self._split(transient)
        if halves is None:
            return 1.0, {"snr_rule_used": SPLIT_EMPTY}
        folds = []
        for train, test in list(zip(halves, halves[::-1], strict=True))[:CV_FOLDS]:
            held, snr, noise = self._held_out(test)
            folds.append((self.prepare(train), held, self._slab_influence(snr), noise,
                          float(np.sum(np.square(held, dtype=np.float64)))))
        gcv_train: list[float] = []
        fits: dict[float, list[np.ndarray]] = {}

        def score(f: float) -> float:
            if setup is not None:
                setup(f"slab SNR by thinning: {f:.3g} x GCV's pick")
            scores, fits[f] = [], []
            for train, held, phi, _, _ in folds:
                rec = self._reconstruct(train, {}, model_snr=model_snr, slab_snr_factor=f,
                                        resampled=resampled)
                gcv_train.append(rec.params.get("snr_data", math.nan))
                pred = phi.apply_device(self.invert.predict(rec.volume)).get()
                fits[f].append(scaled_fit(pred, held))
                scores.append(fitted_residual(fits[f][-1], held, scaled=True))
            return float(np.mean(scores))

        def margin(f_new: float, f_best: float) -> float:
            """CV_SIGNIFICANCE standard errors of the score difference's part from the
            held-out half's noise, 2 <n, q_new - q_best> / ||held||^2 over each fold's noise
            realisations (the folds' variances summed as if independent). The split's own
            variation (which half each photon went to) is not in it: on a 16 x 16 'UT' it
            was 3-6x larger (12 split seeds), so a choice between neighbouring factors can
            depend on THINNING_SEED (clnlos.inverse.thinning)."""
            var = 0.0
            for k, (_, _, _, noise, energy) in enumerate(folds):
                d = (fits[f_new][k] - fits[f_best][k]).ravel()
                var += np.mean([(2.0 * float(r.ravel() @ d) / energy) ** 2 for r in noise])
            return CV_SIGNIFICANCE * math.sqrt(var) / len(folds)

        def clipped(f: float) -> bool:  # the step before already at SNR_MAX: no change
            g = gcv_train[0] if gcv_train else math.nan
            return not g * f / CV_STEP < SNR_MAX

        factor, tried = descend_factor(score, limit=clipped, margin=margin,
                                       factor_range=self.thinning_factor_range)
        return factor, {"snr_rule_used": "thinning", "thinning_factor": factor,
                        "thinning_tried": json.dumps([[f, v] for f, v in tried])}

    def _held_out(self, y2: np.ndarray) -> tuple[np.ndarray, float, list[np.ndarray]]:
        """(the held-out half's deconvolved transient on the inverted grid, host; its GCV
        slab SNR; CV_NOISE_RUNS realisations of its noise through the same steps,
        :meth:`_noise_like`): preprocessed, divided by its peak (the score fits the scale)
        and deconvolved at the SNR GCV picks for it (:meth:`slab_gcv_snr`), tail-filled where
        the window needs it."""
        noise = self.raw_noise(y2)
        tau = self.pre(self.without_floor(y2, noise))
        profile, peak = self._profile_peak(tau)
        if peak > 0:
            self._scale_inplace(tau, 1.0 / peak)
        snr = self.slab_gcv_snr(tau)
        deconv = self._deconvolution_for(profile, noise, snr, {}, [])
        deconv.set_snr(snr)
        out = deconv(tau)[:self.shape[0]].get()
        scale = 1.0 / peak if peak > 0 else 1.0
        noise_runs = [self._noise_like(y2, scale, deconv, snr, NOISE_PROBE_SEED + 1 + j).get()
                      for j in range(CV_NOISE_RUNS)]
        return out, snr, noise_runs

    def _noise_like(self, transient: np.ndarray, scale: float, deconv, snr: float,
                    seed: int = NOISE_PROBE_SEED) -> cla.Array:
        """A realisation of the noise of the transient the inversion receives: Gaussian of
        the capture's Poisson variance (each bin's count; ``transient`` holds counts), seed
        ``seed`` (default NOISE_PROBE_SEED), through the same linear steps as the data
        (preprocessing, the normalisation ``scale``: :meth:`_noise_preprocessed`; the slab
        deconvolution ``deconv`` at ``snr`` when not None, the guard bins dropped): the
        noise spectrum of :meth:`clnlos.inverse.lct.LCT.upre_snr`.
        """
        t = self._noise_preprocessed(transient, scale, seed)
        if deconv is not None:
            deconv.set_snr(snr)
            t = deconv(t)
        return t[:self.shape[0]] if self.n_guard else t

    def _noise_preprocessed(self, transient: np.ndarray, scale: float,
                            seed: int = NOISE_PROBE_SEED) -> cla.Array:
        """The noise realisation of :meth:`_noise_like` preprocessed and normalised (guard
        bins kept), drawn block by block of rows (the same stream as one draw; no
        float64 temporary of the capture's size)."""
        y = np.asarray(transient)
        rng = np.random.default_rng(seed)
        n = np.empty(y.shape, self.dtype)
        rows = max(1, (1 << 20) // max(1, int(np.prod(y.shape[1:]))))
        for r0 in range(0, y.shape[0], rows):
            blk = y[r0:r0 + rows]
            n[r0:r0 + rows] = np.sqrt(np.maximum(blk, 0), dtype=np.float64) * \
                rng.standard_normal(blk.shape)
        t = self.pre(cla.to_device(self.queue, n))
        if scale != 1.0:
            self._scale_inplace(t, scale)
        return t

    def _noise_columns(self, prep: PreparedCapture) -> tuple:
        """(K, d) of :class:`NoiseProbe` for a prepared capture without a slab
        deconvolution: the preprocessing's rows of the inverted grid times the
        normalisation, and the raw counts' Poisson variance summed over the scan points
        (the variance of :meth:`_noise_preprocessed`'s realisation)."""
        y = np.asarray(prep.transient)
        y = y.reshape(y.shape[0], -1)
        d = (np.maximum(y, 0) if y.min() < 0 else y).sum(axis=1, dtype=np.float64)
        return self._pre_matrix[:self.shape[0]] * prep.scale, d

    def _probe(self, prep: PreparedCapture, deconv, snr: float) -> cla.Array:
        """:meth:`_noise_like` of a prepared capture (its preprocessed part kept in
        ``prep``: the same for every candidate of a search), deconvolved by ``deconv`` at
        ``snr`` (a tail fill's memo kept too)."""
        if prep.noise_tau is None:
            prep.noise_tau = self._noise_preprocessed(prep.transient, prep.scale)
        t = prep.noise_tau
        if deconv is not None:
            deconv.set_snr(snr)
            t = (deconv(t, prep.noise_fills) if isinstance(deconv, TailFilledDeconvolution)
                 else deconv(t))
        return t[:self.shape[0]] if self.n_guard else t
