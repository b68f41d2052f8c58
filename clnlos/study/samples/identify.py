"""The study's samples rendered and scored: each distinct scene of a plan once through the
dataset's pool (:func:`render_plan`), the resolution the glyph templates are blurred to
(:func:`study_resolution`) and every glyph reconstruction identified against them
(:func:`identification_of`)."""

from __future__ import annotations

import json
import math
from pathlib import Path

from clnlos.forward.scene import Scene
from clnlos.study.plan.scenes import StudyGrid, scene_dict, window_m
from clnlos.study.samples.render import run_samples
from clnlos.study.score.legibility import best_shift, glyph_templates, identify
from clnlos.study.plan.entries import (
    DEFAULT_EXPOSURE_S,
    SEED_GEOMETRY,
    TILT_MAX_SHIFT_M,
    Geometry,
    StudyOptions,
)
from clnlos.study.samples.resolution import (
    ResolutionGeometry,
    json_ready,
    measure_resolution,
    otoole_lateral_bound_m,
)


def render_plan(plan, grid: StudyGrid, cache: Path, **kw) -> list[dict]:
    """The result of every plan entry; each distinct scene rendered once (cached)."""
    keys = [json.dumps(s, sort_keys=True) for _, s in plan]
    unique = list(dict.fromkeys(keys))
    res = run_samples([json.loads(k) for k in unique], grid, cache, **kw)
    by_key = dict(zip(unique, res, strict=True))
    return [by_key[k] for k in keys]


def label_of(value: float, thresholds: tuple[float, float]) -> int:
    t_clear, t_fuzzy = thresholds
    return 1 if value >= t_clear else (3 if value < t_fuzzy else 2)


def legibility_label(identified: bool, iou: float, iou_box: float) -> int:
    """A reconstruction's legibility class: 1 identified and its IoU above the box baseline,
    2 one of the two, 3 neither."""
    return 1 if identified and iou > iou_box else (2 if identified or iou > iou_box else 3)


def resolution_geometry(geo: Geometry, grid: StudyGrid) -> ResolutionGeometry:
    """Where :func:`~clnlos.study.samples.resolution.measure_resolution` measures a study geometry:
    its scan, depth, slab and letters on the study's grid (bins, pulse, window, iterations)."""
    return ResolutionGeometry(
        scan_width_m=geo.scan_width_m, points=grid.points, depth_m=geo.depth_m,
        bin_width_s=grid.bin_width_s, pulse_width_s=grid.pulse_width_s,
        max_path_m=window_m({"depth_m": geo.depth_m}, grid), iterations=grid.iterations,
        snr_rule=grid.snr_rule,
        text="E", letter_height_m=geo.letter_height_m, stroke_m=geo.stroke_m)


def study_resolution(opts: StudyOptions, device) -> tuple[dict, dict[str, float]]:
    """(results.json ``resolution``: every method, noise-free and at the budget, at the seed
    geometry; the study method's noise-free lateral FWHM at each geometry, m). A FWHM that
    cannot be measured (the profile never falls to half) falls back to O'Toole's bound."""
    seed_geo = next((g for g in opts.geometries if g.name == SEED_GEOMETRY),
                    opts.geometries[0])
    method = opts.grid.method
    res = measure_resolution(resolution_geometry(seed_geo, opts.grid), grid=opts.grid,
                             queue=device, exposure_s=DEFAULT_EXPOSURE_S)
    res = json_ready(res)
    gamma = res["effective_temporal_fwhm_s"]
    lateral = {}
    for geo in opts.geometries:
        r = res if geo.name == seed_geo.name else measure_resolution(
            resolution_geometry(geo, opts.grid), grid=opts.grid, queue=device,
            exposure_s=None, methods=(method,))
        fwhm = r[method]["lateral_fwhm_m"]
        lateral[geo.name] = (fwhm if fwhm is not None else
                             otoole_lateral_bound_m(geo.scan_width_m, geo.depth_m, gamma))
    return res, lateral


def identification_of(plan, results, opts: StudyOptions, gamma_s: float,
                      lateral: dict[str, float]) -> None:
    """Adds ``identified``, ``identified_as``, ``margin`` and ``legibility`` to every glyph
    result: its MIP matched to the closest of the K templates blurred to the lateral
    resolution (measured at the study's geometries, O'Toole's bound with the measured
    temporal FWHM elsewhere)."""
    measured = {(g.scan_width_m, g.depth_m): lateral[g.name] for g in opts.geometries}
    templates = {}
    for (meta, s), r in zip(plan, results, strict=True):
        if meta["set"] == "dataset":
            continue
        key = (s["scan_width_m"], s["height_m"], s["stroke_m"], s["depth_m"])
        if key not in templates:
            scene = Scene.from_dict(scene_dict(s, opts.grid))
            fwhm = measured.get((s["scan_width_m"], s["depth_m"]))
            if fwhm is None:  # resolution depends on the scan and the depth only
                fwhm = otoole_lateral_bound_m(s["scan_width_m"], s["depth_m"], gamma_s)
            templates[key] = glyph_templates(s["height_m"], s["stroke_m"], (0.0, 0.0),
                                             scene.scan_centres(), fwhm, opts.glyphs)
        best, margin, scores = identify(r["mip"], templates[key])
        r["identified_as"], r["margin"] = best, margin
        # the true glyph's NCC and its margin over the best other (> 0: identified)
        r["ncc_true"] = scores[s["text"]]
        r["true_margin"] = scores[s["text"]] - max(
            (v for g, v in scores.items() if g != s["text"]), default=-1.0)
        r["identified"] = bool(best == s["text"])
        # the time-integrated measurement matched the same way (no reconstruction at all)
        r["measurement_identified"] = bool(identify(r["meas_image"], templates[key])[0]
                                           == s["text"])
        r["legibility"] = legibility_label(r["identified"], r["iou"], r["iou_box_baseline"])
        if meta["set"] == "tilt_sweep":
            translation_identification(r, s, templates[key], opts.grid)


def translation_identification(r: dict, sample: dict, templates: dict, grid: StudyGrid) -> None:
    """The tilt sweep's identification (keys ``tilt_*``, beside the plain ones a tilt of 0
    shares with the main set): the MIP and the measurement matched up to a translation of
    TILT_MAX_SHIFT_M, with the displacement (m) of the true glyph's best match."""
    pitch = sample["scan_width_m"] / grid.points
    shift = int(math.ceil(TILT_MAX_SHIFT_M / pitch))
    truth = templates[sample["text"]]
    for prefix, img in (("tilt", r["mip"]), ("tilt_measurement", r["meas_image"])):
        r[f"{prefix}_identified"] = bool(identify(img, templates, shift)[0] == sample["text"])
        dy, dx = best_shift(img, truth, shift)
        r[f"{prefix}_shift_m"] = float(math.hypot(dy, dx) * pitch)
