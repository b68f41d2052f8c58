"""The legibility judge: P(legible) of a capture or a reconstruction from measured, scale- and
position-invariant features (:mod:`clnlos.study.judge.features`), a calibrated logistic
regression trained on the simulated twins of the real capture families
(:mod:`clnlos.study.judge.twins`). Pure numpy: no torch to train it or to apply it.

Two models, one per input:

* ``capture``: a photon-count capture, reconstructed with the judge's recipe (the method and
  SNR rule it was trained with, :data:`clnlos.study.judge.twins.JUDGE_METHOD`) together with two
  binomial halves of its photons; features :data:`~clnlos.study.judge.features.
  CAPTURE_FEATURES` (the MIP's and the halves' agreement);
* ``volume``: a reconstruction of any method, grid or size: the MIP's features only
  (:data:`~clnlos.study.judge.features.MIP_FEATURES`).

The model. Features x standardised by the training set's mean and deviation, z, then

    P(legible) = sigmoid(w . z + b),

(w, b) maximising the class-balanced log likelihood minus JUDGE_L2 |w|^2 / 2 (Newton's
method), and the intercept then shifted by the training set's log-odds of legible (what
undoes the balancing; :func:`prior_log_odds`) -- or not, for a judge at *even odds*
(``even_odds``: the shipped one, whose twins' share of legible rungs is set by how many
rungs of each ladder lie above the cut, not by anything of a user's capture; restored,
that share moved every verdict towards the twins' majority, and held out by kind the
model fell below its one-feature baseline: 0.937 against 0.948, at even odds 0.958).

What it knows (:mod:`clnlos.study.judge.domain`): each model keeps the training domain of
its features (and, for the capture model, of the captures' descriptors) and its *spread
models*: bootstrap refits on the training rows resampled by scene and the models of every
held-out fold; :meth:`Judge.assess` gives P with its interval and one note per way an input
lies outside the domain.

Saved as JSON (:data:`JUDGE_FILE` beside the study's results.json; the shipped judge:
:mod:`clnlos.study.judge.shipped`): the feature names, the scaler, the weights, the prior,
the reconstruction recipe, the spread models and the domain, read back by
:func:`load_judge` (``clnlos legibility FILE... [--model STUDY_DIR]``,
:func:`clnlos.study.judge.apply.legibility`). A judge of the first format (no spread, no
domain) still loads; it gives no interval.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from clnlos.study.judge.domain import (
    descriptor_domain,
    descriptor_notes,
    feature_domain,
    feature_notes,
    interval,
)
from clnlos.study.judge.heldout import (
    SPLIT_KEYS,
    SPLITS,
    apply_rule,
    balanced_accuracy,
    group_folds,
    one_feature_rule,
    reliability,
    roc_auc,
)
from clnlos.study.judge.features import (
    CAPTURE_FEATURES,
    MIP_FEATURES,
    capture_features,
    feature_matrix,
    mip_features,
    mip_of,
    pooled,
)

JUDGE_FILE = "judge.json"
JUDGE_FORMAT = "clnlos-legibility-judge/2"
READABLE_FORMATS = ("clnlos-legibility-judge/1", JUDGE_FORMAT)
JUDGE_L2 = 1.0           # the weights' Gaussian prior: penalty JUDGE_L2 |w|^2 / 2
NEWTON_STEPS = 50
JUDGE_FOLDS = {"glyph": 4, "geometry": 5, "material": 3, "kind": 7, "rig": 5}
MODELS = ("capture", "volume")


def prior_log_odds(y) -> float:
    """log(pi / (1 - pi)) of the share pi of positives in ``y``, pi kept within
    [1/(n+2), (n+1)/(n+2)] (Laplace's rule: finite for a split of one class)."""
    y = np.asarray(y, bool)
    pi = (y.sum() + 1) / (len(y) + 2)
    return float(np.log(pi / (1 - pi)))


def class_balanced_weights(y) -> np.ndarray:
    """Per-sample weights n / (2 n_class): both classes weigh half of the likelihood."""
    y = np.asarray(y, bool)
    n, pos = len(y), int(y.sum())
    return np.where(y, n / (2 * pos) if pos else 0.0, n / (2 * (n - pos)) if n > pos else 0.0)


def fit_logistic(X: np.ndarray, y, weights, l2: float = JUDGE_L2,
                 steps: int = NEWTON_STEPS) -> tuple[np.ndarray, float]:
    """(w, b) maximising sum_i weights_i log p(y_i | X_i) - l2 |w|^2 / 2 (Newton)."""
    y = np.asarray(y, np.float64)
    s = np.asarray(weights, np.float64)
    A = np.concatenate([X, np.ones((len(X), 1))], axis=1)
    theta = np.zeros(A.shape[1])
    reg = np.full(A.shape[1], l2)
    reg[-1] = 0.0
    for _ in range(steps):
        p = 1.0 / (1.0 + np.exp(-np.clip(A @ theta, -30, 30)))
        g = A.T @ (s * (p - y)) + reg * theta
        H = (A * (s * p * (1 - p))[:, None]).T @ A + np.diag(reg + 1e-9)
        step = np.linalg.solve(H, g)
        theta -= step
        if float(np.abs(step).max()) < 1e-8:
            break
    return theta[:-1], float(theta[-1])


@dataclass
class JudgeModel:
    """One logistic model over named features (module docstring)."""

    features: tuple[str, ...]
    mean: np.ndarray
    scale: np.ndarray
    weights: np.ndarray
    bias: float
    log_odds: float

    @classmethod
    def fit(cls, X: np.ndarray, y, features, l2: float = JUDGE_L2,
            even_odds: bool = False) -> JudgeModel:
        X = np.asarray(X, np.float64)
        mean, scale = X.mean(axis=0), X.std(axis=0)
        scale = np.where(scale > 0, scale, 1.0)
        w, b = fit_logistic((X - mean) / scale, y, class_balanced_weights(y), l2)
        return cls(tuple(features), mean, scale, w, b,
                   0.0 if even_odds else prior_log_odds(y))

    def logit(self, X: np.ndarray) -> np.ndarray:
        z = (np.asarray(X, np.float64).reshape(-1, len(self.features)) - self.mean) / self.scale
        return z @ self.weights + self.bias + self.log_odds

    def predict_proba(self, X: np.ndarray) -> np.ndarray:
        return 1.0 / (1.0 + np.exp(-np.clip(self.logit(X), -30, 30)))

    def state(self) -> dict:
        return {"features": list(self.features), "mean": self.mean.tolist(),
                "scale": self.scale.tolist(), "weights": self.weights.tolist(),
                "bias": self.bias, "log_odds": self.log_odds,
                "model": "sigmoid(w . (x - mean) / scale + bias + log_odds)"}

    @classmethod
    def from_state(cls, s: dict) -> JudgeModel:
        return cls(tuple(s["features"]), np.asarray(s["mean"], float),
                   np.asarray(s["scale"], float), np.asarray(s["weights"], float),
                   float(s["bias"]), float(s["log_odds"]))


@dataclass
class Assessment:
    """P(legible) of one input by one model, its interval [lo, hi] (None where the judge
    keeps no spread models) and the notes of what lies outside the judge's domain."""

    p: float
    interval: list[float] | None
    notes: list[str]

    @property
    def outside(self) -> bool:
        return bool(self.notes)


@dataclass
class Judge:
    """The two models and how the capture model's reconstructions are made; per model
    (``capture``, ``volume``) its ``spread`` models (``{"bootstrap": [...], "held_out":
    [...]}``) and its ``domain`` (``{"features": ..., "descriptors": ...}``)."""

    capture: JudgeModel
    volume: JudgeModel
    recipe: dict
    info: dict = field(default_factory=dict)
    spread: dict = field(default_factory=dict)
    domain: dict = field(default_factory=dict)

    def model(self, name: str) -> JudgeModel:
        return self.capture if name == "capture" else self.volume

    def volume_proba(self, volumes) -> np.ndarray:
        """P(legible) of each volume [z, y, x] or MIP [y, x] (the MIP-only model, the MIP
        averaged to at most POOLED_POINTS a side: :func:`clnlos.study.judge.features.pooled`)."""
        rows = [mip_features(pooled(mip_of(v))) for v in volumes]
        return self.volume.predict_proba(feature_matrix(rows, self.volume.features))

    def predict_proba(self, images) -> np.ndarray:
        """P(legible) of MIPs [n, y, x] (the study's classifier interface)."""
        return self.volume_proba(list(np.asarray(images)))

    def capture_proba(self, full, half1, half2) -> float:
        """P(legible) of a capture from its reconstruction and its halves' (the recipe's)."""
        f = capture_features(full, half1, half2)
        return float(self.capture.predict_proba(feature_matrix([f], self.capture.features))[0])

    def assess(self, name: str, features: dict, descriptors: dict | None = None
               ) -> Assessment:
        """P of the ``name`` model ("capture" or "volume") from its ``features``, its
        interval and the notes of what lies outside its domain (``descriptors``: of a
        capture, :data:`clnlos.study.judge.domain.DESCRIPTORS`)."""
        m = self.model(name)
        x = feature_matrix([features], m.features)[0]
        dom = self.domain.get(name, {})
        notes = descriptor_notes(descriptors or {}, dom.get("descriptors", {}))
        if "features" in dom:
            notes += feature_notes(x, dom["features"])
        spread = self.spread.get(name, {})
        return Assessment(float(m.predict_proba(x)[0]),
                          interval(x, spread.get("bootstrap", []), spread.get("held_out", []),
                                   dom.get("features"), bool(notes)), notes)

    def to_json(self) -> dict:
        out = {"format": JUDGE_FORMAT, "capture": self.capture.state(),
               "volume": self.volume.state(), "recipe": self.recipe, **self.info}
        if self.spread:
            out["spread"] = {k: {kind: [m.state() for m in ms] for kind, ms in v.items()}
                             for k, v in self.spread.items()}
        if self.domain:
            out["domain"] = self.domain
        return out

    @classmethod
    def from_json(cls, d: dict) -> Judge:
        info = {k: v for k, v in d.items() if k not in ("format", "capture", "volume",
                                                        "recipe", "spread", "domain")}
        spread = {k: {kind: [JudgeModel.from_state(m) for m in ms] for kind, ms in v.items()}
                  for k, v in d.get("spread", {}).items()}
        return cls(JudgeModel.from_state(d["capture"]), JudgeModel.from_state(d["volume"]),
                   dict(d["recipe"]), info, spread, dict(d.get("domain", {})))


def load_judge(path) -> Judge:
    """The judge saved at ``path`` (a judge.json, or a study folder holding one)."""
    p = Path(path)
    if p.is_dir():
        p = p / JUDGE_FILE
    d = json.loads(p.read_text())
    if d.get("format") not in READABLE_FORMATS:
        raise ValueError(f"{p}: not a legibility judge ({JUDGE_FORMAT})")
    return Judge.from_json(d)


# ------------------------------------------------------------------ held-out validation
def grouped_validation(X: np.ndarray, y, groups: dict[str, np.ndarray], features,
                       splits=SPLITS, folds=None, seed: int = 0,
                       models: list | None = None, l2: float = JUDGE_L2,
                       even_odds: bool = False) -> tuple[dict, dict]:
    """Grouped cross-validation of the model on (X, y) per split (whole groups held out),
    beside the one-feature baseline (each feature thresholded at its best cut on the
    training folds, the best kept) and the majority class; a split of one group is left
    out; every fold's model is appended to ``models`` where given. Returns (results.json
    ``classifier.splits``: balanced_accuracy, auc, ece, majority, baseline per split; details:
    n, legible, reliability, the baseline's features, per-fold scores)."""
    folds = dict(JUDGE_FOLDS if folds is None else folds)
    y = np.asarray(y, bool)
    n = len(y)
    feats = {f: X[:, k] for k, f in enumerate(features)}
    out, details = {}, {}
    for name in splits:
        if len(np.unique(groups[name])) < 2:  # nothing to hold out
            continue
        fold = group_folds(groups[name], folds.get(name, 4), seed)
        p, base, major = np.zeros(n), np.zeros(n, bool), np.zeros(n, bool)
        per = []
        for f in range(int(fold.max()) + 1 if n else 0):
            te = fold == f
            model = JudgeModel.fit(X[~te], y[~te], features, l2, even_odds)
            if models is not None:
                models.append(model)
            p[te] = model.predict_proba(X[te])
            rule = one_feature_rule({k: v[~te] for k, v in feats.items()}, y[~te])
            base[te] = apply_rule(rule, {k: v[te] for k, v in feats.items()})
            major[te] = y[~te].mean() >= 0.5
            per.append({"groups": sorted(str(g) for g in np.unique(groups[name][te])),
                        "n_test": int(te.sum()), "legible_test": int(y[te].sum()),
                        "balanced_accuracy": balanced_accuracy(y[te], p[te] >= 0.5),
                        "auc": roc_auc(y[te], p[te]), "baseline_feature": rule["feature"]})
        rel = reliability(y, p)
        out[name] = {"balanced_accuracy": balanced_accuracy(y, p >= 0.5), "auc": roc_auc(y, p),
                     "ece": rel["ece"], "majority": float((major == y).mean()),
                     "baseline": balanced_accuracy(y, base)}
        details[name] = {"n": int(n), "legible": int(y.sum()),
                         "accuracy": float(((p >= 0.5) == y).mean()), "reliability": rel,
                         "baseline_features": [f["baseline_feature"] for f in per],
                         "balanced_accuracy_even_odds": balanced_accuracy(y, p >= 0.5),
                         "folds": per}
    return out, details


def twin_arrays(rows: list[dict], features, splits=SPLITS) -> tuple[np.ndarray, np.ndarray,
                                                                    dict]:
    """(X, y, groups) of twin rows (:func:`clnlos.study.judge.twins.render_twin`; the groups
    of each split by its row key, :data:`clnlos.study.judge.heldout.SPLIT_KEYS`)."""
    X = feature_matrix([r["features"] for r in rows], features)
    y = np.array([bool(r["legible"]) for r in rows], bool)
    groups = {k: np.array([r[SPLIT_KEYS[k]] for r in rows]) for k in splits}
    return X, y, groups


def bootstrap_models(X: np.ndarray, y, clusters, features, n: int, seed: int = 0,
                     l2: float = JUDGE_L2, even_odds: bool = False) -> list[JudgeModel]:
    """``n`` models fitted on the rows resampled with replacement by cluster (a twin's
    rungs together: they share its target)."""
    clusters = np.asarray(clusters)
    names = np.unique(clusters)
    index = {c: np.flatnonzero(clusters == c) for c in names}
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        take = np.concatenate([index[c] for c in rng.choice(names, len(names))])
        out.append(JudgeModel.fit(X[take], np.asarray(y)[take], features, l2, even_odds))
    return out


def decided(rows) -> list[dict]:
    """The rows whose label is decided (not None: :func:`clnlos.study.judge.twins.
    shape_label`)."""
    return [r for r in rows if r.get("legible") is not None]


def train_judge(rows: list[dict], recipe: dict, volume_rows: list[dict] = (),
                seed: int = 0, splits=SPLITS, bootstrap: int = 0, l2: float = JUDGE_L2,
                capture_features=CAPTURE_FEATURES, volume_features=MIP_FEATURES,
                even_odds: bool = False) -> tuple[Judge, dict]:
    """The judge from twin rows (rows marked ``volume_only`` -- the rungs' default
    reconstructions -- and, for the volume model, extra rows of MIP features with labels and
    groups: the study's own reconstructions of every inversion), validated held out by
    ``splits``; with ``bootstrap`` > 0 also its spread models (that many bootstrap refits
    by scene, row key ``scene``, and every held-out fold's model) and its domain; ``l2`` the
    weights' prior (:func:`fit_logistic`), the models' features and whether they answer at
    even odds (:meth:`JudgeModel.fit`). Returns (the judge trained on all of it,
    ``{"capture": (splits, details), "volume": (...)}``)."""
    both = decided(rows) + decided(volume_rows)
    rows = [r for r in decided(rows) if not r.get("volume_only")]
    fit = {"l2": l2, "even_odds": even_odds}
    Xc, yc, gc = twin_arrays(rows, capture_features, splits)
    Xv, yv, gv = twin_arrays(both, volume_features, splits)
    held = {"capture": [], "volume": []}
    validation = {"capture": grouped_validation(Xc, yc, gc, capture_features, splits,
                                                seed=seed, models=held["capture"], **fit),
                  "volume": grouped_validation(Xv, yv, gv, volume_features, splits,
                                               seed=seed, models=held["volume"], **fit)}
    judge = Judge(JudgeModel.fit(Xc, yc, capture_features, **fit),
                  JudgeModel.fit(Xv, yv, volume_features, **fit), dict(recipe),
                  {"n_capture": int(len(yc)), "legible_capture": int(yc.sum()),
                   "n_volume": int(len(yv)), "legible_volume": int(yv.sum()),
                   "splits_held_out": list(splits), **fit})
    if bootstrap > 0:
        for name, X, y, rs, feats in (("capture", Xc, yc, rows, capture_features),
                                      ("volume", Xv, yv, both, volume_features)):
            clusters = [r.get("scene", f"row{i}") for i, r in enumerate(rs)]
            judge.spread[name] = {"bootstrap": bootstrap_models(X, y, clusters, feats,
                                                                bootstrap, seed, **fit),
                                  "held_out": held[name]}
            judge.domain[name] = {"features": feature_domain(X, feats)}
        judge.domain["capture"]["descriptors"] = descriptor_domain(rows)
        judge.domain["volume"]["descriptors"] = descriptor_domain(both, ("points",))
    return judge, validation
