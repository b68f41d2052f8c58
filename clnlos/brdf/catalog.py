"""The names a BRDF can be given by (pure: no OpenCL, no file formats beyond their tags):
the seed's ten measured-data presets (``presets.json``), the analytic presets, the
reconstruction's ``"lambertian"`` and ``"auto"``, and the format tags of BRDF files.

:mod:`clnlos.brdf.presets` turns a name into a model, :mod:`clnlos.brdf.lobes` into the
retro lobe a reconstruction assumes; the config checks a ``brdf`` spec here
(:func:`check_brdf_spec`) before any work.
"""

from __future__ import annotations

import importlib.resources
import json
from functools import lru_cache
from pathlib import Path

import h5py

from clnlos.brdf.models import BRDFModel
from clnlos.checks import did_you_mean, input_file
from clnlos.errors import InputFileError, ParameterError

# Analytic presets beside the seed's ten measured-data presets (names are case-insensitive);
# None is the Lambertian (no BRDF table).
ANALYTIC_PRESETS: dict[str, BRDFModel | None] = {
    "lambertian": None,
    "matte-dark": BRDFModel("minnaert", {"kd": 0.3, "k": 1.5}),
    "glossy-paint": BRDFModel("phong", {"kd": 0.3, "ks": 0.7, "shininess": 30.0}),
    "brushed-metal": BRDFModel("microfacet", {"kd": 0.0, "ks": 1.0, "alpha": 0.15, "f0": 0.9}),
    "mirror-like": BRDFModel("microfacet", {"kd": 0.0, "ks": 1.0, "alpha": 0.01, "f0": 0.95}),
}

# the retroreflective preset (clnlos.physics.retroreflector): a material of its own, not a
# BRDFModel (its confocal return depends on the distance to the scanned spot, not on theta
# alone); a scene may override its parameters with a table {model = "retroreflective", ...}
RETROREFLECTIVE = "retroreflective"

CLASSES = ("strong specular", "strong specular + diffuse", "strong diffuse", "Lambertian")
LAMBERTIAN = "lambertian"   # a reconstruction's default reflectance
AUTO = "auto"               # a reconstruction's lobe chosen from the capture
TEXTURE_FORMAT = "clnlos-brdf-texture"  # the ``format`` tag of a BRDF texture file
MODEL_FORMAT = "clnlos-brdf-model"      # ... and of a fitted BRDF model file


@lru_cache(maxsize=1)
def preset_table() -> dict:
    text = importlib.resources.files("clnlos.brdf").joinpath("presets.json").read_text()
    return json.loads(text)


def preset_names() -> list[str]:
    return list(preset_table())


def material_names() -> list[str]:
    return ["lambertian", *preset_table(), *(k for k in ANALYTIC_PRESETS if k != "lambertian"),
            RETROREFLECTIVE]


def is_retroreflective(material) -> bool:
    """Whether a scene material (a name or a model table) is the retroreflective preset."""
    if isinstance(material, dict):
        return str(material.get("model", "")).lower() == RETROREFLECTIVE
    return str(material).lower() == RETROREFLECTIVE


def is_file_spec(spec) -> bool:
    return str(spec).lower().endswith((".h5", ".hdf5"))


def file_format(path) -> str:
    """The ``format`` tag of a BRDF file: TEXTURE_FORMAT or MODEL_FORMAT, else an
    InputFileError naming the file."""
    try:
        with h5py.File(path, "r") as f:
            fmt = f.attrs.get("format")
    except OSError as exc:
        raise InputFileError(f"{path}: unreadable as HDF5 ({exc})") from None
    if fmt not in (TEXTURE_FORMAT, MODEL_FORMAT):
        raise InputFileError(f"{path}: neither a BRDF texture ({TEXTURE_FORMAT}) nor a fitted "
                             f"BRDF model ({MODEL_FORMAT}): format {fmt!r}")
    return str(fmt)


def check_brdf_spec(spec, name: str = "brdf", base_dir=".") -> str:
    """A reconstruction's ``brdf`` spec, checked: ``"lambertian"``, ``"auto"``, a material
    name (lower-cased) or an existing BRDF texture / model file; else a ParameterError (or
    InputFileError) naming ``name``."""
    allowed = "\"lambertian\", \"auto\", a material name or a BRDF texture / model .h5"
    if not isinstance(spec, str) or not spec:
        raise ParameterError(name, spec, allowed)
    if is_file_spec(spec):
        file_format(input_file(Path(base_dir) / spec, "BRDF "))
        return spec
    key = spec.lower()
    names = material_names()
    if key != AUTO and key not in names:
        raise ParameterError(name, spec, "\"auto\", " + ", ".join(names) + " or a BRDF "
                             "texture / model .h5" + did_you_mean(key, [*names, AUTO]))
    return key
