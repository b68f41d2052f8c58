"""``clnlos study``: how a hidden target's surface material changes what NLOS imaging through
a scattering slab can *read* (seed sections 3.2, 4.2, 4.3, 5).

The question is answered with legibility, not with how well a blob covers the target:

1. Geometries (:data:`GEOMETRIES`), each stated in every table: the seed's Table 1
   (``seed_table1``: 0.3 m scan, letters 0.15 m tall with 4 cm strokes at 0.5 m, the strokes
   at the confocal resolution limit) and ``legible`` (0.6 m scan, letters 0.3 m tall with
   8 cm strokes at 0.5 m: the scale of the published CDT captures, where a Lambertian target
   reads at the default budget).
2. Materials: the ten presets, each reconstructing each of the K = 8 glyphs of
   :mod:`clnlos.study.score.legibility` (``seeds`` noise realisations each) at each geometry.
   Per material: identification accuracy (closest of the K blurred glyph templates, Wilson
   95% interval, chance 1/K), IoU beside the IoU of the filled box of the true mask (what a
   blob scores) and the excess over it; the seed's Figure 9 grouping beside ours.
3. Legibility sweeps at the legible geometry for a strong-specular, a mixed and a Lambertian
   material: letter height (strokes scaled with it) and exposure; the smallest legible
   letter and the exposure each material needs (identification >= LEGIBLE_ACCURACY).
4. The geometry sweeps (scan width, depth, slab thickness) at the seed's letter size,
   scored the same way.
5. Measured resolution (:mod:`clnlos.study.samples.resolution`) and a real capture beside its
   simulation (:mod:`clnlos.study.real.capture`), when a folder of the real CDT captures
   is given (``real_data``, ``--real-data DIR``: its ``cdt/*.mat``).
6. The legibility judge (:mod:`clnlos.study.judge.study`): a calibrated logistic model on
   scale- and position-invariant measured features (:mod:`clnlos.study.judge.features`),
   the agreement of two binomial photon halves' reconstructions among them, trained on
   simulated twins of the real CDT and LCT capture families (:mod:`clnlos.study.judge.twins`)
   to give P(legible) (identified and IoU above the box baseline), validated on held-out
   glyphs, geometries and materials against the majority and a one-feature baseline and by
   family on every real capture's thinning ladder (:mod:`clnlos.study.judge.real`), saved
   as judge.json (``clnlos legibility FILE... --model STUDY_DIR``) and applied to the real
   captures thinned to fewer photons (:mod:`clnlos.study.real.thinning`);
   ``--labels fft`` / ``nr`` add the seed's recipe (a torch CNN, :mod:`clnlos.study.judge.cnn`:
   FFT clarity / no-reference terciles), whose three classes label the materials.
7. With ``transport = "both"`` (``--transport both``): the materials at the legible geometry
   under the bistatic transport too (Eq. 8 in full, :mod:`clnlos.study.findings.transport`),
   their table and ranks under both and the rank correlation. Everything else is simulated
   with the confocal transport (the seed's Eq. 9).
8. Report (report.html, with the seed's Figure 8 side by side) and results.json.

Every sample is rendered (simulated, reconstructed, scored) by :mod:`clnlos.study.samples.render`,
cached on disk and run through one pool of workers; identification is computed from the
cached MIPs, so a change of the matching rule reuses every sample.

The study's modules, in the order :func:`run_study` uses them: :mod:`clnlos.study.plan.entries`
(options, geometries, every sample), :mod:`clnlos.study.samples.identify` (rendered, resolution,
identification), :mod:`clnlos.study.findings.sweeps` (the tables), :mod:`clnlos.study.sections`
(classifier, real captures, transport comparison, cost), :mod:`clnlos.study.findings.summary` (the
answer), :mod:`clnlos.study.report.page`. Their public names are re-exported here
(``from clnlos.study.run import StudyOptions`` keeps working).
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from clnlos.brdf.presets import preset_table
from clnlos.errors import ParameterError
from clnlos.io.files import atomic_path
from clnlos.io.outputs import stamp
from clnlos.io.progress import counter, progress_bar
from clnlos.study.score.clarity import label_thresholds, truth_thresholds
from clnlos.study.samples.render import cpu_workers
from clnlos.study.findings.summary import (  # noqa: F401 (the names past make_findings: re-exported)
    GAP_CLOSED,
    geometry_sweep_effects,
    inversion_accuracy,
    make_findings,
    study_statement,
    tilt_findings,
)
from clnlos.study.plan.entries import (  # noqa: F401 (the plan's names: re-exported)
    DEFAULT_EXPOSURE_S,
    GEOMETRIES,
    HELD_OUT_GLYPHS,
    HELD_OUT_HEIGHT_M,
    INVERSIONS,
    LABEL_METRICS,
    LEGIBILITY_SWEEPS,
    LEGIBLE_GEOMETRY,
    MAIN_TARGET,
    QUICK_GRID,
    SEED_GEOMETRY,
    STROKE_PER_HEIGHT,
    SWEEP_MATERIALS,
    SWEEPS,
    TILT_MATERIALS,
    TILT_MAX_SHIFT_M,
    TILTS_DEG,
    TRANSPORT_CHOICES,
    Geometry,
    StudyOptions,
    comparison_plan,
    glyph_sample,
    inversion_brdf,
    noise_seed,
    study_plan,
)
from clnlos.study.judge.study import study_judge
from clnlos.study.score.quality import METRICS, pearson, validate_metrics
from clnlos.study.real.materials import RealPlan, real_capture_paths, real_materials
from clnlos.study.report.page import write_report
from clnlos.study.samples.resolution import json_ready
from clnlos.study.samples.identify import (  # noqa: F401 (re-exported)
    identification_of,
    label_of,
    legibility_label,
    render_plan,
    resolution_geometry,
    study_resolution,
    translation_identification,
)
from clnlos.study.sections import (  # noqa: F401 (re-exported)
    cnn_samples,
    real_capture_dir,
    real_captures_cnn,
    real_data_study,
    samples_labels,
    study_cost,
    train_cnn,
    transport_comparison,
)
from clnlos.study.findings.sweeps import (  # noqa: F401 (re-exported)
    SEED_FIGURE9,
    cnn_material_label,
    material_class,
    material_entries,
    mean_interval,
    smallest_legible,
    specular_fraction,
    sweep_rows,
    tilt_rows,
)


def run_study(out_dir: Path, opts: StudyOptions, *, workers: int | None = None,
              scheduler: str | None = None, device: str | None = None) -> dict:
    """The study of ``opts`` into ``out_dir`` (report.html, results.json, the sample cache):
    the plan rendered, identified, tabled, the sections, the findings, the report; returns
    what results.json holds (its ``timings_s``: each stage's wall time)."""
    opts = opts.validate()
    out_dir.mkdir(parents=True, exist_ok=True)
    cache = out_dir / "cache"
    table = preset_table()
    materials = opts.materials or list(table)
    unknown = [m for m in materials if m not in table]
    if unknown:
        raise ParameterError("materials", unknown[0], "the preset names: " + ", ".join(table))
    nw = cpu_workers(workers) if scheduler is None else 1
    timings = {}
    chance = 1.0 / len(opts.glyphs)

    # -- every sample through one pool (cached)
    plan = study_plan(materials, opts)
    t0 = time.perf_counter()
    results = render_plan(plan, opts.grid, cache, workers=nw, scheduler=scheduler,
                          device=device, desc="study samples")
    timings["samples_s"] = time.perf_counter() - t0

    # -- resolution, identification
    t0 = time.perf_counter()
    resolution, lateral = study_resolution(opts, device)
    identification_of(plan, results, opts, resolution["effective_temporal_fwhm_s"], lateral)
    timings["resolution_s"] = time.perf_counter() - t0

    # -- metrics, labels
    glyph_idx = [i for i, (meta, _) in enumerate(plan) if meta["set"] != "dataset"]
    truth = {k: np.array([results[i][k] for i in glyph_idx], float)
             for k in ("iou", "depth_error_m", "psnr_db", "identified")}
    truth["iou_excess"] = np.array([results[i]["iou"] - results[i]["iou_box_baseline"]
                                    for i in glyph_idx])
    values = {m: np.array([results[i][f"q_{m}"] for i in glyph_idx]) for m in METRICS}
    validation = validate_metrics(values, truth)
    label_metric = LABEL_METRICS[opts.labels]
    all_values = {m: np.array([r[f"q_{m}"] for r in results]) for m in METRICS}
    thresholds = ((0.5, 0.5) if label_metric == "identification"
                  else label_thresholds(all_values[label_metric]))
    fft_thresholds = label_thresholds(all_values["fft_clarity"])

    # -- the materials under both transports (legible geometry)
    comparison = None
    if opts.transport == "both":
        t0 = time.perf_counter()
        comparison = transport_comparison(materials, opts, cache, resolution, lateral,
                                          table, workers=nw, scheduler=scheduler,
                                          device=device)
        timings["transport_s"] = time.perf_counter() - t0

    # -- the legibility judge (simulated twins and every rendered reconstruction with ground
    #    truth) and, for --labels fft / nr, the seed's recipe, whose classes then label the
    #    materials
    t0 = time.perf_counter()
    rendered = [(plan, results)] + ([] if comparison is None else
                                    [(comparison["plan"], comparison["results"])])
    with progress_bar(None, "legibility judge twins", "scene") as bar:
        legibility, classifier, judge, family = study_judge(
            [(s, r) for p, rs in rendered for (_, s), r in zip(p, rs, strict=True)], out_dir,
            per_geometry=opts.judge_twins, seed=opts.seed, cache=cache,
            real_root=opts.real_data, device=device, progress=counter(bar))
    classifier_splits = classifier["splits"]
    predict, seed_cnn = legibility.predict_proba, None
    labels = samples_labels(results, cnn_samples(plan, label_metric), label_metric,
                             thresholds)
    if label_metric != "identification":
        predict, seed_cnn, labels = train_cnn(plan, results, opts, label_metric, thresholds)
    timings["cnn_s"] = time.perf_counter() - t0

    # -- materials per geometry
    geometries = []
    for geo in opts.geometries:
        ents = material_entries(materials, plan, results, geo, opts, table, label_metric,
                                thresholds, fft_thresholds, predict)
        geometries.append({**asdict(geo), "lateral_resolution_m": lateral[geo.name],
                           "stroke_over_resolution": geo.stroke_m / lateral[geo.name],
                           "materials": ents})
    main_geo = next(g for g in geometries if g["name"] == LEGIBLE_GEOMETRY)
    per_material = main_geo["materials"]
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

    # -- sweeps
    legibility_rows = sweep_rows(plan, results, "legibility_sweep", chance)
    geometry_rows = sweep_rows(plan, results, "geometry_sweep", chance)
    tilts = tilt_rows(plan, results, chance)
    need = smallest_legible(legibility_rows, opts.sweep_materials, opts.sweep_inversions)

    # -- real captures (shared data): the simulated twin, the CNN's verdict
    t0 = time.perf_counter()
    cdt = real_capture_dir(opts.real_data)
    real = None if cdt is None else real_data_study(
        cdt, predict, opts.grid, device, legibility=legibility, label_metric=label_metric,
        cache=cache)
    if real is not None and real["chart"] is not None:
        resolution["real_chart"] = real["chart"]
    timings["real_capture_s"] = time.perf_counter() - t0
    if real is not None:
        timings["real_thinning_s"] = real["thinning_s"]

    # -- the material question on the real captures (LCT release, CDT): photons needed
    t0 = time.perf_counter()
    real_section = None
    if opts.real_data is not None and real_capture_paths(opts.real_data):
        real_section = real_materials(opts.real_data, RealPlan.quick() if opts.label == "quick"
                                      else RealPlan(), device)
    timings["real_materials_s"] = time.perf_counter() - t0

    findings = make_findings(geometries, need, geometry_rows, validation, label_metric,
                             classifier_splits, agreement, opts, tilts)
    ious = np.array([r["iou"] for r in results])
    hist, edges = np.histogram(ious, bins=10, range=(0, 1))
    results_json = {
        "study": opts.label,
        "options": {**asdict(opts), "grid": asdict(opts.grid), "workers": nw,
                    "real_data": None if opts.real_data is None else str(opts.real_data)},
        "materials": per_material,
        "geometries": geometries, "legible_geometry": LEGIBLE_GEOMETRY,
        "seed_geometry": next((g["name"] for g in geometries if g["name"] == SEED_GEOMETRY),
                              geometries[0]["name"]),
        "resolution": resolution,
        "inversions": list(opts.inversions),
        "legibility_sweeps": [{"variable": r["variable"], "value": r["value"],
                               "material": r["material"], "inversion": r["inversion"],
                               "identification": r["identification"],
                               "measurement_identification": r["measurement_identification"],
                               "iou": r["iou"],
                               "iou_box_baseline": r["iou_box_baseline"],
                               "iou_excess": r["iou_excess"],
                               "photon_counts": r["photon_counts"], "n": r["n"]}
                              for r in legibility_rows],
        "smallest_legible": need, "tilt_sweep": tilts, "tilt_max_shift_m": TILT_MAX_SHIFT_M,
        "real_capture": None if real is None else real["summary"],
        "real_captures_cnn": None if real is None else [
            {k: v for k, v in c.items() if k != "mip"} for c in real["cnn"]],
        "classifier": {**classifier, "real_thinning": [] if real is None else [
            {k: r[k] for k in ("capture", "fraction", "photons", "p_legible")}
            for r in real["thinning"]]},
        "judge": judge, **({} if seed_cnn is None else {"cnn_seed_recipe": seed_cnn}),
        "labels": {"source": opts.labels, "metric": label_metric,
                   "corr_with_iou": validation[label_metric]["iou"]
                   if label_metric in validation else pearson(truth["identified"],
                                                               truth["iou"]),
                   "thresholds": list(thresholds),
                   "counts": {str(k): int((labels == k).sum()) for k in (1, 2, 3)}},
        "metrics": {m: validation[m]["iou"] for m in METRICS},
        "metric_validation": validation,
        "clarity_thresholds": list(fft_thresholds),
        "label_counts": {str(k): int((labels == k).sum()) for k in (1, 2, 3)},
        "seed_figure9_agreement": int(agreement[LEGIBLE_GEOMETRY]),
        "seed_figure9_agreement_by_geometry": agreement,
        "seed_figure9_agreement_cnn": int(cnn_agreement),
        "seed_figure9_agreement_truth_cut": truth_agreement,
        "label_thresholds_truth_cut": None if truth_cut is None else list(truth_cut),
        "sweeps": geometry_rows,
        "dataset": {"n": len(results), "iou_median": float(np.median(ious)),
                    "iou_histogram": {"edges": edges.tolist(), "counts": hist.tolist()},
                    "iou_zero_fraction": float(np.mean(ious == 0))},
        "findings": findings, "timings_s": timings, "n_dataset": len(results),
        "real_materials": real_section}
    if comparison is not None:
        results_json["transport_comparison"] = {
            **{k: v for k, v in comparison.items() if k not in ("plan", "results")},
            "face_rings": opts.face_rings, "face_angles": opts.face_angles,
            "glyphs": list(opts.transport_glyphs or opts.glyphs),
            "geometry": LEGIBLE_GEOMETRY}
    t0 = time.perf_counter()
    results_json["cost"] = study_cost(plan, results, timings, comparison)
    if real is not None:
        real["family"] = family  # the family split's MIPs, for the report's figure
    write_report(out_dir, results_json, plan, results, real)
    timings["report_s"] = time.perf_counter() - t0
    results_json["cost"] = study_cost(plan, results, timings, comparison)
    results_json["real_materials"] = (None if real_section is None
                                      else json_ready(real_section))  # arrays: the report's
    with atomic_path(out_dir / "results.json") as tmp:
        tmp.write_text(json.dumps(stamp(results_json), indent=1))
    return results_json

