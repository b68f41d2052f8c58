"""``brdf = "auto"``: the retro lobe that best predicts held-out photons.

A photon-counting capture splits by binomial thinning into two independent Poisson halves
(:mod:`clnlos.inverse.thinning`). For each lobe of a ladder ordered from the Lambertian to
ever sharper lobes (:func:`clnlos.brdf.lobes.auto_ladder`), the first half is reconstructed
with that lobe and its prediction of the second half scored,

    CV(f) = min_{a >= 0} || y2' - a Phi2 L_f rho_f ||^2 / || y2' ||^2,

y2' the held-out half as the inversion sees it (deconvolved at its own GCV SNR behind a
slab, Phi2 that deconvolution's influence; preprocessed without one), L_f the light-cone
transport with lobe f (:mod:`clnlos.forward.transport`). A lobe wider than the target's
cannot put the light where the data have it; a narrower one fits the first half's noise by
placing voxels in front of each scan point and predicts the second half worse. The ladder is
walked from the Lambertian: a sharper lobe is taken where its score is lower than the best
so far by more than CV_SIGNIFICANCE standard errors of the held-out noise's part in the
difference (:func:`score_margin`), and the walk stops at the first lobe that is not.
A wider lobe and a sharper one can explain the same photons with different volumes: a lobe a
few degrees wide lets each voxel explain its own scan point's histogram (the volume becomes the
unfocused data, a bowl of voxels per target point), which predicts the held-out half well where
the photons are many. A hidden surface must explain the data from the voxels it holds, one per
scan point: a lobe is therefore taken only where it also predicts the held-out half better
from its surface, the volume's brightest voxels as many as scan points (:func:`surface_of`),
by the same margin of the noise (:func:`both_margins`; docs/brdf.md, "Why the data do not
tell the retroreflector from a diffuse surface").
A lobe of another family (:func:`clnlos.brdf.lobes.auto_challengers`: the retroreflector,
whose falloff in r differs, not only its width in theta) does not fit the order of the walk:
each is scored after it against the lobe the walk chose and taken where its score is lower
by more than the same margin (:func:`challenge`).
The search never sees the truth, only the capture; it costs one reconstruction of half the
data per lobe tried (3 to 6), on a grid of at most LOBE_SEARCH_POINTS scan points per side and
LOBE_SEARCH_BINS bins (:func:`search_factors`: a larger capture's counts summed over blocks of
scan points, still Poisson counts, and its time axis rebinned), so that choosing costs a
fraction of the reconstruction it chooses for (docs/brdf.md).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence

import numpy as np

from clnlos.inverse.thinning import CV_SIGNIFICANCE
from clnlos.physics.lobe import RetroLobe

LOBE_NOT_SEARCHED = "lambertian (not searched)"
LOBE_NOT_SEARCHED_REASON = ("the lobe is chosen on held-out photons and the capture is not "
                            "photon counts (or a half of the split is empty)")
PATIENCE = 1  # lobes in a row without a significant gain that end the walk
LOBE_SEARCH_ITERATIONS = 50  # iterations of each half reconstruction at most
# the grid the search reconstructs its halves on, at most: scan points per side and time
# bins (a larger capture's counts are summed over blocks of scan points and rebinned; the
# chosen lobe then runs on the capture's own grid); the grid of the held-out scores that
# docs/brdf.md reports for the LCT release (tools/retro_identifiability.py)
LOBE_SEARCH_POINTS = 32
LOBE_SEARCH_BINS = 256


def score_margin(fit_new: np.ndarray, fit_best: np.ndarray, held: np.ndarray,
                 noise_runs: Sequence[np.ndarray]) -> float:
    """CV_SIGNIFICANCE standard errors of the held-out noise's part of a score difference,
    2 <n, q_new - q_best> / ||held||^2 over realisations n of that noise (``noise_runs``), q
    the scaled predictions (:func:`clnlos.inverse.thinning.scaled_fit`)."""
    energy = float(np.sum(np.square(held, dtype=np.float64)))
    if not energy > 0 or not noise_runs:
        return 0.0
    d = (np.asarray(fit_new, np.float64) - np.asarray(fit_best, np.float64)).ravel()
    var = float(np.mean([(2.0 * float(np.asarray(r, np.float64).ravel() @ d) / energy) ** 2
                         for r in noise_runs]))
    return CV_SIGNIFICANCE * math.sqrt(var)


def surface_of(volume: np.ndarray) -> np.ndarray:
    """The volume [z, y, x] with only its brightest voxels kept, as many as its columns (scan
    points): the surface it reconstructs, the rest zero (ties at the threshold kept)."""
    v = np.asarray(volume)
    k = v.shape[-2] * v.shape[-1]
    if v.size <= k:
        return v.copy()
    threshold = np.partition(v.ravel(), -k)[-k]
    return np.where(v >= threshold, v, 0).astype(v.dtype, copy=False)


def both_margins(gain_surface: float, margin_volume: float, margin_surface: float) -> float:
    """The margin a candidate's gain on the whole volume must pass: ``margin_volume`` where
    its surface's score gains ``gain_surface`` > ``margin_surface`` too, else infinite (the
    lobe is not taken: module docstring)."""
    return margin_volume if gain_surface > margin_surface else math.inf


def choose_lobe(ladder: Sequence[RetroLobe], score: Callable[[RetroLobe], float],
                margin: Callable[[RetroLobe, RetroLobe], float] | None = None,
                patience: int = PATIENCE) -> tuple[RetroLobe, list[tuple[str, float]]]:
    """(the lobe the walk of the module docstring stops at, every (name, score) tried), on
    ``ladder`` in order (its first entry the default)."""
    tried: list[tuple[str, float]] = []
    scores: dict[int, float] = {}

    def at(k: int) -> float:
        if k not in scores:
            scores[k] = float(score(ladder[k]))
            tried.append((ladder[k].name, scores[k]))
        return scores[k]

    best = 0
    at(best)
    for k in range(1, len(ladder)):
        if k - best > patience:
            break
        gain = at(best) - at(k)
        if gain > (0.0 if margin is None else margin(ladder[k], ladder[best])):
            best = k
    return ladder[best], tried


def challenge(best: RetroLobe, tried: list[tuple[str, float]], challengers: Sequence[RetroLobe],
              score: Callable[[RetroLobe], float],
              margin: Callable[[RetroLobe, RetroLobe], float] | None = None
              ) -> tuple[RetroLobe, list[tuple[str, float]]]:
    """(``best``, or the challenger that beats it by more than ``margin``, and ``tried`` with
    each challenger's (name, score) appended): the lobes of another family than the walk's
    (module docstring), each against the best so far."""
    tried = list(tried)
    best_score = dict(tried)[best.name]
    for cand in challengers:
        s = float(score(cand))
        tried.append((cand.name, s))
        if best_score - s > (0.0 if margin is None else margin(cand, best)):
            best, best_score = cand, s
    return best, tried


def search_factors(shape: tuple[int, int, int]) -> tuple[int, int]:
    """(scan points summed per side, time bins per search bin) that bring an inverted grid
    ``shape`` [t, y, x] within LOBE_SEARCH_POINTS per side and LOBE_SEARCH_BINS bins: the
    fewest points per block that divide both sides, up to twice the fewest that would do
    (1: none summed, where none does), and the fewest bins per search bin (the
    preprocessing rebins the kept window to the rest)."""
    nt, ny, nx = (int(v) for v in shape)
    need = max(1, -(-max(ny, nx) // LOBE_SEARCH_POINTS))
    f = next((f for f in range(need, 2 * need + 1) if not (ny % f or nx % f)), 1)
    return f, max(1, -(-nt // LOBE_SEARCH_BINS))


def lobe_choice_note(params: dict) -> str:
    """One line: the lobe ``brdf = "auto"`` chose, every lobe's held-out score (whole volume
    / surface; lower is better), the grid they were reconstructed on and what choosing
    cost (the params :meth:`clnlos.inverse.pipeline.ReconstructionPipeline.brdf_lobe`
    recorded)."""
    whole = json.loads(params["brdf_tried"])
    surface = dict(json.loads(params.get("brdf_tried_surface", "[]")))
    scores = ", ".join(f"{name} {v:.4g}" + (f" / {surface[name]:.4g}" if name in surface
                                             else "") for name, v in whole)
    grid = params.get("brdf_search_grid", "").replace("x", " x ")
    cost = params.get("brdf_choice_s")
    return (f"brdf auto chose {params['brdf_chosen']} by held-out photons (scores, whole "
            f"volume / surface, lower better: {scores}; halves reconstructed on a "
            f"[t, y, x] = {grid} grid" + ("" if cost is None else f", {cost:.3g} s") + ")")
