"""The study's sections beyond its tables: the seed's CNN recipe (:func:`train_cnn`; the
legibility judge is :mod:`clnlos.study.judge.study`), the real captures
(:func:`real_data_study`), the transport comparison (:func:`transport_comparison`) and where the
time went (:func:`study_cost`)."""

from __future__ import annotations

import json
import time
import warnings
from pathlib import Path

import numpy as np

from clnlos.io.progress import counter, progress_bar
from clnlos.study.file.spec import Study, StudyGrid
from clnlos.study.judge.cnn import SEED_EPOCHS, train_classifier
from clnlos.study.plan.entries import comparison_plan
from clnlos.study.real.capture import (
    PUBLISHED_SCAN_WIDTH_M,
    compare_real_capture,
    real_capture_figure,
    reconstruct_chart,
)
from clnlos.study.samples.identify import identification_of, label_of, render_plan
from clnlos.study.real.thinning import real_thinning
from clnlos.study.findings.transport import comparison_table


def samples_labels(results, idx, label_metric, thresholds) -> np.ndarray:
    if label_metric == "identification":
        return np.array([results[i]["legibility"] for i in idx])
    return np.array([label_of(results[i][f"q_{label_metric}"], thresholds) for i in idx])


def cnn_samples(plan, label_metric: str) -> list[int]:
    """Plan indices of the seed recipe's images: every glyph reconstruction (and the random
    extras for the metric labels), one per distinct scene."""
    use = [i for i, (meta, _) in enumerate(plan)
           if meta["set"] != "dataset" or label_metric != "identification"]
    seen, idx = set(), []
    for i in use:
        key = json.dumps(plan[i][1], sort_keys=True)
        if key not in seen:
            seen.add(key)
            idx.append(i)
    return idx


def train_cnn(plan, results, study: Study, label_metric: str, thresholds):
    """The seed's recipe (``--labels fft`` / ``nr``) on :func:`cnn_samples`: validation on
    the ``[classifier]``'s held-out glyphs and letter size."""
    c = study.classifier
    idx = cnn_samples(plan, label_metric)
    held = np.array([plan[i][0].get("glyph") in c.held_out_glyphs
                     or (plan[i][0].get("variable") == "letter_height_m"
                         and plan[i][0].get("value") == c.held_out_height_m) for i in idx])
    labels = samples_labels(results, idx, label_metric, thresholds)
    images = np.stack([results[i]["mip"] for i in idx])
    with progress_bar(None, "study CNN", "batch") as bar:
        predict, report = train_classifier(images, labels, epochs=c.epochs or SEED_EPOCHS,
                                           seed=study.seed, progress=counter(bar),
                                           val_mask=held)
    report["held_out"] = {"glyphs": list(c.held_out_glyphs),
                          "letter_height_m": c.held_out_height_m}
    return predict, report, labels


def real_capture_dir(root: Path | None) -> Path | None:
    """``root/cdt`` when it holds at least one of the real CDT captures, else None (with a
    one-line warning when ``root`` was given: the study goes on without the real data)."""
    if root is None:
        return None
    cdt = Path(root) / "cdt"
    if any((cdt / f"{n}.mat").is_file() for n in PUBLISHED_SCAN_WIDTH_M):
        return cdt
    warnings.warn(f"--real-data {root}: no real CDT capture ({', '.join(PUBLISHED_SCAN_WIDTH_M)}"
                  ".mat) in its cdt/ folder; the report goes without the real captures",
                  UserWarning, stacklevel=2)
    return None


def real_captures_cnn(rows: list[dict], predict, label_metric: str) -> list[dict]:
    """The CNN's verdict on each real capture at all its photons (the fraction-1 rows of
    :func:`clnlos.study.real.thinning.real_thinning`): the legibility classifier's
    ``p_legible`` (label 1 legible at P >= 1/2, else 3), or the seed recipe's class."""
    out = []
    for r in rows:
        if r["fraction"] != 1.0:
            continue
        if label_metric == "identification":
            label, probs = (1 if r["p_legible"] >= 0.5 else 3), [r["p_legible"]]
        else:
            lab, pr = predict(r["mip"][None])
            label, probs = int(lab[0]), [float(v) for v in pr[0]]
        out.append({"name": r["capture"], "cnn_label": int(label), "p_legible": r["p_legible"],
                    "cnn_probabilities": probs, "mip": r["mip"]})
    return out


def real_data_study(cdt: Path, predict, grid: StudyGrid, device=None, *, legibility,
                    label_metric: str = "identification", cache: Path | None = None) -> dict:
    """The real captures in ``cdt``: letters_ut beside a simulation of a comparable scene
    (:func:`clnlos.study.real.capture.compare_real_capture`, its figure), the resolution
    chart's resolved features, every capture thinned to THINNING_FRACTIONS of its photons
    with the ``legibility`` classifier's P(legible) (``thinning``) and the CNN's verdict at
    all its photons (``cnn``)."""
    out: dict = {"summary": None, "figure": None, "chart": None}
    if (cdt / "letters_ut.mat").is_file():
        cmp = compare_real_capture(cdt / "letters_ut.mat", grid.method,
                                   iterations=grid.iterations, grid=grid, queue=device)
        out["figure"] = real_capture_figure(cmp)
        cmp.pop("arrays")
        out["summary"] = cmp
    if (cdt / "resolution_70.mat").is_file():
        chart = reconstruct_chart(cdt / "resolution_70.mat", "lct", queue=device)
        chart.pop("arrays", None)
        out["chart"] = chart
    t0 = time.perf_counter()
    with progress_bar(None, "real captures thinned", "reconstruction") as bar:
        out["thinning"] = real_thinning(cdt, grid, legibility.predict_proba, cache=cache,
                                        device=device, progress=counter(bar))
    out["thinning_s"] = time.perf_counter() - t0
    out["cnn"] = real_captures_cnn(out["thinning"], predict, label_metric)
    return out


def transport_comparison(study: Study, mats, cache: Path, resolution: dict,
                         lateral: dict[str, float], **kw) -> dict:
    """The materials at the table's legible target under the confocal and the bistatic
    transport (:mod:`clnlos.study.findings.transport`): its table, with ``plan`` and
    ``results``."""
    plan = comparison_plan(study, mats)
    results = render_plan(plan, study.grid, cache, desc="transport comparison", **kw)
    identification_of(plan, results, study, resolution["effective_temporal_fwhm_s"], lateral)
    target = study.target(study.table.legible_target)
    out = comparison_table([m.name for m in study.materials], plan, results,
                           1.0 / len(target.glyphs),
                           {n: {"class": k.brdf_class} for n, k in mats.items()})
    return {**out, "plan": plan, "results": results}


def study_cost(plan, results, timings: dict, comparison: dict | None = None) -> dict:
    """Where the study's time goes: per part of the plan (the main table, each sweep, the
    random extras, the transport comparison) its entries, the distinct samples they need
    and the seconds those samples took to simulate and to reconstruct (summed over the
    workers, as each sample recorded when it was rendered: a sample read from the cache
    costs nothing now); and each stage's wall time (``timings``)."""
    parts: dict[str, dict] = {}
    seen: set[str] = set()
    entries = list(zip(plan, results, strict=True))
    if comparison is not None:
        entries += [(({"set": "transport_comparison"}, s), r) for (_, s), r in
                    zip(comparison["plan"], comparison["results"], strict=True)]
    for (meta, sample), r in entries:
        row = parts.setdefault(meta["set"], {"part": meta["set"], "entries": 0, "samples": 0,
                                             "simulate_s": 0.0, "reconstruct_s": 0.0})
        row["entries"] += 1
        key = json.dumps(sample, sort_keys=True)
        if key in seen:
            continue  # rendered once, counted where first asked for
        seen.add(key)
        row["samples"] += 1
        row["simulate_s"] += float(r.get("simulate_s", 0.0))
        row["reconstruct_s"] += float(r.get("reconstruct_s", 0.0))
    return {"parts": list(parts.values()), "stages_s": dict(timings),
            "total_s": float(sum(timings.values()))}
