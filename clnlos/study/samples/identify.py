"""The study's samples rendered and scored: each distinct scene of a plan once through the
pool (:func:`render_plan`), the resolution the templates are blurred to
(:func:`study_resolution`) and every reconstruction judged against its target
(:func:`identification_of`).

Legibility, by what the target is (ground truth: the rule sees the image and the candidates,
never which one is true):

* a glyph of a set: identified among the set's glyphs (chance 1/K);
* a text: every letter read, each among the font's 26 capitals with the others as they are
  (the text's template with that letter swapped for each capital: chance 1/26 a letter);
* a chart: identified among the charts (bar groups upright and lying, dot grids);
* a mask: the IoU of the front view's Otsu mask with the true mask beats the IoU of the true
  mask's filled box (what a blob of the right size and place scores).

Every reading must also beat the blob: the filled box of what it reads (a glyph's box, a
chart's square), the template a featureless blob of the right size and place matches.

Templates are the targets' true coverage blurred to the lateral resolution: measured where
the study measures it (its table's targets), O'Toole's bound c gamma sqrt(w^2 + z^2) / (2 w)
elsewhere, gamma the measured temporal FWHM or, without a measurement, the rig's pulse and
bin added in quadrature. The front view and the templates are compared by their detail
(:func:`~clnlos.study.score.legibility.detail`: each less its blur of DETAIL_PER_HEIGHT
letter heights, rms): what tells letters apart is their strokes, not the mass of their
footprint, which a blurred reconstruction keeps long after its strokes are gone.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from clnlos.forward.geometry import GLYPHS as FONT
from clnlos.forward.geometry import glyph_boxes, letters_mask
from clnlos.forward.scene import Scene
from clnlos.study.file.spec import Study, StudyGrid, Target, rig_slab
from clnlos.study.plan.scenes import rig_temporal_fwhm_s, scene_dict, window_m
from clnlos.study.samples.render import run_samples
from clnlos.study.samples.resolution import (
    ResolutionGeometry,
    json_ready,
    measure_resolution,
    otoole_lateral_bound_m,
)
from clnlos.study.score.legibility import best_shift, detail, glyph_templates, identify
from clnlos.study.score.patterns import CHART_SCALE, TWIN_CHARTS, pattern_mask

DETAIL_PER_HEIGHT = 0.2  # the detail's blur, rms, in letter heights (a chart's: its side)
TILT_MAX_SHIFT_M = 0.2   # the tilt sweep: a tilted mirror's light lands about z tan(tilt) away
CAPITALS = tuple(c for c in FONT if c != " ")


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


def resolution_geometry(target: Target, grid: StudyGrid) -> ResolutionGeometry:
    """Where :func:`~clnlos.study.samples.resolution.measure_resolution` measures a table
    target: its scan, depth, slab and letters on the rig (bins, pulse, window, iterations)."""
    scan = target.scan_width_m or grid.scan_width_m
    return ResolutionGeometry(
        scan_width_m=scan, points=grid.points, depth_m=target.depth_m,
        bin_width_s=grid.bin_width_s, pulse_width_s=grid.pulse_width_s,
        max_path_m=window_m({"depth_m": target.depth_m}, grid), iterations=grid.iterations,
        snr_rule=grid.snr_rule, slab=rig_slab(grid),
        text="E", letter_height_m=target.height_m, stroke_m=target.stroke_m)


def study_resolution(study: Study, device) -> tuple[dict | None, dict[str, float]]:
    """(results.json ``resolution``: every method, noise-free and at the rig's exposure, at
    the table's seed target; the study method's noise-free lateral FWHM at each table target,
    m). Without a table: (None, {}): the templates take O'Toole's bound. A FWHM that cannot be
    measured (the profile never falls to half) falls back to the bound."""
    if study.table is None:
        return None, {}
    t = study.table
    first = study.target(t.seed_target or t.targets[0])
    method = study.grid.method
    res = json_ready(measure_resolution(resolution_geometry(first, study.grid),
                                        grid=study.grid, queue=device,
                                        exposure_s=study.grid.exposure_s))
    gamma = res["effective_temporal_fwhm_s"]
    lateral = {}
    for name in t.targets:
        target = study.target(name)
        r = res if name == first.name else measure_resolution(
            resolution_geometry(target, study.grid), grid=study.grid, queue=device,
            exposure_s=None, methods=(method,))
        fwhm = r[method]["lateral_fwhm_m"]
        lateral[name] = (fwhm if fwhm is not None else otoole_lateral_bound_m(
            target.scan_width_m or study.grid.scan_width_m, target.depth_m, gamma))
    return res, lateral


def chance_of(target: Target) -> float:
    """The chance of reading a target by guessing: 1/K for a set's glyph, (1/26)^letters for
    a text, 1/charts for a chart, 0 for a mask (no candidates: its IoU against its box)."""
    if target.kind == "glyphs":
        return 1.0 / len(target.glyphs)
    if target.kind == "text":
        return float(len(CAPITALS)) ** -len(target.text.replace(" ", ""))
    return 1.0 / len(TWIN_CHARTS) if target.kind == "pattern" else 0.0


BLOB = "blob"   # the candidate of a filled box: what a blob of the right size and place shows


def target_mask(target: Target):
    """The mask function (name, height, stroke, xy) -> inside of a target's candidates: a
    letter text, a chart, or ``"blob:<text>:<i>"``, the text with its i-th letter's glyph
    box filled (``"blob:<chart>"``: the chart's square filled)."""
    def mask(name, h, stroke, xy):
        if name.startswith(BLOB + ":"):
            _, text, *i = name.split(":")
            if target.kind == "pattern":
                side = CHART_SCALE * h
                return (np.abs(xy[:, 0]) <= side / 2) & (np.abs(xy[:, 1]) <= side / 2)
            k = int(i[0]) if i else 0
            x0, x1, y0, y1 = glyph_boxes(text, h, stroke)[k]
            box = (xy[:, 0] >= x0) & (xy[:, 0] <= x1) & (xy[:, 1] >= y0) & (xy[:, 1] <= y1)
            rest = text[:k] + " " + text[k + 1:]
            return box | (letters_mask(rest, h, stroke, xy) if rest.strip() else False)
        if target.kind == "pattern":
            return pattern_mask(name, h, stroke, xy)
        return letters_mask(name, h, stroke, xy)
    return mask


def candidates_of(target: Target, sample: dict) -> tuple[dict[str, str], float, float]:
    """({candidate: the text, chart or blob its template draws}, height, stroke) of a
    sample: a set's glyphs, a text's one-letter swaps (keys "i:C"), the charts; and the
    blob (keys "blob", "i:blob"): a reading must beat the filled box of what it reads."""
    if target.kind == "pattern":
        cands = {c: c for c in TWIN_CHARTS}
        cands[BLOB] = f"{BLOB}:{sample['pattern']}"
        return cands, sample["side_m"] / CHART_SCALE, 0.0
    h, stroke = sample["height_m"], sample["stroke_m"]
    if target.kind == "glyphs":
        return ({**{g: g for g in target.glyphs},
                 BLOB: f"{BLOB}:{sample['text']}:0"}, h, stroke)
    text = sample["text"]
    swaps = {}
    for i, ch in enumerate(text):
        if ch == " ":
            continue
        swaps.update({f"{i}:{c}": text[:i] + c + text[i + 1:] for c in CAPITALS})
        swaps[f"{i}:{BLOB}"] = f"{BLOB}:{text}:{i}"
    return swaps, h, stroke


def _read(img, templates: dict, target: Target, sample: dict, shift=None) -> tuple[bool, str,
                                                                                  float, dict]:
    """(read right, what was read, the margin, every candidate's NCC) of an image; a text is
    read right when each of its letters beats its 25 swaps and its blob."""
    kw = {} if shift is None else {"max_shift": shift}
    if target.kind != "text":
        best, margin, scores = identify(img, templates, **kw)
        truth = sample["pattern"] if target.kind == "pattern" else sample["text"]
        return best == truth, best, margin, scores
    text = sample["text"]
    read, margins, scores = [], [], {}
    for i, ch in enumerate(text):
        if ch == " ":
            read.append(" ")
            continue
        mine = {k: v for k, v in templates.items() if k.startswith(f"{i}:")}
        best, margin, sc = identify(img, mine, **kw)
        read.append(best.split(":")[1])
        margins.append(margin if best == f"{i}:{ch}" else -margin)
        scores.update(sc)
    got = "".join(read)
    return got == text, got, float(min(margins)), scores


def detail_sigma_cells(target: Target, height_m: float, pitch_m: float) -> float:
    """The detail's blur (rms, scan cells): DETAIL_PER_HEIGHT of the letter height, of a
    chart's side."""
    size = height_m * (CHART_SCALE if target.kind == "pattern" else 1.0)
    return DETAIL_PER_HEIGHT * size / pitch_m


def identification_of(plan, results, study: Study, gamma_s: float | None,
                      lateral: dict[str, float], templates: dict | None = None) -> None:
    """Adds ``identified`` (read right; a mask: its IoU beats the box), ``identified_as``,
    ``margin``, ``legibility`` and, for letters and charts, the true candidate's NCC margin
    and the time-integrated measurement read the same way, to every result of a target.
    ``templates``: the drawn templates of earlier calls with the same ``gamma_s`` and
    ``lateral`` (filled here; by default drawn afresh)."""
    gamma = gamma_s if gamma_s is not None else rig_temporal_fwhm_s(study.grid)
    templates = {} if templates is None else templates
    for (meta, s), r in zip(plan, results, strict=True):
        if meta["set"] == "dataset":
            continue
        target = study.target(meta["target"])
        if target.kind == "mask":
            r["identified"] = bool(r["iou"] > r["iou_box_baseline"])
            r["identified_as"], r["margin"] = "", float(r["iou"] - r["iou_box_baseline"])
            r["ncc_true"] = r["true_margin"] = r["margin"]
            r["measurement_identified"] = False
            r["legibility"] = legibility_label(r["identified"], r["iou"], r["iou_box_baseline"])
            continue
        cands, h, stroke = candidates_of(target, s)
        key = (target.name, s["scan_width_m"], h, stroke, s["depth_m"],
               s.get("text", s.get("pattern")))
        if key not in templates:
            scene = Scene.from_dict(scene_dict(s, study.grid))
            fwhm = lateral.get(target.name) if (
                s["scan_width_m"] == (target.scan_width_m or study.grid.scan_width_m)
                and s["depth_m"] == target.depth_m) else None
            if fwhm is None:  # resolution depends on the scan and the depth only
                fwhm = otoole_lateral_bound_m(s["scan_width_m"], s["depth_m"], gamma)
            drawn = glyph_templates(h, stroke, (0.0, 0.0), scene.scan_centres(), fwhm,
                                    tuple(dict.fromkeys(cands.values())), target_mask(target))
            sigma = detail_sigma_cells(target, h, s["scan_width_m"] / study.grid.points)
            templates[key] = ({c: detail(drawn[t], sigma) for c, t in cands.items()}, sigma)
        tmpl, sigma = templates[key]
        mip, meas = detail(r["mip"], sigma), detail(r["meas_image"], sigma)
        ok, got, margin, scores = _read(mip, tmpl, target, s)
        r["identified"], r["identified_as"], r["margin"] = bool(ok), got, float(margin)
        truth = (s["pattern"] if target.kind == "pattern" else s["text"])
        true_key = truth if target.kind != "text" else None
        r["ncc_true"] = float(scores[true_key]) if true_key in scores else float(margin)
        r["true_margin"] = (float(scores[true_key] - max((v for g, v in scores.items()
                                                         if g != true_key), default=-1.0))
                            if true_key in scores else float(margin))
        r["measurement_identified"] = bool(_read(meas, tmpl, target, s)[0])
        r["legibility"] = legibility_label(r["identified"], r["iou"], r["iou_box_baseline"])
        if meta["set"] == "tilt_sweep":
            translation_identification(r, s, tmpl, study.grid, target, (mip, meas))


def translation_identification(r: dict, sample: dict, templates: dict, grid: StudyGrid,
                               target: Target, images) -> None:
    """The tilt sweep's identification (keys ``tilt_*``, beside the plain ones a tilt of 0
    shares with the main set): the MIP and the measurement matched up to a translation of
    TILT_MAX_SHIFT_M, with the displacement (m) of the true candidate's best match;
    ``images``: the (MIP, measurement) details."""
    pitch = sample["scan_width_m"] / grid.points
    shift = int(math.ceil(TILT_MAX_SHIFT_M / pitch))
    truth_key = sample["pattern"] if target.kind == "pattern" else (
        sample["text"] if target.kind == "glyphs" else f"0:{sample['text'][0]}")
    truth = templates[truth_key]
    for prefix, img in zip(("tilt", "tilt_measurement"), images, strict=True):
        r[f"{prefix}_identified"] = bool(_read(img, templates, target, sample, shift)[0])
        dy, dx = best_shift(img, truth, shift)
        r[f"{prefix}_shift_m"] = float(math.hypot(dy, dx) * pitch)
