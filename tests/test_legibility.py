"""Legibility metrics of the study: glyph identification (a blob must fail it), the box
baseline beside IoU, the Wilson interval."""

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter
from scipy.stats import binomtest

from clnlos.study.score.legibility import (
    GLYPHS,
    box_baseline_iou,
    glyph_coverage,
    glyph_templates,
    identification_summary,
    identify,
    wilson_interval,
)
from clnlos.study.score.metrics import iou, letters_truth_mask


def _centres(n, width):
    return (np.arange(n) + 0.5) / n * width - width / 2


def test_glyphs_share_one_footprint():
    """Every glyph spans the same box: position, size and area cannot tell them apart."""
    c = _centres(32, 0.6)
    boxes = set()
    for g in GLYPHS:
        cov = glyph_coverage(g, 0.3, 0.08, (0.0, 0.0), c) >= 0.5
        ys, xs = np.nonzero(cov)
        boxes.add((ys.min(), ys.max(), xs.min(), xs.max()))
    assert len(GLYPHS) >= 8 and len(boxes) == 1


def test_box_baseline_of_ut_at_the_seed_geometry():
    """The issue's number: a filled rectangle over 'UT' scores IoU 0.64 at 32 x 32 / 0.3 m."""
    truth = letters_truth_mask("UT", 0.15, 0.04, (0.0, 0.0), _centres(32, 0.3))
    assert box_baseline_iou(truth) == pytest.approx(0.64, abs=0.01)
    ys, xs = np.nonzero(truth)
    box = np.zeros_like(truth)
    box[ys.min():ys.max() + 1, xs.min():xs.max() + 1] = True
    assert iou(box, truth) == pytest.approx(box_baseline_iou(truth))


@pytest.mark.parametrize("fwhm", [0.03, 0.06])
def test_blurred_glyphs_are_identified_and_blobs_are_not(fwhm):
    """A glyph blurred to the resolution (plus noise) is matched to itself; the glyph's
    filled box, or the glyph blurred far past the resolution (a blob), is matched to one
    glyph whatever the truth, so over the K glyphs it scores 1/K."""
    rng = np.random.default_rng(0)
    c = _centres(32, 0.6)
    pitch = c[1] - c[0]
    tpl = glyph_templates(0.3, 0.08, (0.0, 0.0), c, fwhm)
    sigma = fwhm / 2.3548 / pitch
    hits_sharp, blob_answers = 0, set()
    for g in GLYPHS:
        cov = glyph_coverage(g, 0.3, 0.08, (0.0, 0.0), c)
        img = gaussian_filter(cov, sigma, mode="constant") + 0.05 * rng.standard_normal(cov.shape)
        hits_sharp += identify(img, tpl)[0] == g
        blob = gaussian_filter(cov, 6.0 * sigma + 3.0, mode="constant")
        blob_answers.add(identify(blob, tpl)[0])
    assert hits_sharp == len(GLYPHS)
    assert len(blob_answers) <= 2  # a blob's answer does not follow the glyph


def test_identification_tolerates_a_one_cell_shift():
    c = _centres(32, 0.6)
    tpl = glyph_templates(0.3, 0.08, (0.0, 0.0), c, 0.04)
    img = np.roll(tpl["P"], 1, axis=1)
    assert identify(img, tpl)[0] == "P"


@pytest.mark.parametrize("level", [0.9, 0.95, 0.99])
def test_wilson_interval_is_scipys(level):
    """The hand-written interval (no scipy.stats import on the CLI's start) equals
    scipy.stats.binomtest(k, n).proportion_ci(method="wilson") on every k of small and large
    n (scipy's is the reference; the ends are clipped to [0, 1] as there)."""
    for n in (1, 2, 7, 8, 16, 20, 80, 1000):
        for k in sorted({0, 1, n // 3, n // 2, n - 1, n}):
            ref = binomtest(k, n).proportion_ci(level, method="wilson")
            lo, hi = wilson_interval(k, n, level)
            assert lo == pytest.approx(ref.low, abs=1e-12), (k, n)
            assert hi == pytest.approx(ref.high, abs=1e-12), (k, n)


def test_wilson_interval_covers_like_the_exact_one():
    lo, hi = wilson_interval(8, 8)
    assert hi == 1.0 and 0.6 < lo < 0.7  # 0.676 for 8/8
    lo, hi = wilson_interval(0, 16)
    assert lo == 0.0 and 0.15 < hi < 0.25
    exact = binomtest(7, 20).proportion_ci(0.95, method="exact")
    lo, hi = wilson_interval(7, 20)
    assert abs(lo - exact.low) < 0.05 and abs(hi - exact.high) < 0.05
    s = identification_summary([True] * 15 + [False], 1 / 8)
    assert s["accuracy"] == pytest.approx(15 / 16) and s["n"] == 16 and s["chance"] == 0.125
