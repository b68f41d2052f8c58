"""Held-out validation of the legibility classifier (:mod:`clnlos.study.classify`).

What it learns from (:func:`legibility_set`): every glyph reconstruction the study makes that
has ground truth (a result with ``identified``, whatever part of the study planned it and
whatever method reconstructed it), once per distinct reconstruction; the label ``legible``
(identified by the template rule and IoU above the box baseline); the IoU over the box
baseline for the second head.

Three splits, each a grouped cross-validation: the reconstructions are grouped by glyph, by
geometry (scan width, letter height and stroke, depth, slab thickness) or by material, whole
groups are dealt into SPLIT_FOLDS folds, and every reconstruction is predicted by a network
that saw no reconstruction of its group (trained on the other folds, whose share of legible
reconstructions is its prior). Reported per split, pooled over its folds (every
reconstruction tested once):

* balanced accuracy (the mean of the true-positive and true-negative rates; P(legible) >=
  1/2 is "legible"), ROC AUC (Mann-Whitney), the expected calibration error over ECE_BINS
  equal-width bins, ECE = sum_b n_b / n |mean(y)_b - mean(p)_b|, and the reliability diagram;
* the majority baseline: the training split's commonest class for every test sample (its
  accuracy; its balanced accuracy is 1/2 by definition);
* the one-feature baseline: each of BASELINE_FEATURES thresholded at the cut (and side) with
  the best balanced accuracy on the training split, the feature with the best one kept
  (chosen on the training split too), applied to the test split: its balanced accuracy.

The classifier the study applies (real captures, the material table) is the ensemble of all
the folds' networks (:class:`clnlos.study.classify.LegibilityEnsemble`): no network is
trained for it alone. The folds train in worker processes (one thread each) when more than
one is asked for; a fold's network depends on its seed and data only.
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np
from scipy.stats import rankdata

from clnlos.physics.slab import CDT_SLAB
from clnlos.study.classify import (
    LEGIBILITY_EPOCHS,
    LegibilityClassifier,
    LegibilityEnsemble,
    fit_legibility_state,
)

SPLITS = ("glyph", "geometry", "material")
SPLIT_FOLDS = {"glyph": 4, "geometry": 4, "material": 5}
ECE_BINS = 10
# the NCC margin of the closest template over the runner-up (the template rule's own
# confidence, no truth needed) and the no-reference metrics (clnlos.study.quality)
BASELINE_FEATURES = ("margin", "q_nr_clarity", "q_otsu_separability", "q_central_energy",
                     "q_depth_coherence", "q_fft_clarity")


@dataclass
class LegibilitySet:
    """The classifier's data: MIPs [n, y, x], labels, the second head's target, the
    baseline features and each sample's group under every split."""

    images: np.ndarray
    legible: np.ndarray
    iou_excess: np.ndarray
    features: dict[str, np.ndarray]
    groups: dict[str, np.ndarray]

    def __len__(self) -> int:
        return len(self.legible)


def geometry_key(sample: dict) -> str:
    """A glyph sample's geometry: scan width, letter height and stroke, depth, slab."""
    return json.dumps([sample["scan_width_m"], sample["height_m"], sample["stroke_m"],
                       sample["depth_m"],
                       sample.get("slab_thickness_m", CDT_SLAB.thickness_m)])


def legibility_set(pairs) -> LegibilitySet:
    """The data of every (sample, result) pair whose result has ground truth
    (``identified``), each distinct reconstruction (sample and MIP) once."""
    seen, rows = set(), []
    for sample, r in pairs:
        if "identified" not in r:
            continue
        mip = np.asarray(r["mip"], np.float32)
        key = (json.dumps(sample, sort_keys=True), hashlib.sha1(mip.tobytes()).hexdigest())
        if key not in seen:
            seen.add(key)
            rows.append((sample, r, mip))
    n = len(rows)
    excess = np.array([r["iou"] - r["iou_box_baseline"] for _, r, _ in rows], np.float64)
    return LegibilitySet(
        images=np.stack([m for *_, m in rows]) if n else np.zeros((0, 1, 1), np.float32),
        legible=np.array([bool(r["identified"]) for _, r, _ in rows], bool) & (excess > 0),
        iou_excess=excess,
        features={f: np.array([r[f] for _, r, _ in rows], np.float64)
                  for f in BASELINE_FEATURES if all(f in r for _, r, _ in rows)},
        groups={"glyph": np.array([s["text"] for s, *_ in rows]),
                "geometry": np.array([geometry_key(s) for s, *_ in rows]),
                "material": np.array([s["material"] for s, *_ in rows])})


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


def split_scores(y, p, baseline_pred, majority_pred) -> dict:
    """results.json ``classifier.splits.<name>`` (the contract) from pooled out-of-fold
    predictions: P(legible) ``p`` and the one-feature and majority baselines' decisions."""
    y = np.asarray(y, bool)
    return {"balanced_accuracy": balanced_accuracy(y, np.asarray(p) >= 0.5),
            "auc": roc_auc(y, p), "ece": reliability(y, p)["ece"],
            "majority": float((np.asarray(majority_pred, bool) == y).mean()),
            "baseline": balanced_accuracy(y, baseline_pred)}


def fold_plan(data: LegibilitySet, seed: int = 0) -> list[dict]:
    """Every (split, fold): ``{"split", "fold", "test"}`` (a mask), in SPLITS order."""
    out = []
    for name in SPLITS:
        folds = group_folds(data.groups[name], SPLIT_FOLDS[name], seed)
        out += [{"split": name, "fold": int(f), "test": folds == f}
                for f in range(int(folds.max()) + 1 if len(folds) else 0)]
    return out


def _train(data: LegibilitySet, plan: list[dict], epochs: int, seed: int, workers: int,
           progress=None) -> list[dict]:
    """The states of the folds' networks (:func:`clnlos.study.classify.
    fit_legibility_state`), in worker processes when ``workers`` > 1."""
    jobs = [(data.images[~f["test"]], data.legible[~f["test"]], data.iou_excess[~f["test"]],
             epochs, seed * 1000 + k) for k, f in enumerate(plan)]
    if workers <= 1 or len(jobs) <= 1:
        out = []
        for job in jobs:
            out.append(fit_legibility_state(*job))
            if progress is not None:
                progress(len(out), len(jobs))
        return out
    ctx = multiprocessing.get_context("spawn")  # no fork of a process holding OpenCL
    with ProcessPoolExecutor(min(workers, len(jobs)), mp_context=ctx) as pool:
        futures = [pool.submit(fit_legibility_state, *job) for job in jobs]
        out = []
        for fut in futures:
            out.append(fut.result())
            if progress is not None:
                progress(len(out), len(jobs))
        return out


def validate_legibility(data: LegibilitySet, *, epochs: int = LEGIBILITY_EPOCHS,
                        seed: int = 0, workers: int = 1, progress=None
                        ) -> tuple[LegibilityEnsemble, dict, dict]:
    """Train and test the folds of every split (module docstring). Returns (the ensemble of
    the folds' networks, results.json ``classifier.splits`` (the contract), details per
    split: ``n``, ``legible``, the CNN's plain ``accuracy``, ``reliability``, the baseline's
    ``baseline_features`` (per fold), ``balanced_accuracy_even_odds`` (the decision z >= 0,
    P(legible) at even prior odds: what the training prior costs on a split whose test
    groups have another share of legible reconstructions) and the ``folds``' groups and
    scores). ``progress(done, total)`` is called after each fold's network."""
    plan = fold_plan(data, seed)
    states = _train(data, plan, epochs, seed, workers, progress)
    members = [LegibilityClassifier.from_state(s) for s in states]
    y, n = data.legible, len(data)
    splits, details = {}, {}
    for name in SPLITS:
        p, z, base, majority = np.zeros(n), np.zeros(n), np.zeros(n, bool), np.zeros(n, bool)
        folds = []
        for f, member, state in zip(plan, members, states, strict=True):
            if f["split"] != name:
                continue
            te = f["test"]
            z[te] = member.logits(data.images[te])
            p[te] = 1.0 / (1.0 + np.exp(-(z[te] + member.log_odds)))
            rule = one_feature_rule({k: v[~te] for k, v in data.features.items()}, y[~te])
            if rule is not None:
                base[te] = apply_rule(rule, {k: v[te] for k, v in data.features.items()})
            majority[te] = y[~te].mean() >= 0.5
            folds.append({"groups": sorted(str(g) for g in np.unique(data.groups[name][te])),
                          "n_test": int(te.sum()), "legible_test": int(y[te].sum()),
                          "balanced_accuracy": balanced_accuracy(y[te], p[te] >= 0.5),
                          "auc": roc_auc(y[te], p[te]),
                          "baseline_feature": None if rule is None else rule["feature"],
                          "train_loss": state["log"]["train_loss"][-1]})
        splits[name] = split_scores(y, p, base, majority)
        details[name] = {"n": int(n), "legible": int(y.sum()),
                         "accuracy": float(((p >= 0.5) == y).mean()) if n else float("nan"),
                         "reliability": reliability(y, p),
                         "balanced_accuracy_even_odds": balanced_accuracy(y, z >= 0),
                         "baseline_features": [f["baseline_feature"] for f in folds],
                         "folds": folds}
    return LegibilityEnsemble(members), splits, details
