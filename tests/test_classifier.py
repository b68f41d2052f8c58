"""The legibility judge's validation: its metrics against brute force, grouped folds that never
share a group, the study's reconstructions with ground truth taken once each, and the
binomial thinning of the real captures."""

import json

import numpy as np
import pytest

from clnlos.io.files import read_capture
from clnlos.study.judge.heldout import (
    SPLITS,
    balanced_accuracy,
    best_threshold,
    group_folds,
    reliability,
    roc_auc,
)
from clnlos.study.judge.study import study_volume_rows
from clnlos.study.real.thinning import THINNING_FRACTIONS, thinned_series, thinning_figure


def test_metrics_against_brute_force():
    rng = np.random.default_rng(1)
    y = rng.random(60) < 0.3
    s = np.round(rng.normal(y * 1.0, 1.0), 1)  # ties on purpose
    pairs = [(a, b) for a in s[y] for b in s[~y]]
    auc = np.mean([1.0 if a > b else 0.5 if a == b else 0.0 for a, b in pairs])
    assert roc_auc(y, s) == pytest.approx(auc)
    pred = s > 0.5
    tpr, tnr = pred[y].mean(), (~pred[~y]).mean()
    assert balanced_accuracy(y, pred) == pytest.approx((tpr + tnr) / 2)
    assert np.isnan(roc_auc(np.ones(4, bool), np.arange(4)))
    # the cut with the best balanced accuracy, found by trying every cut both ways
    cut, side, ba = best_threshold(s, y)
    brute = max(balanced_accuracy(y, sd * (s - c) >= 0)
                for c in np.concatenate([s - 1e-9, s + 1e-9]) for sd in (1, -1))
    assert ba == pytest.approx(brute) and balanced_accuracy(y, side * (s - cut) >= 0) == \
        pytest.approx(ba)


def test_reliability_and_ece():
    p = np.array([0.05, 0.05, 0.95, 0.95, 0.55, 0.55])
    y = np.array([0, 0, 1, 1, 1, 0], bool)
    rel = reliability(y, p)
    assert rel["ece"] == pytest.approx((2 * 0.05 + 2 * 0.05 + 2 * 0.05) / 6)
    assert sum(rel["count"]) == 6 and rel["count"][0] == 2 and rel["count"][9] == 2
    assert rel["frequency"][5] == pytest.approx(0.5) and rel["confidence"][1] is None
    # a perfectly calibrated predictor on many draws has a small ECE
    rng = np.random.default_rng(0)
    q = rng.random(20000)
    assert reliability(rng.random(20000) < q, q)["ece"] < 0.02


def test_group_folds_keep_groups_whole():
    rng = np.random.default_rng(2)
    groups = rng.choice(list("ABCDEFGHIJ"), 200, p=[0.3] + [0.7 / 9] * 9)
    folds = group_folds(groups, 4, seed=3)
    for g in np.unique(groups):
        assert len(set(folds[groups == g])) == 1
    sizes = np.bincount(folds)
    assert len(sizes) == 4 and sizes.min() > 0
    assert np.array_equal(folds, group_folds(groups, 4, seed=3))
    assert group_folds(np.array(["a", "a", "b"]), 5).max() == 1  # at most one per group


def _result(mip, identified, iou, box):
    return {"mip": mip, "identified": identified, "iou": iou, "iou_box_baseline": box}


def test_the_judges_volume_rows_take_every_reconstruction_with_ground_truth_once():
    img = np.zeros((8, 8), np.float32)
    img[2:6, 3] = 1
    s = {"text": "L", "material": "m1", "scan_width_m": 0.6, "height_m": 0.3,
         "stroke_m": 0.08, "depth_m": 0.5}
    pairs = [(s, _result(img, True, 0.7, 0.6)),
             (s, _result(img, True, 0.7, 0.6)),           # the same reconstruction twice
             ({**s, "method": "other"}, _result(img * 0.5, True, 0.5, 0.6)),  # another one
             ({**s, "text": "T", "slab_thickness_m": 0.0}, _result(img, False, 0.8, 0.6)),
             ({"object": "sphere"}, {"mip": img, "iou": 0.3})]  # no ground truth
    rows = study_volume_rows(pairs)
    assert len(rows) == 3
    assert [r["legible"] for r in rows] == [True, False, False]  # identified, IoU > box
    assert [r["glyph"] for r in rows] == ["L", "L", "T"]
    assert rows[0]["geometry"] == rows[1]["geometry"] != rows[2]["geometry"]
    assert json.loads(rows[2]["geometry"])[-1] == 0.0
    assert {r["material"] for r in rows} == {"m1"} and set(SPLITS) <= set(rows[0])


def test_thinning_is_nested_binomial():
    rng = np.random.default_rng(0)
    counts = rng.poisson(50.0, (40, 8, 8)).astype(np.float32)
    series = thinned_series(counts, THINNING_FRACTIONS, seed=7)
    assert np.array_equal(series[0], counts)
    for a, b, f in zip(series, series[1:], THINNING_FRACTIONS[1:], strict=False):
        assert np.all(b <= a) and np.all(b >= 0) and b.dtype == np.float32
        n, k = counts.sum(), b.sum()  # Binomial(total, f): within 5 standard deviations
        assert abs(k - f * n) <= 5 * np.sqrt(n * f * (1 - f)) + 1
    again = thinned_series(counts, THINNING_FRACTIONS, seed=7)
    assert all(np.array_equal(a, b) for a, b in zip(series, again, strict=True))
    for bad in ((1.0, 0.0), (0.1, 0.3), (1.5,)):
        with pytest.raises(ValueError):
            thinned_series(counts, bad)


def test_thinning_the_real_captures_and_the_figure(shared_data):
    cap = read_capture(shared_data / "cdt" / "letter_s.mat")
    series = thinned_series(cap.transient, (1.0, 0.01))
    total = float(cap.transient.sum())
    assert series[1].sum() == pytest.approx(0.01 * total, rel=5 / np.sqrt(0.01 * total))
    rows = [{"capture": c, "fraction": f, "photons": f * 1e7, "p_legible": p,
             "mip": np.random.default_rng(1).random((8, 8)).astype(np.float32)}
            for c, p0 in (("letter_s", 0.9), ("letters_ut", 0.95))
            for f, p in zip((1.0, 0.1, 0.01), (p0, p0 - 0.3, 0.1), strict=True)]
    fig = thinning_figure(rows)
    assert len(fig.axes) >= 7  # six MIPs, their colour bars, the curve
    curve = fig.axes[-1]
    assert curve.get_title() == "P(legible) against photons"
    assert list(curve.lines[0].get_ydata()) == pytest.approx([0.9, 0.6, 0.1])
    assert list(curve.lines[0].get_xdata()) == pytest.approx([1e7, 1e6, 1e5])


def test_report_names_the_largest_rise_of_p_as_photons_fall():
    from clnlos.study.report.classifier import _trend

    rows = [{"capture": "s", "photons": n, "p_legible": p}
            for n, p in ((1e7, 0.9), (1e6, 0.7), (1e5, 0.8), (1e4, 0.2))]
    assert _trend(rows, "s") == ("s: P(legible) 0.90 with all 1e+07 photons, 0.20 with "
                                 "1e+04; largest rise as photons fall +0.10.")


def test_report_says_when_the_classifier_is_no_verdict():
    """The report's sentences: a split below its one-feature baseline is named; real captures
    with P < 0.5 at all photons or a P that rises as photons fall are 'not a verdict'."""
    from clnlos.study.report.classifier import baseline_verdict, real_verdict

    good = {k: {"balanced_accuracy": 0.9, "baseline": 0.8} for k in ("glyph", "geometry",
                                                                      "material")}
    assert "beats" in baseline_verdict(good)
    bad = {**good, "geometry": {"balanced_accuracy": 0.6, "baseline": 0.8}}
    assert "by geometry" in baseline_verdict(bad) and "glyph" not in baseline_verdict(bad)

    def rows(ps):
        return [{"capture": "c", "photons": 10.0 ** (8 - k), "p_legible": p}
                for k, p in enumerate(ps)]
    assert real_verdict(rows([0.95, 0.9, 0.6, 0.2])).startswith("On every real capture")
    assert "below 0.5" in real_verdict(rows([0.3, 0.2, 0.1]))
    assert "rising" in real_verdict(rows([0.9, 0.7, 0.85, 0.1]))
