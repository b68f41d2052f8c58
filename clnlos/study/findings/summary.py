"""The study's answer in numbers (:func:`make_findings`: per geometry, class and inversion,
the sweeps' effects, the tilt sweep) and in words (:func:`study_statement`)."""

from __future__ import annotations

import numpy as np

from clnlos.study.file.spec import REFLECTANCES, Study
from clnlos.study.score.quality import pearson


GAP_CLOSED = 1 / 8  # strong-specular identification within one glyph in eight of diffuse


def _class_mean(entries, classes, key) -> float | None:
    vals = [key(m) for m in entries if m["brdf_class"] in classes]
    return float(np.mean(vals)) if vals else None


def inversion_accuracy(m: dict, inversion: str) -> float | None:
    """A material entry's identification accuracy with one inversion (None if not run)."""
    if inversion == "lambertian":
        return m["identification"]["accuracy"]
    v = m.get("inversions", {}).get(inversion)
    return None if v is None else v["identification"]["accuracy"]


def make_findings(geometries, need, geometry_rows, validation, label_metric,
                  classifier_splits, agreement, study: Study, tilts=(), classes=None) -> dict:
    """The study's answer in numbers, from its table (the roles its ``legible_target`` and
    ``seed_target`` play) and sweeps; ``classes``: {material: BRDF class}."""
    legible_name, seed_name = study.table.legible_target, study.table.seed_target
    inversions = study.table.reflectance
    def acc(m):
        return m["identification"]["accuracy"]

    def by_class(ms, classes, inv):
        vals = [inversion_accuracy(m, inv) for m in ms if m["brdf_class"] in classes]
        vals = [v for v in vals if v is not None]
        return float(np.mean(vals)) if vals else None

    f: dict = {"by_geometry": {}}
    for g in geometries:
        ms = g["materials"]
        spec = np.array([m["specular_fraction"] for m in ms])
        f["by_geometry"][g["name"]] = {
            "identification_lambertian_and_diffuse": _class_mean(
                ms, ("Lambertian", "strong diffuse"), acc),
            "identification_strong_specular": _class_mean(ms, ("strong specular",), acc),
            "measurement_identification_strong_specular": _class_mean(
                ms, ("strong specular",),
                lambda m: m["measurement_identification"]["accuracy"]),
            "measurement_identification_lambertian_and_diffuse": _class_mean(
                ms, ("Lambertian", "strong diffuse"),
                lambda m: m["measurement_identification"]["accuracy"]),
            "identification_specular_plus_diffuse": _class_mean(
                ms, ("strong specular + diffuse",), acc),
            "iou_excess_lambertian_and_diffuse": _class_mean(
                ms, ("Lambertian", "strong diffuse"), lambda m: m["iou_excess"]),
            "iou_excess_strong_specular": _class_mean(ms, ("strong specular",),
                                                      lambda m: m["iou_excess"]),
            "corr_specular_fraction_vs_identification": pearson(
                spec, np.array([acc(m) for m in ms])),
            "stroke_over_resolution": g["stroke_over_resolution"],
            "by_inversion": {inv: {
                "strong_specular": by_class(ms, ("strong specular",), inv),
                "specular_plus_diffuse": by_class(ms, ("strong specular + diffuse",), inv),
                "lambertian_and_diffuse": by_class(ms, ("Lambertian", "strong diffuse"), inv)}
                for inv in inversions}}
    main = f["by_geometry"][legible_name]
    seed = f["by_geometry"].get(seed_name) if seed_name else None
    # keep today's keys, now about the legible geometry
    legible_ms = next(g for g in geometries if g["name"] == legible_name)["materials"]
    ious = np.array([m["iou"] for m in legible_ms])
    spec = np.array([m["specular_fraction"] for m in legible_ms])
    f.update({
        "corr_specular_fraction_vs_iou_materials": pearson(spec, ious),
        "iou_mean_lambertian_and_diffuse": _class_mean(legible_ms, ("Lambertian",
                                                                    "strong diffuse"),
                                                       lambda m: m["iou"]),
        "iou_mean_strong_specular": _class_mean(legible_ms, ("strong specular",),
                                                lambda m: m["iou"]),
        "iou_mean_specular_plus_diffuse": _class_mean(legible_ms,
                                                      ("strong specular + diffuse",),
                                                      lambda m: m["iou"]),
        "iou_spread_materials": float(ious.max() - ious.min()),
        "label_corr_with_iou": validation.get(label_metric, {}).get("iou"),
        "corr_clarity_vs_iou_dataset": validation["fft_clarity"]["iou"],
        "corr_clarity_vs_identified": validation["fft_clarity"]["identified"],
        "corr_nr_clarity_vs_identified": validation["nr_clarity"]["identified"],
        "corr_clarity_vs_depth_error_dataset": validation["fft_clarity"]["depth_error_m"],
        "corr_clarity_vs_psnr_dataset": validation["fft_clarity"]["psnr_db"],
        "cnn_balanced_accuracy": {k: v["balanced_accuracy"]
                                  for k, v in classifier_splits.items()},
        "cnn_one_feature_baseline": {k: v["baseline"] for k, v in classifier_splits.items()},
        "seed_figure9_agreement": agreement[legible_name]})
    # material cost in photons and size, per inversion and with the best for each
    f["smallest_legible"] = need
    f["sweeps"] = geometry_sweep_effects(geometry_rows)
    spread = [(float(np.ptp([s["identification"]["accuracy"] for s in geometry_rows
                             if (s["variable"], s["value"]) == key])), key)
              for key in {(s["variable"], s["value"]) for s in geometry_rows}]
    if spread:
        best, (var, val) = max(spread)
        f["largest_material_spread"] = {"variable": var, "value": val,
                                        "identification_spread": best}
    ld, sp = main["identification_lambertian_and_diffuse"], main["identification_strong_specular"]
    f["seed_conclusion_holds"] = bool(ld is not None and sp is not None and ld > sp)
    aware = [inv for inv in inversions if inv != "lambertian"]
    best_sp = max([v for v in (main["by_inversion"][inv]["strong_specular"] for inv in aware)
                   if v is not None], default=None)
    f["brdf_aware_closes_gap"] = bool(best_sp is not None and ld is not None
                                      and best_sp >= ld - GAP_CLOSED)
    tilt_invs = [inv for inv in REFLECTANCES if any(inv in r for r in tilts)]
    f["tilt"] = tilt_findings(tilts, tilt_invs, classes or {})
    f["statement"] = study_statement(main, seed, need, f, study)
    return f


def geometry_sweep_effects(geometry_rows) -> dict:
    """Per geometry variable: the identification range per material (geometry's effect)
    beside the spread across materials at each value (the material's effect)."""
    effect = {}
    for var in sorted({s["variable"] for s in geometry_rows}):
        rows = [s for s in geometry_rows if s["variable"] == var]
        per_m = {}
        for m in sorted({s["material"] for s in rows}):
            ys = [s["identification"]["accuracy"] for s in rows if s["material"] == m]
            per_m[m] = {"min": float(min(ys)), "max": float(max(ys)),
                        "range": float(max(ys) - min(ys))}
        geometry = float(np.mean([v["range"] for v in per_m.values()]))
        vals = sorted({s["value"] for s in rows})
        material = float(np.mean([np.ptp([s["identification"]["accuracy"] for s in rows
                                           if s["value"] == v]) for v in vals]))
        effect[var] = {"per_material": per_m, "geometry_effect": geometry,
                       "material_effect": material,
                       "dominant": "geometry" if geometry > material else "material"}
    return effect


def tilt_findings(tilts, inversions, classes: dict) -> dict:
    """Per tilt: the mean identification (up to translation) of the strong-specular tilt
    materials (``classes``: {material: BRDF class}) per inversion and of the measurement, and
    the worst gap of any (material, tilt) cell's best inversion below the measurement."""
    out: dict = {"per_tilt": {}, "worst_gap_below_measurement": None}
    gaps = []
    for t in sorted({r["tilt_deg"] for r in tilts}):
        rows = [r for r in tilts if r["tilt_deg"] == t]
        spec = [r for r in rows if classes.get(r["material"]) == "strong specular"]
        entry = {}
        for inv in (*inversions, "measurement"):
            vals = [r[inv]["identification"]["accuracy"] for r in spec if inv in r]
            entry[inv] = float(np.mean(vals)) if vals else None
        out["per_tilt"][f"{t:g}"] = entry
        for r in rows:
            best = max(r[inv]["identification"]["accuracy"] for inv in inversions if inv in r)
            gaps.append((r["measurement"]["identification"]["accuracy"] - best,
                         r["material"], t))
    if gaps:
        g, m, t = max(gaps)
        out["worst_gap_below_measurement"] = {"gap": float(g), "material": m, "tilt_deg": t}
    return out


def swept_values(study: Study, var: str) -> list[float]:
    """Every value any of the study's sweeps gives ``var``."""
    return sorted({v for s in study.sweeps for k, vals in s.values if k == var for v in vals})


def study_statement(main: dict, seed: dict | None, need: list[dict], f: dict,
                    study: Study) -> str:
    """The study's answer in words, every number naming the inversion it comes from."""
    chance = 1.0 / len(study.target(study.table.legible_target).glyphs)

    def pct(v):
        return "n/a" if v is None else f"{100 * v:.0f}%"

    inv = main["by_inversion"]
    aware = [i for i in study.table.reflectance if i != "lambertian"]
    names = {"known": "with the material's own BRDF", "auto": "with the lobe chosen from the "
             "capture (brdf auto)"}
    aware_txt = "; ".join(
        f"{names[i]}: strong-specular {pct(inv[i]['strong_specular'])}, mixed "
        f"{pct(inv[i]['specular_plus_diffuse'])}, Lambertian and strong-diffuse "
        f"{pct(inv[i]['lambertian_and_diffuse'])}" for i in aware)
    best = [n for n in need if n["inversion"] == "best"]

    def cost(n, var, unit):
        """The threshold in words, never beyond the sweep: at the smallest value tried it
        is an upper bound, where none reached it a lower one."""
        swept = swept_values(study, var)
        if n[var] is None:
            return (f"{n['material']}: > {swept[-1]:g} {unit} (the largest tried)" if swept
                    else f"{n['material']}: not within the swept values")
        at = f"<= {n[var]:g} {unit} (the smallest tried)" if swept and n[var] <= swept[0] \
            else f"{n[var]:g} {unit}"
        return f"{n['material']}: {at} ({n[f'{var}_inversion']} inversion)"

    tilt = f["tilt"]["per_tilt"]
    tilt_txt = "; ".join(
        f"{t} deg: " + ", ".join(f"{k} {pct(v)}" for k, v in e.items()) for t, e in tilt.items())
    text = (
        f"At the legible geometry (stroke / resolution {main['stroke_over_resolution']:.1f}) "
        f"the Lambertian inversion identifies Lambertian and strong-diffuse targets in "
        f"{pct(main['identification_lambertian_and_diffuse'])} of reconstructions, "
        f"strong-specular ones in {pct(main['identification_strong_specular'])} and mixed "
        f"ones in {pct(main['identification_specular_plus_diffuse'])} (chance "
        f"{pct(chance)}). The time-integrated measurement alone is identified in "
        f"{pct(main['measurement_identification_strong_specular'])} for strong-specular "
        f"targets: their data hold the glyph. A BRDF-aware inversion reads what the data "
        f"hold ({aware_txt}). "
        + (f"At the seed's Table 1 geometry (stroke / resolution "
           f"{seed['stroke_over_resolution']:.1f}) the Lambertian inversion identifies diffuse "
           f"targets in {pct(seed['identification_lambertian_and_diffuse'])} and "
           f"strong-specular ones in {pct(seed['identification_strong_specular'])}; "
           + "; ".join(f"{names[i]} strong-specular "
                       f"{pct(seed['by_inversion'][i]['strong_specular'])}" for i in aware
                       if seed["by_inversion"][i]["strong_specular"] is not None)
           + ". " if seed else "")
        + f"Smallest legible letters (identification >= {study.legible_fraction:g}, the best "
        f"inversion for each material): "
        + "; ".join(cost(n, "letter_height_m", "m") for n in best)
        + ". Exposure per scan point needed: "
        + "; ".join(cost(n, "exposure_s", "s") for n in best) + ". "
        + (f"Tilted strong-specular glyphs, matched up to a translation (identification): "
           f"{tilt_txt}. " if tilt else "")
        + ("With the Lambertian inversion less specular targets are read more often, as the "
           "seed concluded; " if f["seed_conclusion_holds"] else
           "With the Lambertian inversion the seed's conclusion (less specular -> clearer) is "
           "not supported; ")
        + ("with an inversion that knows the lobe, strong-specular targets are read about as "
           "often as diffuse ones: the seed's ranking is the Lambertian assumption's, not the "
           "material's." if f["brdf_aware_closes_gap"] else
           "a BRDF-aware inversion does not close the gap: the material itself costs "
           "legibility here."))
    return text


def _duration(s: float) -> str:
    """A time in the unit that reads best (s, ms, us)."""
    if s >= 1:
        return f"{s:.3g} s"
    return f"{s * 1e3:.3g} ms" if s >= 1e-3 else f"{s * 1e6:.3g} us"


def need_text(row: dict) -> str:
    """One row of the plan in words: the exposure per scan point and the photons per
    capture needed, never beyond the sweep."""
    lo, hi = row["exposure_needed_interval_s"]
    if row["status"] == "beyond the sweep":
        return f"more than {_duration(row['bracket_s'][0])} per scan point (beyond the sweep)"
    if row["status"] == "at most the smallest exposure":
        return f"at most {_duration(hi)} per scan point (the smallest exposure tried)"
    return (f"{_duration(row['exposure_needed_s'])} per scan point ({_duration(lo)} to "
            f"{_duration(hi)}; {row['photons_needed']:.3g} photons per capture)")


def plan_statement(rows: list[dict], study: Study, letters: list[dict]) -> str:
    """The plan's answer in words: per target and material, the exposure each inversion
    needs and which needs the least; the smallest legible letters."""
    if not rows:
        return "No exposure was swept: the study answers no exposure needed."
    out = []
    level = f"{100 * study.legible_fraction:.0f}%"
    for target in dict.fromkeys(r["target"] for r in rows):
        for material in dict.fromkeys(r["material"] for r in rows if r["target"] == target):
            mine = [r for r in rows if r["target"] == target and r["material"] == material]
            parts = [f"{r['method']} {r['reflectance']}: {need_text(r)}" for r in mine]
            best = [r for r in mine if r.get("best")]
            tail = (f"; best: {best[0]['method']} {best[0]['reflectance']}" if best
                    else "; no inversion reads it within the sweep")
            at = mine[0]["at"]
            where = (" at " + ", ".join(f"{k} = {v:g}" for k, v in at.items())) if at else ""
            out.append(f"{material}, {target}{where}: legible in {level} of realisations "
                       f"from " + "; ".join(parts) + tail + ".")
    for L in letters:
        if L["letter_height_m"] is not None:
            out.append(f"Smallest legible letter ({L['material']}, {L['method']} "
                       f"{L['reflectance']}, {_duration(L['exposure_s'])} per scan point): "
                       f"{100 * L['letter_height_m']:.3g} cm.")
    return " ".join(out)
