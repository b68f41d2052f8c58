"""The study's tables from its scored samples: per material at each geometry
(:func:`material_entries`), per sweep value (:func:`sweep_rows`), the smallest legible letter
and exposure (:func:`smallest_legible`) and the tilt sweep (:func:`tilt_rows`)."""

from __future__ import annotations

import math

import numpy as np
from scipy.special import stdtrit  # Student's t quantile (what scipy.stats.t.ppf calls)

from clnlos.brdf.models import BRDFModel
from clnlos.brdf.presets import preset_model, preset_table
from clnlos.study.samples.identify import label_of
from clnlos.study.score.legibility import LEGIBLE_ACCURACY, identification_summary, wilson_interval


# The seed's Figure 9 grouping of its ten materials (1 clear, 2 medium, 3 fuzzy).
SEED_FIGURE9 = {
    "aluminium diffuse reflection plate": 1, "standard white plate": 1, "cement board": 1,
    "quartz glass": 2, "aluminium alloy sample": 2, "black anode plate": 2,
    "fuchsia lacquer board": 2,
    "gold-plated polyester film": 3, "painted steel plate": 3, "glass fibre": 3,
}


def specular_fraction(model, theta_i_deg: float = 45.0, n: int = 64) -> float:
    """Share of the directional-hemispherical reflectance at theta_i not from the kd term
    (0 for Lambertian/Minnaert, 1 for a pure microfacet model)."""
    if model is None:
        return 0.0
    th = (np.arange(n) + 0.5) / n * np.pi / 2
    ph = (np.arange(2 * n) + 0.5) / (2 * n) * 2 * np.pi
    T, P = np.meshgrid(th, ph, indexing="ij")
    w = np.cos(T) * np.sin(T) * (np.pi / 2 / n) * (np.pi / n)
    ti = np.radians(theta_i_deg)
    total = float(np.sum(model(ti, 0.0, T, P) * w))
    if total <= 0:
        return 0.0
    spec = BRDFModel(model.name, {**model.params, "kd": 0.0})
    return float(np.clip(np.sum(spec(ti, 0.0, T, P) * w) / total, 0, 1))


def mean_interval(x) -> tuple[float, list[float]]:
    """Mean and its 95% t-interval [lo, hi] (the mean itself for one value)."""
    a = np.asarray(x, float)
    m = float(a.mean())
    if a.size < 2 or a.std() == 0:
        return m, [m, m]
    h = float(stdtrit(a.size - 1, 0.975) * a.std(ddof=1) / math.sqrt(a.size))
    return m, [m - h, m + h]


def _summary(rows: list[dict], chance: float) -> dict:
    iou_mean, iou_ci = mean_interval([r["iou"] for r in rows])
    box = float(np.mean([r["iou_box_baseline"] for r in rows]))
    return {"identification": identification_summary([r["identified"] for r in rows], chance),
            "measurement_identification": identification_summary(
                [r["measurement_identified"] for r in rows], chance),
            "iou": iou_mean, "iou_ci": iou_ci, "iou_box_baseline": box,
            "iou_excess": iou_mean - box}


def material_class(ident: dict) -> int:
    """A material's legibility at a geometry: 1 identification >= LEGIBLE_ACCURACY, 3 not
    above chance (the Wilson interval reaches 1/K), 2 between."""
    if ident["accuracy"] >= LEGIBLE_ACCURACY:
        return 1
    return 3 if ident["ci"][0] <= ident["chance"] else 2


def material_entries(study, mats, plan, results, target_name: str, label_metric: str,
                     thresholds, fft_thresholds, predict) -> list[dict]:
    """The table's row of every material at one target (a glyph set): identification per
    reflectance assumed, IoU against its box baseline, the labels (the study's, the CNN's,
    the seed's Figure 9 class), the measurement alone."""
    chance = 1.0 / len(study.target(target_name).glyphs)
    presets = preset_table()
    out = []
    for mat in study.materials:
        m = mat.name
        by_inv: dict[str, list[dict]] = {}
        for (meta, _), r in zip(plan, results, strict=True):
            if (meta["set"] == "main" and meta["geometry"] == target_name
                    and meta["material"] == m):
                by_inv.setdefault(meta["inversion"], []).append(r)
        rs = by_inv["lambertian"]
        e = {"name": m, "geometry": target_name, "brdf_class": mats[m].brdf_class,
             **_summary(rs, chance), "iou_seeds": [float(r["iou"]) for r in rs],
             "inversions": {inv: {**_summary(v, chance),
                                  "lobe_halfwidth_deg": [float(r["lobe_halfwidth_deg"])
                                                         for r in v]}
                            for inv, v in by_inv.items()}}
        if label_metric == "identification":
            value = e["identification"]["accuracy"]
            label = material_class(e["identification"])
        else:
            value = float(np.mean([r[f"q_{label_metric}"] for r in rs]))
            label = label_of(value, thresholds)
        fft_mean = float(np.mean([r["q_fft_clarity"] for r in rs]))
        cnn_label, p = (None, np.array([])) if predict is None else cnn_material_label(
            predict, np.stack([r["mip"] for r in rs]), label_metric, chance)
        preset = mat.brdf if mat.brdf in presets else None
        e.update({
            "label": label, "label_metric_value": value,
            "cnn_label": cnn_label, "cnn_probabilities": [float(v) for v in p],
            "seed_label": SEED_FIGURE9.get(preset) if mat.albedo == 1.0 else None,
            "clarity_score": fft_mean, "clarity_label": label_of(fft_mean, fft_thresholds),
            "depth_error_m": float(np.mean([r["depth_error_m"] for r in rs])),
            "psnr_db": float(np.mean([r["psnr_db"] for r in rs])),
            "photon_counts": float(np.mean([r["counts"] for r in rs])),
            "specular_fraction": specular_fraction(preset_model(preset)) if preset else None,
            "provenance": presets[preset].get("provenance", "") if preset else mat.brdf})
        out.append(e)
    return out


def cnn_material_label(predict, mips: np.ndarray, label_metric: str,
                       chance: float) -> tuple[int, np.ndarray]:
    """(the CNN's class of a material, its mean probabilities) from the material's MIPs.
    The legibility classifier (``predict``: images -> P(legible)) gives [P, 1 - P], the mean
    P being its expected share of legible reconstructions, classed like identification
    (:func:`material_class`, the interval of that share of the n MIPs); the seed's recipe
    (``predict``: images -> (labels, probabilities)) the class of its mean probabilities."""
    if label_metric == "identification":
        p = float(np.mean(predict(mips)))
        n = len(mips)
        ident = {"accuracy": p, "ci": wilson_interval(int(round(p * n)), n), "chance": chance}
        return material_class(ident), np.array([p, 1.0 - p])
    _, probs = predict(mips)
    p = probs.mean(axis=0)
    return int(np.argmax(p) + 1), p


def sweep_rows(plan, results, which: str, chance) -> list[dict]:
    """One row per (variable, value, the other swept values, target, method, material,
    inversion) of a sweep set (the refined exposures left to the plan's curves);
    ``chance(target)`` the chance of reading that target."""
    groups: dict = {}
    for (meta, _), r in zip(plan, results, strict=True):
        if meta["set"] == which and not meta.get("refined"):
            groups.setdefault((meta["variable"], meta["value"],
                               tuple(sorted(meta.get("at", {}).items())), meta["target"],
                               meta["method"], meta["material"], meta["inversion"]),
                              []).append(r)
    rows = []
    for (var, v, at, target, method, m, inv), rs in groups.items():
        rows.append({"variable": var, "value": v, "at": dict(at), "target": target,
                     "method": method, "material": m, "inversion": inv, "n": len(rs),
                     **_summary(rs, chance(target)),
                     "photon_counts": float(np.mean([r["counts"] for r in rs])),
                     "depth_error_m": float(np.mean([r["depth_error_m"] for r in rs]))})
    return rows


def smallest_legible(rows: list[dict], materials, inversions=("lambertian",),
                     level: float = LEGIBLE_ACCURACY) -> list[dict]:
    """Per material and inversion: the smallest letter height and the smallest exposure whose
    identification reaches ``level`` (None where no swept value does); per material also the
    best over the inversions (``inversion = "best"``, naming which one gave each number)."""
    def first(var, m, inv):
        ok = sorted(r["value"] for r in rows if r["variable"] == var and r["material"] == m
                    and r["inversion"] == inv and r["identification"]["accuracy"] >= level)
        return ok[0] if ok else None

    out = []
    for m in materials:
        per = [{"material": m, "inversion": inv, "letter_height_m": first("letter_height_m",
                                                                          m, inv),
                "exposure_s": first("exposure_s", m, inv)} for inv in inversions]
        best = {"material": m, "inversion": "best"}
        for var in ("letter_height_m", "exposure_s"):  # a tie goes to the earlier inversion
            have = [(p[var], k, p["inversion"]) for k, p in enumerate(per) if p[var] is not None]
            best[var], _, best[f"{var}_inversion"] = min(have) if have else (None, None, None)
        out += per + [best]
    return out


def tilt_rows(plan, results, chance) -> list[dict]:
    """One row per (tilt, target, method, material): identification up to translation per
    inversion and of the measurement alone, each with the mean displacement of the glyph
    (m), beside a mirror's z tan(tilt); ``chance(target)`` the chance of reading it."""
    groups: dict = {}
    for (meta, s), r in zip(plan, results, strict=True):
        if meta["set"] == "tilt_sweep":
            groups.setdefault((meta["value"], meta["target"], meta["method"],
                               meta["material"]), []).append((meta, s, r))
    rows = []
    for (tilt, target, method, m), entries in sorted(groups.items()):
        chance_t = chance(target)
        row = {"tilt_deg": tilt, "target": target, "method": method, "material": m,
               "mirror_shift_m": entries[0][1]["depth_m"] * math.tan(math.radians(tilt))}
        for inv in dict.fromkeys(meta["inversion"] for meta, _, _ in entries):
            rs = [r for meta, _, r in entries if meta["inversion"] == inv]
            row[inv] = {"identification": identification_summary(
                [r["tilt_identified"] for r in rs], chance_t),
                "shift_m": float(np.mean([r["tilt_shift_m"] for r in rs]))}
        first = "lambertian" if "lambertian" in row else entries[0][0]["inversion"]
        rs = [r for meta, _, r in entries if meta["inversion"] == first]
        row["measurement"] = {"identification": identification_summary(
            [r["tilt_measurement_identified"] for r in rs], chance_t),
            "shift_m": float(np.mean([r["tilt_measurement_shift_m"] for r in rs]))}
        rows.append(row)
    return rows
