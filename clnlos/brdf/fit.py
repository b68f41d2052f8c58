"""Fitting analytic BRDF models to measured samples: bounded least squares in log space.

Residuals r_i = log(fhat_i + eps) - log(f_i + eps) (eps = 1e-3 x median positive f, so the
exact zeros of some measurements do not dominate), minimised with
``scipy.optimize.least_squares`` inside the parameter bounds from several seeded random
starts; the best run is kept and its parameters are reported with the metrics.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from clnlos.brdf.data import (
    MIN_SIGNIFICANT,
    BRDFSamples,
    agreement,
    relative_error,
    significance_floor,
)
from clnlos.brdf.mlp import MLPConfig, train_mlp
from clnlos.brdf.models import BRDFModel
from clnlos.brdf.store import save_model
from clnlos.errors import InputFileError, ParameterError
from clnlos.io.files import atomic_path

# (parameter, lower, upper) per model; parameters not listed keep their defaults.
FIT_SPACE = {
    "lambert": [("kd", 0.0, 10.0)],
    "phong": [("kd", 0.0, 10.0), ("ks", 0.0, 100.0), ("shininess", 0.5, 5000.0)],
    "minnaert": [("kd", 0.0, 10.0), ("k", 0.2, 3.0)],
    "torrance-sparrow": [("kd", 0.0, 10.0), ("ks", 0.0, 100.0), ("alpha", 0.005, 1.0)],
    "five-param": [("kb", 0.0, 1e4), ("kr", 1.01, 50.0), ("b", -100.0, 0.0),
                   ("a_exp", 0.1, 3.0), ("kd", 0.0, 10.0)],
}
FIXED = {"torrance-sparrow": {"f0": 1.0, "distribution": "ggx"}}
MIN_MLP_SAMPLES = 10  # significant training samples an MLP fit needs at least


def min_fit_samples(model_name: str) -> int:
    """Significant training samples a fit needs: one more than its free parameters (an
    analytic model), MIN_MLP_SAMPLES for an MLP."""
    name = "lambert" if model_name == "lambertian" else model_name
    return len(FIT_SPACE[name]) + 1 if name in FIT_SPACE else MIN_MLP_SAMPLES


def check_fit_samples(model_name: str, train: BRDFSamples, test: BRDFSamples | None) -> None:
    """Enough samples at or above the significance floor (where the metrics are computed):
    min_fit_samples for the training set, one for a test set; else an InputFileError
    naming the file, the count and the floor (an all-zero BRDF has none)."""
    checks = (("training", train, min_fit_samples(model_name), f"the {model_name} fit needs"),
              ("test", test, 1, "its metrics need"))
    for role, s, need, who in checks:
        if s is None:
            continue
        floor = significance_floor(s)
        n = int(np.count_nonzero(s.brdf >= floor))
        if n < need:
            raise InputFileError(
                f"{s.meta.get('path', role + ' data')}: {n} of {len(s.brdf)} {role} samples "
                f"have brdf >= {floor:g} 1/sr (the significance floor: its precision, at "
                f"least {MIN_SIGNIFICANT:g}); {who} at least {need}")


@dataclass
class FitResult:
    model: BRDFModel
    metrics: dict = field(default_factory=dict)


def metrics_for(predict, train: BRDFSamples, test: BRDFSamples | None) -> dict:
    """Agreement (%), relative L2 error and peak error of ``predict`` on each set, computed on
    the samples at or above the set's significance floor (its precision, at least
    MIN_SIGNIFICANT); the floor and how the precision was found are part of the result."""
    out = {"metrics_on": f"samples with brdf >= max(precision, {MIN_SIGNIFICANT}) 1/sr"}
    for name, s in (("train", train), ("test", test)):
        if s is None:
            continue
        floor = significance_floor(s)
        keep = s.brdf >= floor
        p = predict(s.theta_i[keep], s.phi_i[keep], s.theta_s[keep], s.phi_s[keep])
        f = s.brdf[keep]
        out[f"{name}_relative_error"] = relative_error(p, f)
        out[f"{name}_agreement_pct"] = agreement(p, f)
        out[f"{name}_peak_error_pct"] = peak_error(p, f)
        out[f"{name}_samples"] = int(keep.sum())
        out[f"{name}_samples_below_floor"] = int((~keep).sum())
        out[f"{name}_floor_per_sr"] = floor
        out[f"{name}_precision_per_sr"] = float(s.meta.get("precision", 0.0))
        out[f"{name}_precision_source"] = s.meta.get("precision_source", "not recorded")
    return out


def peak_error(pred, truth) -> float:
    """100 x (fhat - f) / f at the largest measured value (signed %, nan when empty)."""
    pred, truth = np.asarray(pred, float), np.asarray(truth, float)
    if truth.size == 0:
        return float("nan")
    k = int(np.argmax(truth))
    return float(100.0 * (pred[k] - truth[k]) / truth[k])


def fit_analytic(name: str, train: BRDFSamples, test: BRDFSamples | None = None, *,
                 starts: int = 8, seed: int = 0, progress=None) -> FitResult:
    """Fit the analytic model ``name`` from ``starts`` seeded random starts (the module
    docstring). ``progress(done, total)`` is called after every residual evaluation with
    ``done`` of ``total`` = ``starts`` optimiser runs finished."""
    if name == "lambertian":
        name = "lambert"
    if name not in FIT_SPACE:
        raise ParameterError("model", name, " or ".join(sorted(FIT_SPACE)))

    t0 = time.perf_counter()
    space = FIT_SPACE[name]
    lo = np.array([s[1] for s in space])
    hi = np.array([s[2] for s in space])
    f = train.brdf
    eps = 1e-3 * float(np.median(f[f > 0])) if np.any(f > 0) else 1e-6
    logf = np.log(f + eps)
    model_name = "microfacet" if name == "torrance-sparrow" else name
    fixed = FIXED.get(name, {})

    def make(x):
        return BRDFModel(model_name, {**{k: float(v) for (k, _, _), v in zip(space, x,
                                                                               strict=True)},
                                      **fixed})

    done = 0  # optimiser runs finished

    def resid(x):
        p = make(x)(train.theta_i, train.phi_i, train.theta_s, train.phi_s)
        if progress is not None:
            progress(done, starts)
        return np.log(np.maximum(np.nan_to_num(p, nan=0.0, posinf=1e30), 0) + eps) - logf

    rng = np.random.default_rng(seed)
    best = None
    for k in range(starts):
        done = k
        if k == 0:
            x0 = np.where(np.isfinite(hi), (lo + np.minimum(hi, lo + 1)) / 2, lo + 1)
        else:
            # log-uniform where the range spans decades, uniform otherwise
            u = rng.random(len(lo))
            span_log = (lo > 0) & (hi / np.maximum(lo, 1e-300) > 100)
            with np.errstate(divide="ignore", invalid="ignore"):
                x_log = np.exp(np.log(np.maximum(lo, 1e-300)) + u * (
                    np.log(np.maximum(hi, 1e-300)) - np.log(np.maximum(lo, 1e-300))))
            x0 = np.where(span_log, x_log, lo + u * (hi - lo))
        x0 = np.clip(x0, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
        try:
            r = least_squares(resid, x0, bounds=(lo, hi), method="trf", max_nfev=400)
        except ValueError:
            continue
        if best is None or r.cost < best.cost:
            best = r
    if progress is not None:
        progress(starts, starts)
    if best is None:
        raise ParameterError("model", name, "a model that can be evaluated on this data")
    model = make(best.x)
    fit_time = time.perf_counter() - t0
    m = metrics_for(model, train, test)
    m["fit_time_s"] = fit_time
    m.update(model=name, params={k: float(v) for (k, _, _), v in zip(space, best.x,
                                                                    strict=True)},
             fixed=fixed, log_rms=float(np.sqrt(2 * best.cost / len(f))), starts=starts)
    return FitResult(model, m)


def fit_to_file(model_name: str, train, test, out, *, seed: int = 0,
                metrics_json=None, progress=None) -> dict:
    """Fit ``model_name`` (an analytic model, or ``mlp`` / ``mlp-seed``) to ``train`` and save it
    (and its metrics as JSON when asked); returns the metrics. ``progress(done, total)``
    follows the fit: epochs of the MLPs (:func:`clnlos.brdf.mlp.train_mlp`), optimiser runs of
    an analytic model (:func:`fit_analytic`)."""
    check_fit_samples(model_name, train, test)
    if model_name in ("mlp", "mlp-seed"):
        t0 = time.perf_counter()
        model, log = train_mlp(train, MLPConfig(recipe="seed" if model_name == "mlp-seed"
                                                else "improved", seed=seed),
                               progress=progress)
        metrics = {"model": model_name, "fit_time_s": time.perf_counter() - t0,
                   "recipe": model.meta()["config"],
                   **{k: v for k, v in log.items() if k != "loss_log"},
                   **metrics_for(model, train, test)}
    else:
        r = fit_analytic(model_name, train, test, seed=seed, progress=progress)
        model, metrics = r.model, r.metrics
    save_model(out, model, metrics, {"train": train.meta, "test": test.meta if test else None})
    if metrics_json:
        with atomic_path(metrics_json) as tmp:
            tmp.write_text(json.dumps(metrics, indent=1))
    return metrics
