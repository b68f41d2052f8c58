"""``clnlos study``: one study file, end to end (:func:`run_study`).

A study is file -> plan -> samples -> judgement -> report:

1. the file (:mod:`clnlos.study.file.spec`): a rig, materials, targets, sweeps, inversions,
   checked before any work;
2. the plan (:mod:`clnlos.study.plan.entries`): every (meta, sample), the inversions a method
   cannot run left out with a note; the materials made ready
   (:mod:`clnlos.study.samples.materials`);
3. the samples (:mod:`clnlos.study.samples`): each distinct scene simulated, reconstructed and
   scored once (cached on disk; serially or on Dask), every reconstruction judged against its
   target (:mod:`clnlos.study.samples.identify`), the realisations of an exposure rung
   curtailed once they cannot change the answer (:func:`render_curtailed`); the exposure
   curves refined where the exposure needed is not yet bracketed finely enough;
4. the judgement (:mod:`clnlos.study.findings`): the exposure and photons needed per
   material x target x inversion (results.json ``plan``), the smallest legible letter, the
   sweeps' tables; with a ``[table]`` the seed's material table at each of its targets, the
   legibility judge (:mod:`clnlos.study.judge`), the seed recipe's CNN, the transport
   comparison and the findings in words; the ``[[real]]`` captures beside their twins
   (:mod:`clnlos.study.real.check`); with ``real_data`` the shared captures' sections;
5. the report (:mod:`clnlos.study.report`): report.html, whose first screen is the answer,
   and results.json (stamped with the command and commit).

The quick and the full material studies are two study files shipped in ``clnlos/data``
(``clnlos study --quick`` / ``--full``) and run through this same path.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from clnlos.io.files import atomic_path
from clnlos.io.outputs import stamp
from clnlos.io.progress import counter, progress_bar
from clnlos.study.file.spec import Study, load_study
from clnlos.study.findings.exposure import (
    MAX_REFINEMENTS,
    exposure_curves,
    plan_rows,
    refinement,
    rung_key,
    rung_stopped,
    rungs_to_render,
    smallest_letters,
)
from clnlos.study.findings.summary import make_findings, plan_statement
from clnlos.study.findings.sweeps import (
    material_entries,
    smallest_legible,
    sweep_rows,
    tilt_rows,
)
from clnlos.study.judge.study import study_judge
from clnlos.study.plan.entries import refined_entries, study_plan
from clnlos.study.real.check import json_rows, real_check
from clnlos.study.real.check import summary as real_check_summary
from clnlos.study.real.materials import RealPlan, real_capture_paths, real_materials
from clnlos.study.report.page import write_report
from clnlos.study.samples.identify import (
    TILT_MAX_SHIFT_M,
    chance_of,
    identification_of,
    label_of,
    render_plan,
    study_resolution,
)
from clnlos.study.samples.materials import prepare_materials
from clnlos.study.samples.render import cpu_workers, sample_pool
from clnlos.study.samples.resolution import json_ready
from clnlos.study.score.clarity import label_thresholds, truth_thresholds
from clnlos.study.score.quality import METRICS, pearson, validate_metrics
from clnlos.study.sections import (
    cnn_samples,
    real_capture_dir,
    real_data_study,
    samples_labels,
    study_cost,
    train_cnn,
    transport_comparison,
)

LABEL_METRICS = {"legibility": "identification", "nr": "nr_clarity", "fft": "fft_clarity"}


def refine_exposures(study: Study, mats, plan, results, cache: Path, gamma, lateral,
                     **kw) -> tuple[list, list]:
    """The plan and results with rungs added where an exposure needed is bracketed more
    coarsely than the study's ``refine_ratio`` (:func:`clnlos.study.findings.exposure.
    refinement`), at most MAX_REFINEMENTS rounds."""
    for _ in range(MAX_REFINEMENTS):
        curves = exposure_curves(plan, results, study)
        add = refinement(curves, study.legible_fraction, study.refine_ratio)
        if not add:
            break
        new = []
        for key, exposures in add.items():
            sweep, at, target, material, method, refl = key
            new += refined_entries(study, mats, {
                "sweep": sweep, "at": dict(at), "target": target, "material": material,
                "method": method, "inversion": refl}, exposures)
        new, res = render_curtailed(new, study, cache, gamma, lateral,
                                    "refining the exposure needed", **kw)
        plan, results = plan + new, results + res
    return plan, results


def render_curtailed(plan, study: Study, cache: Path, gamma, lateral, desc: str,
                     **kw) -> tuple[list, list]:
    """(the entries rendered, their identified results): the entries off an exposure curve
    and the first realisation of every rung at once, then the realisations
    :func:`clnlos.study.findings.exposure.rungs_to_render` asks for, round by round (one
    progress bar; its total: the realisations still possible). A sweep of letter heights
    keeps every realisation: its smallest legible letter reads each exposure whole."""
    def curtailed(meta) -> tuple | None:
        key = rung_key(meta)
        heights = key is not None and "letter_height_m" in study.sweeps[meta["sweep"]].variables
        return None if heights else key

    rungs: dict = {}
    for entry in plan:
        key = curtailed(entry[0])
        if key is not None:
            rungs.setdefault(key, []).append(entry)
    for entries in rungs.values():
        entries.sort(key=lambda e: e[0].get("k", 0))  # by realisation index
    state = {key: (0, 0, len(entries)) for key, entries in rungs.items()}
    templates: dict = {}  # drawn once for every round
    batch = [e for e in plan if curtailed(e[0]) is None]
    done_plan: list = []
    done: list = []
    with progress_bar(len(plan), desc, "sample") as bar:
        while True:
            todo = rungs_to_render(state, study.legible_fraction)
            batch += [rungs[key][state[key][0]] for key in todo]
            if not batch:
                break
            res = render_plan(batch, study.grid, cache, bar=bar, **kw)
            identification_of(batch, res, study, gamma, lateral, templates)
            for (meta, _), r in zip(batch, res, strict=True):
                key = curtailed(meta)
                if key is not None:
                    m, f, n = state[key]
                    state[key] = (m + 1, f + (not r["identified"]), n)
            done_plan, done, batch = done_plan + batch, done + res, []
            bar.total = bar.n + sum(  # what can still be asked for
                n - m for m, f, n in state.values()
                if not rung_stopped(f, n, study.legible_fraction))
            bar.refresh()
        bar.total = bar.n
        bar.refresh()
    return done_plan, done


def table_part(study: Study, mats, plan, results, resolution, lateral, out_dir: Path,
               cache: Path, timings: dict, labels: str, **kw) -> dict:
    """The material table's sections: metric validation and labels, the transport
    comparison, the legibility judge and the seed recipe's CNN, the materials per target,
    the shared CDT captures (``real_data``), the findings."""
    glyph_idx = [i for i, (meta, _) in enumerate(plan) if meta["set"] != "dataset"]
    truth = {k: np.array([results[i][k] for i in glyph_idx], float)
             for k in ("iou", "depth_error_m", "psnr_db", "identified")}
    truth["iou_excess"] = np.array([results[i]["iou"] - results[i]["iou_box_baseline"]
                                    for i in glyph_idx])
    values = {m: np.array([results[i][f"q_{m}"] for i in glyph_idx]) for m in METRICS}
    validation = validate_metrics(values, truth)
    label_metric = LABEL_METRICS[labels]
    all_values = {m: np.array([r[f"q_{m}"] for r in results]) for m in METRICS}
    thresholds = ((0.5, 0.5) if label_metric == "identification"
                  else label_thresholds(all_values[label_metric]))
    fft_thresholds = label_thresholds(all_values["fft_clarity"])

    comparison = None
    if study.transport is not None:
        t0 = time.perf_counter()
        comparison = transport_comparison(study, mats, cache, resolution, lateral, **kw)
        timings["transport_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    rendered = [(plan, results)] + ([] if comparison is None else
                                    [(comparison["plan"], comparison["results"])])
    legibility = judge = family = None
    classifier = {"splits": {}}
    if study.judge_twins:
        with progress_bar(None, "legibility judge twins", "scene") as bar:
            legibility, classifier, judge, family = study_judge(
                [(s, r) for p, rs in rendered for (_, s), r in zip(p, rs, strict=True)],
                out_dir, per_geometry=study.judge_twins, seed=study.seed, cache=cache,
                real_root=study.real_data, device=kw.get("device"), progress=counter(bar))
    predict = legibility.predict_proba if legibility is not None else None
    seed_cnn = None
    labels_arr = samples_labels(results, cnn_samples(plan, label_metric), label_metric,
                                thresholds)
    if label_metric != "identification":
        predict, seed_cnn, labels_arr = train_cnn(plan, results, study, label_metric,
                                                  thresholds)
    timings["cnn_s"] = time.perf_counter() - t0

    geometries = []
    for name in study.table.targets:
        target = study.target(name)
        ents = material_entries(study, mats, plan, results, name, label_metric, thresholds,
                                fft_thresholds, predict)
        scan = target.scan_width_m or study.grid.scan_width_m
        geometries.append({"name": name, "scan_width_m": scan,
                           "letter_height_m": target.height_m, "stroke_m": target.stroke_m,
                           "depth_m": target.depth_m, "glyphs": list(target.glyphs),
                           "description": _describe(target, scan),
                           "lateral_resolution_m": lateral[name],
                           "stroke_over_resolution": target.stroke_m / lateral[name],
                           "materials": ents})
    legible = study.table.legible_target
    per_material = next(g for g in geometries if g["name"] == legible)["materials"]
    agreement = {g["name"]: sum(m["label"] == m["seed_label"] for m in g["materials"]
                                if m["seed_label"] is not None) for g in geometries}
    cnn_agreement = sum(m["cnn_label"] == m["seed_label"] for m in per_material
                        if m["seed_label"] is not None)
    # labels cut at the seed's split agree with its labels' mix by construction: the same
    # agreement with cuts fitted to the study's own ground truth instead
    truth_cut = None if label_metric == "identification" else truth_thresholds(
        values[label_metric], [results[i]["legibility"] for i in glyph_idx])
    truth_agreement = None if truth_cut is None else {
        g["name"]: sum(label_of(m["label_metric_value"], truth_cut) == m["seed_label"]
                       for m in g["materials"] if m["seed_label"] is not None)
        for g in geometries}

    t0 = time.perf_counter()
    cdt = real_capture_dir(study.real_data) if legibility is not None else None
    real = None if cdt is None else real_data_study(
        cdt, predict, study.grid, kw.get("device"), legibility=legibility,
        label_metric=label_metric, cache=cache)
    if real is not None and real["chart"] is not None:
        resolution["real_chart"] = real["chart"]
    timings["real_capture_s"] = time.perf_counter() - t0
    if real is not None:
        timings["real_thinning_s"] = real["thinning_s"]
        real["family"] = family
    return {"validation": validation, "label_metric": label_metric, "thresholds": thresholds,
            "fft_thresholds": fft_thresholds, "comparison": comparison,
            "classifier": classifier, "judge": judge, "seed_cnn": seed_cnn,
            "labels": labels_arr, "geometries": geometries, "per_material": per_material,
            "agreement": agreement, "cnn_agreement": cnn_agreement, "real": real, "truth": truth,
            "truth_cut": truth_cut, "truth_agreement": truth_agreement}


def _describe(target, scan: float) -> str:
    what = {"glyphs": f"glyphs {''.join(target.glyphs)}", "text": f"the text {target.text!r}",
            "pattern": f"the chart {target.pattern}", "mask": "a mask"}[target.kind]
    size = (f"{100 * target.height_m:.0f} cm tall" if target.kind != "pattern"
            else f"{100 * target.height_m:.0f} cm wide")
    stroke = f" with {100 * target.stroke_m:.0f} cm strokes" if target.stroke_m else ""
    return f"{scan:g} m scan, {what} {size}{stroke} at {target.depth_m:g} m"


def run_study(out_dir: Path, study: Study, *, workers: int | None = None,
              scheduler: str | None = None, device: str | None = None,
              labels: str | None = None) -> dict:
    """The study into ``out_dir`` (report.html, results.json, the sample cache, the
    materials made, the judge); returns what results.json holds (its ``timings_s``: each
    stage's wall time). ``labels``: what the table's CNN learns (default: the file's
    ``[classifier] labels``, else "legibility")."""
    study = load_study(study)
    out_dir.mkdir(parents=True, exist_ok=True)
    cache = out_dir / "cache"
    nw = cpu_workers(workers) if scheduler is None else 1
    labels = labels or (study.classifier.labels if study.classifier else "legibility")
    with sample_pool(nw, scheduler) as pool:
        return _run_study(out_dir, study, cache, nw, labels, pool=pool, device=device)


def _run_study(out_dir: Path, study: Study, cache: Path, nw: int, labels: str, **kw) -> dict:
    """:func:`run_study` in its sample pool (``kw``: ``pool``, ``device``)."""
    device = kw["device"]
    timings: dict = {}

    t0 = time.perf_counter()
    mats, material_records = prepare_materials(study, out_dir)
    plan, left_out = study_plan(study, mats)
    timings["materials_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    resolution, lateral = study_resolution(study, device)
    gamma = resolution["effective_temporal_fwhm_s"] if resolution else None
    timings["resolution_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    plan, results = render_curtailed(plan, study, cache, gamma, lateral, "study samples", **kw)
    timings["samples_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    plan, results = refine_exposures(study, mats, plan, results, cache, gamma, lateral, **kw)
    timings["refine_s"] = time.perf_counter() - t0
    answer = plan_rows(exposure_curves(plan, results, study), study)

    def chance(name):
        return chance_of(study.target(name))

    legibility_rows = sweep_rows(plan, results, "legibility_sweep", chance)
    geometry_rows = sweep_rows(plan, results, "geometry_sweep", chance)
    tilts = tilt_rows(plan, results, chance)
    other_rows = sweep_rows(plan, results, "sweep", chance)
    letters = smallest_letters(plan, results, study)

    table = None
    if study.table is not None:
        table = table_part(study, mats, plan, results, resolution, lateral, out_dir, cache,
                           timings, labels, **kw)

    t0 = time.perf_counter()
    checks = None
    if study.real:
        with progress_bar(None, "real captures and their twins", "reconstruction") as bar:
            checks = real_check(study, mats, out_dir, device, lambda: bar.update(1))
    timings["real_check_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    real_section = None
    if study.real_data is not None and real_capture_paths(study.real_data):
        real_section = real_materials(study.real_data, RealPlan.quick()
                                      if study.real_data_plan == "quick" else RealPlan(),
                                      device)
    timings["real_materials_s"] = time.perf_counter() - t0

    need = smallest_legible(legibility_rows, list(dict.fromkeys(
        r["material"] for r in legibility_rows)), list(dict.fromkeys(
            r["inversion"] for r in legibility_rows)), study.legible_fraction)
    classes = {n: k.brdf_class for n, k in mats.items()}
    if table is not None:
        findings = make_findings(table["geometries"], need, geometry_rows,
                                 table["validation"], table["label_metric"],
                                 table["classifier"]["splits"], table["agreement"], study,
                                 tilts, classes)
    else:
        findings = {}
    findings["plan_statement"] = plan_statement(answer, study, letters)
    findings.setdefault("statement", findings["plan_statement"])

    ious = np.array([r["iou"] for r in results])
    hist, edges = np.histogram(ious, bins=10, range=(0, 1))
    out = {
        "study": study.name, "source": study.source, "study_file": study.text,
        "options": {**study.summary(), "workers": nw, "labels": labels},
        "materials_prepared": material_records, "left_out": left_out,
        "plan": answer, "smallest_legible_letter": letters,
        "real_check": None if checks is None else json_rows(checks),
        "real_check_summary": None if checks is None else real_check_summary(checks),
        "resolution": resolution, "inversions": list(study.reflectance),
        "methods": list(study.methods),
        "legibility_sweeps": [{k: r[k] for k in (
            "variable", "value", "at", "target", "method", "material", "inversion",
            "identification", "measurement_identification", "iou", "iou_box_baseline",
            "iou_excess", "photon_counts", "n")} for r in legibility_rows],
        "smallest_legible": need, "tilt_sweep": tilts, "tilt_max_shift_m": TILT_MAX_SHIFT_M,
        "sweeps": geometry_rows,
        "other_sweeps": other_rows,
        "dataset": {"n": len(results), "iou_median": float(np.median(ious)),
                    "iou_histogram": {"edges": edges.tolist(), "counts": hist.tolist()},
                    "iou_zero_fraction": float(np.mean(ious == 0))},
        "findings": findings, "timings_s": timings, "n_dataset": len(results),
        "real_materials": real_section}
    real = None
    if table is not None:
        real = table["real"]
        out.update(table_results(study, table))
    t0 = time.perf_counter()
    out["cost"] = study_cost(plan, results, timings, None if table is None
                             else table["comparison"])
    write_report(out_dir, out, plan, results, real, checks)
    timings["report_s"] = time.perf_counter() - t0
    out["cost"] = study_cost(plan, results, timings, None if table is None
                             else table["comparison"])
    out["real_materials"] = None if real_section is None else json_ready(real_section)
    with atomic_path(out_dir / "results.json") as tmp:
        tmp.write_text(json.dumps(stamp(out), indent=1))
    return out


def table_results(study: Study, table: dict) -> dict:
    """The results.json keys of the material table (:func:`table_part`)."""
    truth, validation = table["truth"], table["validation"]
    label_metric, labels = table["label_metric"], table["labels"]
    real = table["real"]
    out = {
        "materials": table["per_material"], "geometries": table["geometries"],
        "legible_geometry": study.table.legible_target,
        "seed_geometry": study.table.seed_target or study.table.legible_target,
        "real_capture": None if real is None else real["summary"],
        "real_captures_cnn": None if real is None else [
            {k: v for k, v in c.items() if k != "mip"} for c in real["cnn"]],
        "classifier": {**table["classifier"], "real_thinning": [] if real is None else [
            {k: r[k] for k in ("capture", "fraction", "photons", "p_legible")}
            for r in real["thinning"]]},
        "judge": table["judge"],
        **({} if table["seed_cnn"] is None else {"cnn_seed_recipe": table["seed_cnn"]}),
        "labels": {"source": {v: k for k, v in LABEL_METRICS.items()}[label_metric],
                   "metric": label_metric,
                   "corr_with_iou": validation[label_metric]["iou"]
                   if label_metric in validation else pearson(truth["identified"],
                                                               truth["iou"]),
                   "thresholds": list(table["thresholds"]),
                   "counts": {str(k): int((labels == k).sum()) for k in (1, 2, 3)}},
        "metrics": {m: validation[m]["iou"] for m in METRICS},
        "metric_validation": validation,
        "clarity_thresholds": list(table["fft_thresholds"]),
        "label_counts": {str(k): int((labels == k).sum()) for k in (1, 2, 3)},
        "seed_figure9_agreement": int(table["agreement"][study.table.legible_target]),
        "seed_figure9_agreement_by_geometry": table["agreement"],
        "seed_figure9_agreement_cnn": int(table["cnn_agreement"]),
        "seed_figure9_agreement_truth_cut": table["truth_agreement"],
        "label_thresholds_truth_cut": None if table["truth_cut"] is None
        else list(table["truth_cut"])}
    comparison = table["comparison"]
    if comparison is not None:
        tc = study.transport
        out["transport_comparison"] = {
            **{k: v for k, v in comparison.items() if k not in ("plan", "results")},
            "face_rings": tc.face_rings, "face_angles": tc.face_angles,
            "glyphs": list(tc.glyphs or study.target(study.table.legible_target).glyphs),
            "geometry": study.table.legible_target}
    return out
