"""Grouped held-out validation and its scores (pure numpy / scipy): the legibility judge's
splits (:mod:`clnlos.study.judge.model`).

Each split is a grouped cross-validation: the reconstructions are grouped by glyph, by
geometry (scan width, letter height and stroke, depth, slab thickness: :func:`geometry_key`)
or by material (the study's judge, :data:`SPLITS`), or by target kind, by rig (slab or
none, and the band of the scan width) or by material (the shipped judge,
:data:`BROAD_SPLITS`; the row keys :data:`SPLIT_KEYS`), whole groups are dealt into folds
(:func:`group_folds`), and every reconstruction is predicted by a model that saw no
reconstruction of its group. Reported per split, pooled over its folds (every
reconstruction tested once):

* balanced accuracy (the mean of the true-positive and true-negative rates; P(legible) >=
  1/2 is "legible"), ROC AUC (Mann-Whitney), the expected calibration error over ECE_BINS
  equal-width bins, ECE = sum_b n_b / n |mean(y)_b - mean(p)_b|, and the reliability diagram;
* the majority baseline: the training split's commonest class for every test sample (its
  accuracy; its balanced accuracy is 1/2 by definition);
* the one-feature baseline: each feature thresholded at the cut (and side) with the best
  balanced accuracy on the training split, the feature with the best one kept (chosen on the
  training split too), applied to the test split: its balanced accuracy.
"""

from __future__ import annotations

import json

import numpy as np
from scipy.stats import rankdata

from clnlos.physics.slab import CDT_SLAB

SPLITS = ("glyph", "geometry", "material")        # the study's judge (its glyph twins)
BROAD_SPLITS = ("kind", "rig", "material")        # the shipped judge (every kind of target)
# the row key that groups each split (a rig's group: the rig and the band of its scan width)
SPLIT_KEYS = {"glyph": "glyph", "geometry": "geometry", "kind": "kind", "rig": "rig_group",
              "material": "material"}
ECE_BINS = 10


def geometry_key(sample: dict) -> str:
    """A glyph sample's geometry: scan width, letter height and stroke, depth, slab."""
    return json.dumps([sample["scan_width_m"], sample["height_m"], sample["stroke_m"],
                       sample["depth_m"],
                       sample.get("slab_thickness_m", CDT_SLAB.thickness_m)])


def group_folds(groups, n_folds: int, seed: int = 0) -> np.ndarray:
    """Fold index of every sample: whole groups dealt into ``n_folds`` folds (at most one
    per group), largest first (ties in a seeded order), each to the fold with fewest
    samples."""
    groups = np.asarray(groups)
    names, counts = np.unique(groups, return_counts=True)
    n_folds = max(1, min(n_folds, len(names)))
    order = np.random.default_rng(seed).permutation(len(names))
    order = order[np.argsort(-counts[order], kind="stable")]
    size = np.zeros(n_folds, int)
    fold_of = {}
    for i in order:
        f = int(np.argmin(size))
        fold_of[names[i]] = f
        size[f] += counts[i]
    return np.array([fold_of[g] for g in groups], int)


def balanced_accuracy(y, pred) -> float:
    """Mean of the true-positive and true-negative rates (of the classes present)."""
    y, pred = np.asarray(y, bool), np.asarray(pred, bool)
    rates = [float((pred[y == c] == c).mean()) for c in (True, False) if (y == c).any()]
    return float(np.mean(rates)) if rates else float("nan")


def roc_auc(y, score) -> float:
    """Area under the ROC curve: P(score of a positive > score of a negative), ties 1/2
    (NaN without both classes)."""
    y = np.asarray(y, bool)
    n1, n0 = int(y.sum()), int((~y).sum())
    if not n1 or not n0:
        return float("nan")
    r = rankdata(np.asarray(score, np.float64))
    return float((r[y].sum() - n1 * (n1 + 1) / 2) / (n1 * n0))


def reliability(y, p, bins: int = ECE_BINS) -> dict:
    """Reliability diagram over equal-width bins of p: per bin its count, mean predicted
    probability and observed frequency (None in empty bins), and the ECE."""
    y, p = np.asarray(y, np.float64), np.asarray(p, np.float64)
    edges = np.linspace(0.0, 1.0, bins + 1)
    idx = np.clip(np.searchsorted(edges, p, side="right") - 1, 0, bins - 1)
    count, conf, freq, ece = [], [], [], 0.0
    for b in range(bins):
        sel = idx == b
        n = int(sel.sum())
        count.append(n)
        conf.append(float(p[sel].mean()) if n else None)
        freq.append(float(y[sel].mean()) if n else None)
        if n:
            ece += n / len(y) * abs(freq[-1] - conf[-1])
    return {"edges": edges.tolist(), "count": count, "confidence": conf, "frequency": freq,
            "ece": float(ece)}


def best_threshold(x, y) -> tuple[float, int, float]:
    """(cut, side, balanced accuracy) of the rule side * (x - cut) >= 0 -> positive with the
    best balanced accuracy on (x, y); cuts below, between and above the distinct values."""
    x, y = np.asarray(x, np.float64), np.asarray(y, bool)
    v, inv = np.unique(x, return_inverse=True)
    cuts = np.concatenate([[v[0] - 1.0], (v[1:] + v[:-1]) / 2, [v[-1] + 1.0]])
    pos = np.bincount(inv, weights=y, minlength=len(v))
    neg = np.bincount(inv, weights=~y, minlength=len(v))
    # cut k: x >= cuts[k] holds the values v[k:]
    pos_above = np.concatenate([np.cumsum(pos[::-1])[::-1], [0.0]])
    neg_above = np.concatenate([np.cumsum(neg[::-1])[::-1], [0.0]])
    n1, n0 = max(pos.sum(), 1.0), max(neg.sum(), 1.0)
    rates = [r for r, present in ((pos_above / n1, pos.sum()), (1 - neg_above / n0, neg.sum()))
             if present]
    up = np.mean(rates, axis=0)
    down = np.mean([1 - r for r in rates], axis=0)  # side -1: x <= cut is positive
    k_up, k_down = int(np.argmax(up)), int(np.argmax(down))
    if up[k_up] >= down[k_down]:
        return float(cuts[k_up]), 1, float(up[k_up])
    return float(cuts[k_down]), -1, float(down[k_down])


def one_feature_rule(features: dict[str, np.ndarray], y) -> dict | None:
    """The best single feature thresholded on (features, y): ``{"feature", "cut", "side",
    "train_balanced_accuracy"}`` (None without features)."""
    best = None
    for f, x in features.items():
        cut, side, ba = best_threshold(x, y)
        if best is None or ba > best["train_balanced_accuracy"]:
            best = {"feature": f, "cut": cut, "side": side, "train_balanced_accuracy": ba}
    return best


def apply_rule(rule: dict, features: dict[str, np.ndarray]) -> np.ndarray:
    return rule["side"] * (np.asarray(features[rule["feature"]], np.float64)
                           - rule["cut"]) >= 0
