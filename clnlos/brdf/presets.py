"""The ten material presets of the seed (four BRDF classes), with provenance.

Parameters live in ``presets.json`` beside this file, written by ``tools/fit_presets.py``:
a GGX microfacet + Lambertian model fitted (log space) to the closest measured set in
the project's shared measured-BRDF data, or documented analytic parameters where no data is
close (the data itself is never copied into the package).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from clnlos.brdf.catalog import (
    ANALYTIC_PRESETS,
    CLASSES,
    RETROREFLECTIVE,
    is_retroreflective,
    material_names,
    preset_names,
    preset_table,
)
from clnlos.brdf.models import BRDFModel, make_model, retro_slice
from clnlos.brdf.texture import checked_retro, read_texture
from clnlos.checks import did_you_mean, real
from clnlos.errors import ParameterError
from clnlos.physics.retroreflector import RETRO_LIMITS, Retroreflector

def preset_model(name: str) -> BRDFModel:
    return make_model(preset_table()[name]["model"])


def retroreflector(material, name: str = "material") -> Retroreflector | None:
    """The retroreflector of a scene material: the preset for ``"retroreflective"``, the
    preset with a table's fields overriding it for ``{model = "retroreflective", ...}``
    (fields: :data:`clnlos.physics.retroreflector.RETRO_LIMITS`, each checked against its
    range; ``name`` names the material in an error); None for any other material."""
    if not is_retroreflective(material):
        return None
    over = {}
    if isinstance(material, dict):
        for key, value in material.items():
            if key == "model":
                continue
            if key not in RETRO_LIMITS:
                raise ParameterError(f"{name}.{key}", value, "one of " + ", ".join(
                    RETRO_LIMITS) + " (the retroreflective material's fields)"
                    + did_you_mean(key, list(RETRO_LIMITS)))
            over[key] = real(f"{name}.{key}", value, *RETRO_LIMITS[key])
    return Retroreflector.preset(**over)


def material_retro(material, base_dir, n_theta: int) -> np.ndarray | None:
    """The confocal retro slice f(theta) (1/sr) on ``n_theta`` angles over [0, pi/2] of a
    scene material, or None for Lambertian; for the retroreflective material its diffuse
    part (the cone, which depends on the distance to the scanned spot as well:
    :func:`retroreflector`). ``material``: a model table (dict), a BRDF
    texture file (.h5/.hdf5, its retro slice checked against its model:
    :func:`clnlos.brdf.texture.checked_retro`, one warning line where it was taken from the
    model), a seed preset or an analytic preset name."""
    retro = retroreflector(material)
    if retro is not None:
        return retro.diffuse_slice(np.linspace(0.0, np.pi / 2, n_theta))
    if isinstance(material, dict):
        return retro_slice(make_model(material), n_theta)
    if str(material).endswith((".h5", ".hdf5")):
        path = Path(base_dir) / material
        retro, note = checked_retro(read_texture(path), path, n_theta)
        if note:
            warnings.warn(note, UserWarning, stacklevel=2)
        return retro
    key = str(material).lower()
    if key in preset_table():
        return retro_slice(preset_model(key), n_theta)
    if key not in ANALYTIC_PRESETS:
        names = material_names()
        raise ParameterError("objects.material", material, ", ".join(names) + ", a BRDF "
                             "texture .h5 or a model table" + did_you_mean(key, names))
    model = ANALYTIC_PRESETS[key]
    return None if model is None else retro_slice(model, n_theta)


__all__ = ["ANALYTIC_PRESETS", "CLASSES", "RETROREFLECTIVE", "material_names", "material_retro", "preset_model",
           "preset_names", "preset_table", "retroreflector"]
