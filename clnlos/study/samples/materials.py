"""A study's materials made ready for its scenes and inversions (:func:`prepare_materials`):
a preset as it is, a BRDF texture as it is, a fitted model (``clnlos brdf fit``) tabulated
into a texture for the simulation, a measured gonio CSV fitted first (``clnlos brdf fit
--model auto`` on a seeded 80% of its rows, :func:`clnlos.brdf.fit.fit_to_file`; its
quality measured on the other 20%, a fit that is not usable said in a warning). What is made
is written under ``OUT/materials/``, named by the source file's SHA-256, and reused while
that file is unchanged."""

from __future__ import annotations

import warnings
from pathlib import Path


from clnlos.brdf.catalog import ANALYTIC_PRESETS, LAMBERTIAN, RETROREFLECTIVE, preset_table
from clnlos.brdf.data import read_gonio_csv
from clnlos.brdf.fit import AUTO, fit_to_file, validation_split
from clnlos.brdf.lobes import retro_lobe
from clnlos.brdf.models import model_spec
from clnlos.brdf.store import load_model
from clnlos.brdf.texture import tabulate, write_texture
from clnlos.study.file.spec import Material, Study
from clnlos.study.plan.entries import MaterialKeys

HELD_OUT_FRACTION = 0.2     # of a measured CSV's rows, held out to say how good its fit is


def _made(out_dir: Path, m: Material, what: str) -> Path:
    return out_dir / "materials" / f"{Path(m.brdf).stem}-{m.sha256[:12]}.{what}.h5"


def texture_of_model(model_path: Path, texture_path: Path) -> None:
    """Tabulate a fitted model file into a texture (what ``clnlos brdf texture`` writes)."""
    model, meta = load_model(model_path)
    spec = model_spec(model)
    texture_path.parent.mkdir(parents=True, exist_ok=True)
    write_texture(texture_path, tabulate(model, provenance={
        "model_file": str(model_path), **meta, **({} if spec is None else {"model_spec": spec})}))


def _fit_file(m: Material, out_dir: Path, seed: int) -> tuple[Path, dict]:
    """The model file of a measured CSV (fitted now by ``auto``, or read back), with its fit
    metrics (``fit_quality``: the held-out agreement and peak error, whether it is usable)."""
    path = _made(out_dir, m, "model")
    if not path.is_file():
        train, test = validation_split(read_gonio_csv(m.brdf), seed, HELD_OUT_FRACTION)
        path.parent.mkdir(parents=True, exist_ok=True)
        fit_to_file(AUTO, train, test, path, seed=seed)
    return path, load_model(path)[1]["metrics"]


def brdf_class(m: Material, flat: bool) -> str:
    """The seed's class of a preset; "retroreflective"; "Lambertian" for a flat lobe; else
    "measured" (a file's lobe)."""
    if m.brdf in preset_table():
        return preset_table()[m.brdf]["class"]
    if m.brdf == RETROREFLECTIVE:
        return "retroreflective"
    if flat:
        return "Lambertian"
    return "analytic" if m.brdf in ANALYTIC_PRESETS else "measured"


def prepare_material(m: Material, out_dir: Path, seed: int = 0, warned: set | None = None
                     ) -> tuple[MaterialKeys, dict]:
    """(what samples hold of ``m`` and the inversion assumes, a record for results.json: the
    files made, a measured BRDF's fit and whether it is usable); a fit's warning is given
    once per file (``warned``: the SHA-256 of those already said)."""
    warned = set() if warned is None else warned
    record: dict = {"name": m.name, "brdf": m.brdf, "albedo": m.albedo, "kind": m.kind}
    sample: dict = {}
    if m.kind == "preset":
        scene, known = m.brdf, m.brdf
    elif m.kind == "texture":
        scene, known = m.brdf, m.brdf
        sample["material_sha256"] = m.sha256
    else:
        if m.kind == "measured":
            model_path, metrics = _fit_file(m, out_dir, seed)
            quality = metrics["fit_quality"]
            record["fit"] = {"model": metrics["model"], **quality,
                             "candidates": metrics.get("auto", {}).get("candidates", {})}
            record["fit_usable"] = bool(quality["usable"])
            if quality.get("warning") and m.sha256 not in warned:
                warned.add(m.sha256)
                warnings.warn(f"material {m.name!r} ({m.brdf}): {quality['warning']}",
                              UserWarning, stacklevel=2)
        else:
            model_path = Path(m.brdf)
        tex = _made(out_dir, m, "texture")
        if not tex.is_file():
            texture_of_model(model_path, tex)
        scene, known = str(tex), str(model_path)
        record["model_file"], record["texture_file"] = str(model_path), str(tex)
        sample["material_sha256"] = m.sha256
    sample = {"material": scene, **sample}
    if m.albedo != 1.0:
        sample["albedo"] = m.albedo
    retro = m.brdf == RETROREFLECTIVE
    flat = m.brdf == LAMBERTIAN or (not retro and retro_lobe(known).flat)
    keys = MaterialKeys(m.name, sample, None if flat else known, retro, flat,
                        brdf_class(m, flat))
    record["brdf_class"] = keys.brdf_class
    return keys, record


def prepare_materials(study: Study, out_dir: Path) -> tuple[dict[str, MaterialKeys], list]:
    """Every material of the study (and of its real captures) made ready: ({name: keys},
    the records)."""
    mats, records = {}, []
    every = list(study.materials) + [r.material for r in study.real
                                     if r.material.name not in {m.name for m in
                                                                study.materials}]
    warned: set = set()
    for m in every:
        mats[m.name], rec = prepare_material(m, out_dir, study.seed, warned)
        records.append(rec)
    return mats, records
