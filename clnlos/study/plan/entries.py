"""Every (meta, sample) a study renders, from its checked study file (pure: nothing is rendered
here): the material table (:func:`table_entries`), each sweep (:func:`sweep_entries`), the
exposures added where the exposure needed is not yet bracketed finely enough
(:func:`refined_entries`), the random extras and the transport comparison
(:func:`comparison_plan`).

A sample's noise seed comes from what identifies its scene (the target, the letter, the
realisation), not from its material, exposure or inversion: every material and exposure of
one realisation meets the same random stream (common random numbers), so a comparison of
two materials is not a comparison of two noise draws.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

from clnlos.brdf.catalog import AUTO
from clnlos.study.file.spec import GEOMETRY_VARIABLES, Study, Target
from clnlos.study.plan.scenes import bistatic_table, dataset_samples

# which table a sweep of these variables feeds (the findings and the report read them so)
LEGIBILITY_VARIABLES = ("exposure_s", "letter_height_m")


@dataclass(frozen=True)
class MaterialKeys:
    """A study material made ready for the scenes (:mod:`clnlos.study.samples.materials`):
    what a sample holds of it (``sample``: the scene ``material`` spec, ``albedo``, the
    SHA-256 of a file), the ``brdf`` the iterative inversion assumes for "known" (None where
    its retro lobe is flat: the Lambertian reconstruction up to the albedo, which the
    normalised MIP drops, so one sample serves both) and whether it is retroreflective."""

    name: str
    sample: dict
    known: str | None
    retroreflective: bool = False
    flat: bool = False
    brdf_class: str = ""


def noise_seed(base: int, *parts) -> int:
    """A sample's noise seed from what identifies its scene's random stream."""
    return base * 1_000_003 + zlib.crc32("|".join(str(p) for p in parts).encode()) % 1_000_000


def inversion_brdf(method: str, reflectance: str, mat: MaterialKeys
                   ) -> tuple[dict | None, str | None]:
    """(the sample's ``brdf`` entry, None) for an inversion that assumes ``reflectance``
    ("lambertian", "known", "auto") of ``mat``; (None, why) where ``method`` cannot assume it
    (LCT and f-k model a reflectance by their falloff alone: Lambertian or retroreflective;
    "auto" chooses a lobe for the iterative method)."""
    if reflectance == "lambertian":
        return {}, None
    if method == "iterative":
        if reflectance == AUTO:
            return {"brdf": AUTO}, None
        return ({} if mat.flat or mat.known is None else {"brdf": mat.known}), None
    if reflectance == AUTO:
        return None, f"{method}: \"auto\" chooses a lobe for the iterative method only"
    if mat.retroreflective:
        return {"brdf": "retroreflective"}, None
    if mat.flat:
        return {}, None
    return None, (f"{method} assuming {mat.name!r}: LCT and f-k model a reflectance only by "
                  "their falloff (Lambertian or retroreflective), not a glossy lobe")


def target_sample(target: Target, letter: str, mat: MaterialKeys, *, exposure_s: float,
                  seed: int, method: str, brdf: dict, values: dict | None = None,
                  scan_width_m: float) -> dict:
    """The sample of one letter (a glyph of a set, the text) or of the pattern or mask of a
    target in ``mat``, at the swept ``values`` (letter_height_m, depth_m, scan_width_m,
    slab_thickness_m, tilt_deg; the target's own where not swept)."""
    v = values or {}
    s: dict = {"depth_m": float(v.get("depth_m", target.depth_m)),
               "scan_width_m": float(v.get("scan_width_m", target.scan_width_m
                                           or scan_width_m)),
               "rotate_deg": [0.0, float(v.get("tilt_deg", target.tilt_deg)), 0.0],
               "exposure_s": float(exposure_s), "seed": int(seed), "method": method,
               **mat.sample, **brdf}
    h = float(v.get("letter_height_m", target.height_m))
    if target.kind in ("glyphs", "text"):
        s.update(object="letters", text=letter, height_m=round(h, 6),
                 stroke_m=round(target.stroke_m * h / target.height_m, 6))
    elif target.kind == "pattern":
        s.update(object="pattern", pattern=target.pattern, side_m=round(h, 6))
    else:
        s.update(object="mask", mask=target.mask, mask_sha256=target.mask_sha256,
                 width_m=target.width_m, height_m=target.height_m)
    if "slab_thickness_m" in v:
        s["slab_thickness_m"] = float(v["slab_thickness_m"])
    return s


def target_letters(target: Target, glyphs=None) -> tuple[str, ...]:
    """What one realisation of a target renders: each glyph of a set (or the ``glyphs`` a
    sweep narrows it to), the text, or the one pattern or mask ("")."""
    if target.kind == "glyphs":
        return tuple(glyphs) if glyphs else target.glyphs
    return target.letters or ("",)


def sweep_set(variables) -> str:
    """The set a sweep's entries belong to: "legibility_sweep" (exposure and letter height),
    "tilt_sweep", "geometry_sweep" (depth, scan width, slab thickness) or "sweep" (a mix)."""
    v = set(variables)
    if v <= set(LEGIBILITY_VARIABLES):
        return "legibility_sweep"
    if v == {"tilt_deg"}:
        return "tilt_sweep"
    if v <= set(GEOMETRY_VARIABLES):
        return "geometry_sweep"
    return "sweep"


def primary_variable(variables) -> str:
    """The variable a sweep's curves run along: the exposure where it is swept."""
    return "exposure_s" if "exposure_s" in variables else variables[0]


def _entries(study: Study, mats, target: Target, meta: dict, *, letters, realisations,
             methods, reflectances, values, notes: list) -> list:
    exposure = values.get("exposure_s", study.grid.exposure_s)
    out = []
    for m in meta.get("materials", ()):
        for g in letters:
            for k in range(realisations):
                seed = noise_seed(study.seed, target.name, g, k)
                for method in methods:
                    for refl in reflectances(g):
                        brdf, why = inversion_brdf(method, refl, mats[m])
                        if brdf is None:
                            if why not in notes:
                                notes.append(why)
                            continue
                        s = target_sample(target, g, mats[m], exposure_s=exposure, seed=seed,
                                          method=method, brdf=brdf, values=values,
                                          scan_width_m=study.grid.scan_width_m)
                        out.append(({**{k2: v for k2, v in meta.items() if k2 != "materials"},
                                     "material": m, "glyph": g, "k": k, "method": method,
                                     "inversion": refl, "target": target.name}, s))
    return out


def table_entries(study: Study, mats, notes: list) -> list:
    """The material table: every material x table target x glyph x realisation at the
    rig's exposure; the BRDF-aware reflectances on the table's aware glyphs, "auto" at its
    auto targets only."""
    t = study.table
    if t is None:
        return []
    out = []
    for name in t.targets:
        target = study.target(name)
        aware = set(t.aware_glyphs or target.glyphs)
        refl = tuple(r for r in t.reflectance if r != AUTO or t.auto_targets is None
                     or name in t.auto_targets)
        out += _entries(study, mats, target,
                        {"set": "main", "geometry": name,
                         "materials": [m.name for m in study.materials]},
                        letters=target.glyphs, realisations=t.realisations,
                        methods=study.methods[:1],
                        reflectances=lambda g, a=aware, r=refl: tuple(
                            x for x in r if x == "lambertian" or g in a),
                        values={}, notes=notes)
    return out


def sweep_entries(study: Study, mats, notes: list) -> list:
    """Every sweep's grid of values x targets x materials x letters x realisations x
    inversions (meta: ``sweep`` its index, ``variable`` and ``value`` the curve's, ``at``
    the other swept values)."""
    out = []
    for i, s in enumerate(study.sweeps):
        var = primary_variable(s.variables)
        for point in s.grid():
            for name in s.targets:
                target = study.target(name)
                out += _entries(study, mats, target, {
                    "set": sweep_set(s.variables), "sweep": i, "variable": var,
                    "value": point[var],
                    "at": {k: v for k, v in point.items() if k != var},
                    "geometry": name, "materials": list(s.materials)},
                    letters=target_letters(target, s.glyphs), realisations=s.realisations,
                    methods=s.methods, reflectances=lambda g, r=s.reflectance: r,
                    values=point, notes=notes)
    return out


def refined_entries(study: Study, mats, row: dict, exposures) -> list:
    """The entries of one exposure curve (``row``: its sweep, ``at``, target, material,
    method and inversion) at more ``exposures``."""
    s = study.sweeps[row["sweep"]]
    target = study.target(row["target"])
    out = []
    for e in exposures:
        point = {**row["at"], "exposure_s": float(e)}
        out += _entries(study, mats, target, {
            "set": sweep_set(s.variables), "sweep": row["sweep"], "variable": "exposure_s",
            "value": float(e), "at": dict(row["at"]), "geometry": target.name,
            "materials": [row["material"]], "refined": True},
            letters=target_letters(target, s.glyphs), realisations=s.realisations,
            methods=(row["method"],), reflectances=lambda g: (row["inversion"],),
            values=point, notes=[])
    return out


def extra_entries(study: Study, mats) -> list:
    """The classifier's random extras (metric validation, the seed recipe's CNN)."""
    n = study.classifier.extras if study.classifier is not None else 0
    names = [m.name for m in study.materials]
    out = []
    for k, s in enumerate(dataset_samples(n, [{"material": m} for m in names], study.seed)):
        name = s.pop("material")
        out.append(({"set": "dataset", "k": k, "material": name},
                    {**s, **mats[name].sample, "method": study.methods[0]}))
    return out


def study_plan(study: Study, mats) -> tuple[list[tuple[dict, dict]], list[str]]:
    """(every (meta, sample) of the study, the notes of the inversions left out)."""
    notes: list[str] = []
    plan = table_entries(study, mats, notes) + sweep_entries(study, mats, notes)
    return plan + extra_entries(study, mats), notes


def comparison_plan(study: Study, mats) -> list[tuple[dict, dict]]:
    """(meta, sample) of every comparison sample: per material, glyph and noise realisation
    at the table's legible target, once confocal (the table's own sample) and once bistatic
    (the same sample with a ``transport`` table)."""
    tc, t = study.transport, study.table
    target = study.target(t.legible_target)
    table = bistatic_table(tc.face_rings, tc.face_angles)
    plan = []
    for meta, s in _entries(study, mats, target, {
            "set": "transport", "geometry": target.name,
            "materials": [m.name for m in study.materials]},
            letters=tc.glyphs or target.glyphs, realisations=t.realisations,
            methods=study.methods[:1], reflectances=lambda g: ("lambertian",), values={},
            notes=[]):
        plan.append(({**meta, "transport": "confocal"}, s))
        plan.append(({**meta, "transport": "bistatic"}, {**s, "transport": table}))
    return plan
