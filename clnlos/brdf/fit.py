"""Fitting analytic BRDF models to measured samples: bounded least squares in log space.

Residuals r_i = log(fhat_i + eps) - log(f_i + eps) (eps = 1e-3 x median positive f, so the
exact zeros of some measurements do not dominate), minimised with
``scipy.optimize.least_squares`` inside the parameter bounds from several seeded random
starts; the best run is kept and its parameters are reported with the metrics.

Every fit says how good it is (:func:`fit_quality`): its agreement and peak error on the
held-out data (the ``--test`` set; without one, on the training data), the parameters that
ended at a bound of the fit space, and whether it is a usable fit: agreement >=
USABLE_AGREEMENT_PCT and the fitted peak within a factor USABLE_PEAK_RATIO of the measured
one (docs/brdf.md, "A usable fit"). ``model = "auto"`` (:func:`fit_auto`) fits every
candidate on the training data less a held-out part (AUTO_VALIDATION_FRACTION, seeded), keeps
the one that agrees best with that part, and fits it again on all the training data.
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
MLP_MODELS = ("mlp", "mlp-seed")  # the neural BRDFs (torch)
AUTO = "auto"  # the model name that fits the candidates and keeps the best
# ``auto``'s default candidates: the analytic models (seconds each; the neural BRDF, about
# 100 s on 2 CPU cores, is a candidate when asked for: ``candidates``)
AUTO_CANDIDATES = ("five-param", "torrance-sparrow", "phong", "minnaert", "lambert")
AUTO_VALIDATION_FRACTION = 0.2  # the training samples ``auto`` holds out to choose on
# A usable fit (docs/brdf.md): a mean relative error of at most 20% on held-out data (the
# seed's agreement) and the peak of the lobe within a factor 2 of the measured one
USABLE_AGREEMENT_PCT = 80.0
USABLE_PEAK_RATIO = 2.0
AT_BOUND_RTOL = 1e-6  # a parameter within this fraction of its range of a bound sits on it


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


def fit_one(model_name: str, train: BRDFSamples, test: BRDFSamples | None, *, seed: int = 0,
            progress=None) -> FitResult:
    """Fit one model (an analytic one, or ``mlp`` / ``mlp-seed``) to ``train``; its metrics
    on ``train`` and ``test`` (:func:`metrics_for`)."""
    if model_name in MLP_MODELS:
        t0 = time.perf_counter()
        model, log = train_mlp(train, MLPConfig(recipe="seed" if model_name == "mlp-seed"
                                                else "improved", seed=seed),
                               progress=progress)
        return FitResult(model, {"model": model_name, "fit_time_s": time.perf_counter() - t0,
                                 "recipe": model.meta()["config"],
                                 **{k: v for k, v in log.items() if k != "loss_log"},
                                 **metrics_for(model, train, test)})
    return fit_analytic(model_name, train, test, seed=seed, progress=progress)


def params_at_bounds(metrics: dict) -> list[str]:
    """The fitted parameters of an analytic fit that sit on a bound of its fit space
    (:data:`FIT_SPACE`, within AT_BOUND_RTOL of the range), as "kr = 50 (upper bound)": the
    best fit lies outside the space searched. A bound at 0 is not one of them: a term whose
    weight is 0 is the model without that term, a fit inside the model's own range."""
    name = metrics.get("model")
    out = []
    for key, lo, hi in FIT_SPACE.get("lambert" if name == "lambertian" else name, ()):
        v = metrics.get("params", {}).get(key)
        if v is None:
            continue
        tol = AT_BOUND_RTOL * (hi - lo)
        if (v <= lo + tol and lo != 0.0) or v >= hi - tol:
            out.append(f"{key} = {v:.4g} ({'lower' if v <= lo + tol else 'upper'} bound)")
    return out


def fit_quality(metrics: dict) -> dict:
    """How good a fit is (module docstring): ``on`` ("test", else "train"), its
    ``agreement_pct`` and ``peak_error_pct`` there, ``samples``, the parameters ``at_bound``
    (:func:`params_at_bounds`), ``usable`` (agreement and peak) and ``why`` a warning is due
    (not usable, a parameter at a bound)."""
    on = "test" if "test_agreement_pct" in metrics else "train"
    agree, peak = metrics[f"{on}_agreement_pct"], metrics[f"{on}_peak_error_pct"]
    bound = params_at_bounds(metrics)
    why = []
    if not agree >= USABLE_AGREEMENT_PCT:
        why.append(f"agreement {agree:.1f}% < {USABLE_AGREEMENT_PCT:g}%")
    ratio = 1 + peak / 100
    if not 1 / USABLE_PEAK_RATIO <= ratio <= USABLE_PEAK_RATIO:
        why.append(f"peak off by more than a factor {USABLE_PEAK_RATIO:g} ({peak:+.1f}%)")
    usable = not why
    if bound:
        why.append("at its bound: " + ", ".join(bound))
    return {"on": on, "agreement_pct": agree, "peak_error_pct": peak,
            "samples": metrics.get(f"{on}_samples"), "at_bound": bound,
            "usable": usable, "why": why}


def quality_line(model_name: str, quality: dict) -> str:
    """The one line a fit prints: its model, agreement and peak error and where measured."""
    where = ("held-out" if quality["on"] == "test" else "training (no held-out data: "
             "--test)")
    return (f"{model_name}: {where} agreement {quality['agreement_pct']:.1f}%, peak error "
            f"{quality['peak_error_pct']:+.1f}% ({quality['samples']} samples)")


def better_models(train: BRDFSamples, test: BRDFSamples | None, model_name: str,
                  agreement_pct: float, *, seed: int = 0,
                  candidates=AUTO_CANDIDATES) -> list[tuple[str, float]]:
    """(model, agreement %) of the analytic ``candidates`` other than ``model_name`` that
    agree better than ``agreement_pct`` with the data a fit is judged on (``test``, else
    ``train``), best first: fitted on ``train`` here (a few seconds each)."""
    out = []
    for name in candidates:
        if name == model_name or name in MLP_MODELS:
            continue
        q = fit_quality(fit_analytic(name, train, test, seed=seed).metrics)
        if q["agreement_pct"] > agreement_pct:
            out.append((name, q["agreement_pct"]))
    return sorted(out, key=lambda r: -r[1])


def quality_warning(model_name: str, quality: dict, better: list[tuple[str, float]]) -> str:
    """The warning line of a fit that is not usable or has a parameter at a bound: why, and a
    model that fits better (an analytic one measured on the same data, else the neural
    BRDF)."""
    if better:
        name, agree = better[0]
        hint = (f"{name} agrees better ({agree:.1f}% on the same data): --model {name}, or "
                "--model auto to choose on held-out data")
    elif quality["usable"]:
        hint = ("its agreement and peak are usable; the best parameters lie outside the space "
                "searched and no analytic model agrees better on the same data")
    elif model_name in MLP_MODELS:
        hint = "no analytic model agrees better on the same data"
    else:
        hint = ("no analytic model agrees better on the same data: the neural BRDF "
                "(--model mlp, needs torch) fits measured glossy sets better (docs/brdf.md)")
    if quality["usable"]:
        return (f"{model_name} fit has a parameter at its bound ({'; '.join(quality['why'])}): "
                f"{hint}")
    return (f"{model_name} fit is not usable ({'; '.join(quality['why'])}; usable: agreement "
            f">= {USABLE_AGREEMENT_PCT:g}% and the peak within a factor "
            f"{USABLE_PEAK_RATIO:g}, docs/brdf.md): {hint}")


def validation_split(train: BRDFSamples, seed: int, fraction: float = AUTO_VALIDATION_FRACTION
                     ) -> tuple[BRDFSamples, BRDFSamples]:
    """(fit part, held-out part) of the training samples: ``fraction`` of them at random
    (numpy Generator seeded with ``seed``) held out."""
    order = np.random.default_rng(seed).permutation(len(train))
    n_held = max(1, int(round(fraction * len(train))))
    return train.subset(np.sort(order[n_held:])), train.subset(np.sort(order[:n_held]))


def fit_auto(train: BRDFSamples, test: BRDFSamples | None, *, seed: int = 0,
             candidates=AUTO_CANDIDATES, progress=None) -> FitResult:
    """Fit every candidate on ``train`` less a held-out part (:func:`validation_split`),
    keep the one whose agreement with that part is highest, fit it again on all of
    ``train``; its metrics gain ``auto`` (each candidate's held-out agreement and peak
    error, the one kept). ``progress(done, total)`` counts the fits."""
    part, held = validation_split(train, seed)
    total = len(candidates) + 1
    scores = {}
    for k, name in enumerate(candidates):
        if progress is not None:
            progress(k, total)
        check_fit_samples(name, part, held)
        m = fit_one(name, part, held, seed=seed).metrics
        scores[name] = {"agreement_pct": m["test_agreement_pct"],
                        "peak_error_pct": m["test_peak_error_pct"]}
    best = max(candidates, key=lambda n: scores[n]["agreement_pct"])
    if progress is not None:
        progress(len(candidates), total)
    r = fit_one(best, train, test, seed=seed)
    if progress is not None:
        progress(total, total)
    r.metrics["auto"] = {"candidates": scores, "kept": best,
                         "held_out_fraction": AUTO_VALIDATION_FRACTION, "seed": seed}
    return r


def auto_line(auto: dict) -> str:
    """The line ``auto`` prints: each candidate's agreement on the held-out part, the kept."""
    scores = sorted(auto["candidates"].items(), key=lambda kv: -kv[1]["agreement_pct"])
    return (f"auto: held-out agreement on {auto['held_out_fraction'] * 100:g}% of the "
            "training data: " + ", ".join(f"{n} {v['agreement_pct']:.1f}%" for n, v in scores)
            + f"; {auto['kept']} kept")


def fit_to_file(model_name: str, train, test, out, *, seed: int = 0,
                metrics_json=None, progress=None, candidates=AUTO_CANDIDATES) -> dict:
    """Fit ``model_name`` (an analytic model, ``mlp`` / ``mlp-seed``, or ``auto``: the best
    of ``candidates`` on held-out data, :func:`fit_auto`) to ``train`` and save it (and its
    metrics as JSON when asked); returns the metrics, with ``fit_quality``
    (:func:`fit_quality`; for a fit that is not usable or has a parameter at a bound
    ``fit_quality["warning"]``, naming a model that fits better: :func:`better_models`).
    ``progress(done, total)`` follows the fit: epochs of the MLPs
    (:func:`clnlos.brdf.mlp.train_mlp`), optimiser runs of an analytic model
    (:func:`fit_analytic`), candidates of ``auto``."""
    if model_name == AUTO:
        for name in candidates:
            check_fit_samples(name, train, test)
        r = fit_auto(train, test, seed=seed, candidates=candidates, progress=progress)
    else:
        check_fit_samples(model_name, train, test)
        r = fit_one(model_name, train, test, seed=seed, progress=progress)
    model, metrics = r.model, r.metrics
    quality = fit_quality(metrics)
    if quality["why"]:  # not usable, or a parameter at a bound of the space searched
        kept = metrics["model"]
        tried = set(candidates) if model_name == AUTO else set()
        better = better_models(train, test, kept, quality["agreement_pct"], seed=seed,
                               candidates=[c for c in AUTO_CANDIDATES if c not in tried])
        quality["warning"] = quality_warning(kept, quality, better)
    metrics["fit_quality"] = quality
    save_model(out, model, metrics, {"train": train.meta, "test": test.meta if test else None})
    if metrics_json:
        with atomic_path(metrics_json) as tmp:
            tmp.write_text(json.dumps(metrics, indent=1))
    return metrics
