"""P(legible) of any capture or reconstruction: what ``clnlos legibility FILE... [--model
STUDY_DIR]`` and ``clnlos.legibility`` run.

The judge is the one shipped with clnlos (package data :data:`SHIPPED_JUDGE`, trained once
by tools/train_judge.py on twins of every kind of target, both rigs, and validated on the
real captures; its provenance is in the file) unless a study's own judge is given
(``model``: a study folder holding judge.json, the file itself or a loaded
:class:`~clnlos.study.judge.model.Judge`).

A *volume* (a clnlos volume .h5 of any method, grid or size, a
:class:`~clnlos.inverse.pipeline.Reconstruction`, or an array [z, y, x] / a MIP [y, x]) is
judged by the MIP-only model, its MIP averaged to the recipe's grid
(:func:`clnlos.study.judge.features.pooled`). A *capture* (any file
:func:`clnlos.io.files.read_capture` reads, or a :class:`~clnlos.io.capture.Capture`) is
reconstructed with the judge's recipe (:func:`clnlos.study.judge.recipe.judge_config`: the
file's contents and the user's options, never its name) together with two binomial halves
of its photons and judged by the capture model (a capture of anything but photon counts is
an error naming the way out: judge its reconstruction). Every verdict carries P's interval
and the notes of what lies outside the judge's training domain
(:mod:`clnlos.study.judge.domain`).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path

import h5py
import numpy as np

from clnlos.config import ReconstructionConfig, load_toml, slab_from_table
from clnlos.errors import InputFileError, ParameterError
from clnlos.inverse.snr import is_counts
from clnlos.io.capture import Capture
from clnlos.io.files import read_capture, read_volume
from clnlos.runtime.device import get_queue
from clnlos.study.judge.features import capture_features, mip_features, mip_of, pooled
from clnlos.study.judge.model import JUDGE_FILE, JUDGE_FORMAT, Judge, load_judge
from clnlos.study.judge.recipe import (
    JUDGE_MAX_POINTS,
    USER_FIELDS,
    binned_laterally,
    capture_descriptors,
    judge_config,
    judge_reconstructions,
)

SHIPPED_JUDGE = "legibility_judge.json"   # in the package clnlos.data


@dataclass
class Verdict:
    """The judge's answer for one input: ``p_legible``, its ``interval`` [lo, hi] (None for
    a judge that keeps no spread models), ``notes`` (what lies outside the judge's domain;
    empty inside it), which model (``kind``: "capture" or "volume"), the features it read,
    the input's ``descriptors`` and which judge answered (``judge``)."""

    source: str
    kind: str
    p_legible: float
    features: dict
    interval: list[float] | None = None
    notes: list[str] = field(default_factory=list)
    descriptors: dict = field(default_factory=dict)
    judge: str = ""

    def line(self) -> str:
        band = ("" if self.interval is None
                else f" [{self.interval[0]:.3f}, {self.interval[1]:.3f}]")
        return (f"{self.source}  P(legible) = {self.p_legible:.3f}{band}  ({self.kind} model"
                + (", outside the judge's domain)" if self.notes else ")"))

    def as_json(self) -> dict:
        return {"file": self.source, "p_legible": self.p_legible, "interval": self.interval,
                "notes": self.notes, "model": self.kind, "judge": self.judge,
                "descriptors": self.descriptors, "features": self.features}


def shipped_judge() -> Judge:
    """The judge shipped with clnlos (package data, written by tools/train_judge.py)."""
    entry = resources.files("clnlos.data").joinpath(SHIPPED_JUDGE)
    if not entry.is_file():
        raise InputFileError(f"the shipped legibility judge ({SHIPPED_JUDGE} in clnlos.data) "
                             "is missing from this installation: give --model STUDY_DIR")
    judge = Judge.from_json(json.loads(entry.read_text(encoding="utf-8")))
    judge.info.setdefault("source", f"shipped ({SHIPPED_JUDGE})")
    return judge


def judge_from(model=None) -> Judge:
    """The judge of ``model``: the shipped one for None, a
    :class:`~clnlos.study.judge.model.Judge`, a study folder holding judge.json, or a
    judge.json file (an :class:`InputFileError` naming the path when it is none of these)."""
    if model is None:
        return shipped_judge()
    if isinstance(model, Judge):
        return model
    p = Path(model)
    f = p / JUDGE_FILE if p.is_dir() else p
    if not f.is_file():
        raise InputFileError(f"{model}: no {JUDGE_FILE} (a study folder written by "
                             "`clnlos study` holds one)")
    try:
        judge = load_judge(f)
    except (ValueError, KeyError, TypeError) as exc:
        raise InputFileError(f"{f}: not a legibility judge ({JUDGE_FORMAT}): "
                             f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
                             ) from None
    judge.info["source"] = str(f)
    return judge


def options_config(config=None, **options) -> ReconstructionConfig | None:
    """The user's options for a capture the judge reconstructs: ``config`` (a
    :class:`~clnlos.config.ReconstructionConfig`, a TOML path or its parsed table) and
    keyword ``options`` over it, among :data:`clnlos.study.judge.recipe.USER_FIELDS`
    (``slab`` a table or a :class:`~clnlos.physics.slab.Slab`); None for neither."""
    unknown = sorted(set(options) - set(USER_FIELDS))
    if unknown:
        raise ParameterError(unknown[0], options[unknown[0]],
                             "an option of the judge's reconstruction: " + ", ".join(USER_FIELDS))
    if config is None and not options:
        return None
    if isinstance(config, ReconstructionConfig):
        cfg = config
    else:
        table = dict(config) if isinstance(config, Mapping) else (
            load_toml(config) if config is not None else {})
        cfg = ReconstructionConfig.from_dict(table)
    if isinstance(options.get("slab"), Mapping):
        options["slab"], _ = slab_from_table(dict(options["slab"]), section="slab")
    return cfg.replace(**options).validate()


def is_volume_file(path) -> bool:
    """True for an HDF5 file holding a dataset ``volume`` (what clnlos reconstruct writes)."""
    p = Path(path)
    if not p.is_file() or not h5py.is_hdf5(p):
        return False
    with h5py.File(p, "r") as f:
        return "volume" in f


def judge_capture(capture: Capture, judge: Judge, source: str = "capture",
                  options: ReconstructionConfig | None = None, *, no_slab: bool = False,
                  device=None) -> Verdict:
    """The capture model's verdict on a capture (reconstructed with the judge's recipe,
    ``options`` the user's)."""
    if not is_counts(capture.transient):
        raise InputFileError(
            f"{source}: the judge splits a capture's photons into two halves, and this one "
            "holds no photon counts (values that are not whole numbers: a simulation without "
            "a [detector]?); judge its reconstruction (a volume .h5) instead")
    capture = binned_laterally(capture, judge.recipe.get("max_points", JUDGE_MAX_POINTS))
    cfg = judge_config(capture, options, judge.recipe, no_slab=no_slab)
    counted = replace(capture, transient=np.asarray(capture.transient, np.float32))
    full, h1, h2 = judge_reconstructions(counted, cfg, get_queue(device))
    f = capture_features(full, h1, h2)
    d = capture_descriptors(counted, cfg)
    a = judge.assess("capture", f, d)
    return Verdict(source, "capture", a.p, f, a.interval, a.notes, d,
                   judge.info.get("source", ""))


def judge_volume(volume, judge: Judge, source: str = "volume") -> Verdict:
    """The volume model's verdict on a volume [z, y, x] or a MIP [y, x] (its MIP averaged
    to the recipe's grid)."""
    v = np.asarray(volume)
    if v.ndim not in (2, 3) or not v.size:
        raise InputFileError(f"{source}: a volume [z, y, x] or an image [y, x] is needed, "
                             f"not an array of shape {list(v.shape)}")
    mip = pooled(mip_of(v), judge.recipe.get("max_points", JUDGE_MAX_POINTS))
    f = mip_features(mip)
    d = {"points": int(max(mip.shape))}
    a = judge.assess("volume", f, d)
    return Verdict(source, "volume", a.p, f, a.interval, a.notes, d,
                   judge.info.get("source", ""))


def legibility(source, model=None, *, config=None, no_slab: bool = False, device=None,
               **options) -> Verdict:
    """P(legible) of ``source`` by the shipped judge, or by the one in ``model`` (a study
    folder, its judge.json or a loaded :class:`~clnlos.study.judge.model.Judge`):
    ``source`` a capture or volume file, a :class:`~clnlos.io.capture.Capture`, a
    reconstruction (anything with a ``volume``) or an array. A capture the file does not
    fully describe takes ``config`` / ``options`` (:func:`options_config`: e.g.
    ``scan_width_m=0.7``, ``slab={...}``) as ``clnlos reconstruct`` does; ``no_slab``
    skips a recorded slab. Returns a :class:`Verdict` (``.p_legible``, ``.interval``,
    ``.notes``)."""
    judge = judge_from(model)
    opts = options_config(config, **options)
    if isinstance(source, Capture):
        return judge_capture(source, judge, source.source or "capture", opts,
                             no_slab=no_slab, device=device)
    if hasattr(source, "volume"):
        return judge_volume(source.volume, judge, "reconstruction")
    if isinstance(source, np.ndarray):
        return judge_volume(source, judge, "array")
    path = Path(source)
    if not path.is_file():
        raise InputFileError(f"{source}: no such file")
    if is_volume_file(path):
        return judge_volume(read_volume(path)[0], judge, str(source))
    return judge_capture(read_capture(path), judge, str(source), opts, no_slab=no_slab,
                         device=device)
