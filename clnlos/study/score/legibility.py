"""Legibility of a reconstruction: can the hidden glyph be told from the others, and does its
IoU beat that of a featureless blob? (pure numpy / scipy, no OpenCL)

Identification. The glyph set GLYPHS has K = 8 capital letters of one stroke font
(:data:`clnlos.forward.geometry.GLYPHS`) that share one footprint: every one spans the full
glyph box
(0.6 x 1 letter heights), so the box, the area and the centre of a blob do not tell them
apart. A reconstruction's max-intensity projection m [y, x] is matched to the closest of
the K templates

    g_k = G_sigma * c_k,        sigma = FWHM_lateral / (2 sqrt(2 ln 2)),

c_k the true coverage of glyph k on the scan grid and G_sigma a Gaussian of the measured
lateral resolution (what a perfect reconstruction at that resolution would show), by the
normalised cross-correlation (Pearson r over the scan cells), maximised over integer shifts
of up to ``max_shift`` cells (a reconstruction displaced by a cell is still legible). The
rule sees only the image and the K candidates, never which one is true; chance is 1/K.
Accuracy over n reconstructions comes with the Wilson 95% score interval (exact coverage
near 0 and 1, where a normal interval fails).

Box baseline. Beside every IoU: the IoU of the filled bounding box of the true mask (what a
blob of the right size and place scores: 0.64 for 'UT' at the seed geometry) and the excess
over it. An IoU below its baseline says the image holds no more shape than a rectangle.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy.ndimage import gaussian_filter
from scipy.special import ndtri  # the normal quantile (scipy.stats.norm.ppf computes it so)

from clnlos.forward.geometry import letters_mask

GLYPHS = ("E", "F", "H", "L", "P", "T", "U", "X")
COVERAGE_SUBSAMPLES = 4   # per scan cell and axis, for the true coverage of a glyph
FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))
MAX_SHIFT_CELLS = 1
LEGIBLE_ACCURACY = 0.9    # "legible": identification accuracy at least this


def glyph_coverage(glyph: str, height_m: float, stroke_m: float, centre_xy,
                   scan_centres: np.ndarray, mask=letters_mask) -> np.ndarray:
    """Covered fraction [y, x] of each scan cell (centres ``scan_centres``, m) by the glyph,
    letters of ``height_m`` with strokes of ``stroke_m`` centred at ``centre_xy`` (m);
    ``mask(glyph, height_m, stroke_m, xy)`` says which local points it covers (another
    pattern set: :func:`clnlos.study.score.patterns.pattern_mask`)."""
    c = np.asarray(scan_centres, float)
    pitch = float(c[1] - c[0]) if c.size > 1 else 1.0
    s = COVERAGE_SUBSAMPLES
    sub = ((np.arange(s) + 0.5) / s - 0.5) * pitch
    fine = (c[:, None] + sub[None, :]).ravel()
    Y, X = np.meshgrid(fine, fine, indexing="ij")
    pts = np.stack([X.ravel() - centre_xy[0], Y.ravel() - centre_xy[1]], axis=1)
    inside = mask(glyph, height_m, stroke_m, pts).reshape(c.size * s, c.size * s)
    return inside.reshape(c.size, s, c.size, s).mean(axis=(1, 3))


def glyph_templates(height_m: float, stroke_m: float, centre_xy, scan_centres: np.ndarray,
                    lateral_fwhm_m: float, glyphs=GLYPHS,
                    mask=letters_mask) -> dict[str, np.ndarray]:
    """Template g_k [y, x] of every glyph: its coverage blurred to the lateral resolution."""
    c = np.asarray(scan_centres, float)
    pitch = float(c[1] - c[0])
    sigma_cells = max(float(lateral_fwhm_m), 0.0) / FWHM_PER_SIGMA / pitch
    return {g: gaussian_filter(glyph_coverage(g, height_m, stroke_m, centre_xy, c, mask),
                               sigma_cells, mode="constant")
            for g in glyphs}


def ncc_map(mip: np.ndarray, template: np.ndarray, max_shift: int) -> np.ndarray:
    """Pearson r of the template with the MIP shifted by (dy, dx) (zero fill), for every
    shift in [-max_shift, max_shift]^2 (array [2 S + 1, 2 S + 1], index S the unshifted),
    from three cross-correlations: sum(m_s t), sum(m_s) and sum(m_s^2) over the frame."""
    m = np.asarray(mip, np.float64)
    t = np.asarray(template, np.float64)
    n = m.size
    S = int(max_shift)
    ny, nx = m.shape
    # shifted[i, j] = m[v + (i - S, j - S)] (zero fill): the MIP moved by -(i - S, j - S);
    # flipped so that index S + d holds the shift d of the docstring
    shifted = sliding_window_view(np.pad(m, S), (ny, nx))[::-1, ::-1]
    c = np.einsum("ijyx,yx->ij", shifted, t)
    s1 = shifted.sum(axis=(2, 3))
    s2 = np.einsum("ijyx,ijyx->ij", shifted, shifted)
    tc = t - t.mean()
    tt = float((tc * tc).sum())
    var = np.maximum(s2 - s1 * s1 / n, 0.0) * tt
    num = c - s1 * t.mean()
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.where(var > 0, num / np.sqrt(np.where(var > 0, var, 1.0)), 0.0)
    return r


def match_scores(mip: np.ndarray, templates: dict[str, np.ndarray],
                 max_shift: int = MAX_SHIFT_CELLS) -> dict[str, float]:
    """Normalised cross-correlation of the MIP with each template, best over shifts of up to
    ``max_shift`` cells in x and y."""
    return {g: float(ncc_map(mip, t, max_shift).max()) for g, t in templates.items()}


def best_shift(mip: np.ndarray, template: np.ndarray, max_shift: int) -> tuple[int, int]:
    """(dy, dx) cells by which the MIP's glyph sits off the template's place: the shift of the
    best match (the MIP shifted by -(dy, dx) fits the template best)."""
    r = ncc_map(mip, template, max_shift)
    iy, ix = np.unravel_index(int(np.argmax(r)), r.shape)
    return -(int(iy) - max_shift), -(int(ix) - max_shift)


def identify(mip: np.ndarray, templates: dict[str, np.ndarray],
             max_shift: int = MAX_SHIFT_CELLS) -> tuple[str, float, dict[str, float]]:
    """(the closest glyph, its margin over the runner-up in NCC, every glyph's NCC)."""
    scores = match_scores(mip, templates, max_shift)
    ranked = sorted(scores, key=scores.get, reverse=True)
    margin = scores[ranked[0]] - (scores[ranked[1]] if len(ranked) > 1 else -1.0)
    return ranked[0], float(margin), scores


def detail(img: np.ndarray, sigma_cells: float) -> np.ndarray:
    """The image less its Gaussian blur of ``sigma_cells`` (rms): the strokes and edges a
    blob lacks (float64)."""
    img = np.asarray(img, np.float64)
    return img - gaussian_filter(img, sigma_cells)


def wilson_interval(k: int, n: int, level: float = 0.95) -> list[float]:
    """Wilson score interval [lo, hi] of a proportion k / n."""
    if n <= 0:
        return [float("nan"), float("nan")]
    z = float(ndtri(0.5 + level / 2))
    p = k / n
    d = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / d
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    # the interval holds p itself (rounding could put an end a hair past it at k = 0 or n)
    return [max(0.0, min(p, centre - half)), min(1.0, max(p, centre + half))]


def identification_summary(hits, chance: float) -> dict:
    """``{"accuracy", "ci", "chance", "n"}`` of a sequence of identified / not."""
    h = np.asarray(list(hits), bool)
    n = int(h.size)
    k = int(h.sum())
    return {"accuracy": k / n if n else float("nan"), "ci": wilson_interval(k, n),
            "chance": float(chance), "n": n}


def box_baseline_iou(truth: np.ndarray) -> float:
    """IoU of the filled bounding box of the true mask [y, x] with the mask itself."""
    t = np.asarray(truth, bool)
    if not t.any():
        return 0.0
    ys, xs = np.nonzero(t)
    box = np.zeros_like(t)
    box[ys.min():ys.max() + 1, xs.min():xs.max() + 1] = True
    return float(t.sum() / box.sum())

