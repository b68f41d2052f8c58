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
    material_names,
    preset_names,
    preset_table,
)
from clnlos.brdf.models import BRDFModel, make_model, retro_slice
from clnlos.brdf.texture import checked_retro, read_texture
from clnlos.checks import did_you_mean
from clnlos.errors import ParameterError

def preset_model(name: str) -> BRDFModel:
    return make_model(preset_table()[name]["model"])


def material_retro(material, base_dir, n_theta: int) -> np.ndarray | None:
    """The confocal retro slice f(theta) (1/sr) on ``n_theta`` angles over [0, pi/2] of a
    scene material, or None for Lambertian. ``material``: a model table (dict), a BRDF
    texture file (.h5/.hdf5, its retro slice checked against its model:
    :func:`clnlos.brdf.texture.checked_retro`, one warning line where it was taken from the
    model), a seed preset or an analytic preset name."""
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


__all__ = ["ANALYTIC_PRESETS", "CLASSES", "material_names", "material_retro", "preset_model",
           "preset_names", "preset_table"]
