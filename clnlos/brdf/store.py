"""Saving and loading fitted BRDF models (HDF5, ``format = "clnlos-brdf-model"``).

Analytic models store their name and parameters; neural models store the network weights
(one dataset per tensor) and their configuration. Both carry the fit metrics and the data
provenance as JSON attributes.
"""

from __future__ import annotations

import json

import h5py
import numpy as np

from clnlos.brdf.catalog import MODEL_FORMAT
from clnlos.brdf.mlp import NeuralBRDF
from clnlos.brdf.models import BRDFModel
from clnlos.checks import input_file
from clnlos.errors import InputFileError
from clnlos.io.files import write_h5

FORMAT = MODEL_FORMAT


class FitQualityWarning(UserWarning):
    """A BRDF fit that is not usable (docs/brdf.md, "A usable fit"), or a texture or scene
    that uses one."""


def fit_warning(metrics: dict, source) -> str | None:
    """The warning a fit's metrics carry (``fit_quality["warning"]``, written by
    :func:`clnlos.brdf.fit.fit_to_file` for a fit that is not usable or has a parameter at a
    bound), naming ``source`` (the model file, a texture of it); None for a fit without one
    or one fitted before fits said so."""
    quality = metrics.get("fit_quality") if isinstance(metrics, dict) else None
    if not isinstance(quality, dict) or not quality.get("warning"):
        return None
    return f"{source}: {quality['warning']}"


def save_model(path, model, metrics: dict, provenance: dict) -> None:
    attrs = {"format": FORMAT, "version": 1, "metrics": json.dumps(metrics),
             "provenance": json.dumps(provenance)}
    if isinstance(model, NeuralBRDF):
        attrs.update(kind="mlp", meta=json.dumps(model.meta()))
        data = {f"weights/{k}": v for k, v in model.state().items()}
    else:
        attrs.update(kind="analytic", model=model.name, params=json.dumps(model.params))
        data = {}
    write_h5(path, data, attrs)


def load_model(path):
    path = input_file(path, "BRDF model ")
    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") != FORMAT:
                raise InputFileError(f"{path}: not a clnlos BRDF model file")
            kind = f.attrs["kind"]
            meta = {"metrics": json.loads(f.attrs.get("metrics", "{}")),
                    "provenance": json.loads(f.attrs.get("provenance", "{}"))}
            if kind == "mlp":
                state = {k: np.asarray(v) for k, v in f["weights"].items()}
                return NeuralBRDF.from_state(state, json.loads(f.attrs["meta"])), meta
            return BRDFModel(str(f.attrs["model"]), json.loads(f.attrs["params"])), meta
    except OSError as exc:
        raise InputFileError(f"{path}: unreadable ({exc})") from None
