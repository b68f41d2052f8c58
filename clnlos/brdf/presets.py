"""The ten material presets of the seed (four BRDF classes), with provenance.

Parameters live in ``presets.json`` beside this file, written by ``tools/fit_presets.py``:
a GGX microfacet + Lambertian model fitted (log space) to the closest measured set in
the project's shared measured-BRDF data, or documented analytic parameters where no data is
close (the data itself is never copied into the package).
"""

from __future__ import annotations

import importlib.resources
import json
from functools import lru_cache

from .models import BRDFModel, make_model

CLASSES = ("strong specular", "strong specular + diffuse", "strong diffuse", "Lambertian")


@lru_cache(maxsize=1)
def preset_table() -> dict:
    text = importlib.resources.files("clnlos.brdf").joinpath("presets.json").read_text()
    return json.loads(text)


def preset_model(name: str) -> BRDFModel:
    return make_model(preset_table()[name]["model"])


def preset_names() -> list[str]:
    return list(preset_table())
