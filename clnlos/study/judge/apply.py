"""P(legible) of any capture or reconstruction by a study's trained judge: what
``clnlos legibility FILE... --model STUDY_DIR`` and ``clnlos.legibility`` run.

A *volume* (a clnlos volume .h5 of any method, grid or size, a
:class:`~clnlos.inverse.pipeline.Reconstruction`, or an array [z, y, x] / a MIP [y, x]) is
judged by the MIP-only model. A *capture* (any file :func:`clnlos.io.files.read_capture`
reads, or a :class:`~clnlos.io.capture.Capture`) is reconstructed with the judge's recipe
(:func:`clnlos.study.judge.real.judge_config`) together with two binomial halves of its
photons and judged by the capture model (its counts are rounded to whole photons for the
split).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import h5py
import numpy as np

from clnlos.errors import InputFileError
from clnlos.io.capture import Capture
from clnlos.io.files import read_capture, read_volume
from clnlos.runtime.device import get_queue
from clnlos.study.judge.model import JUDGE_FILE, JUDGE_FORMAT, Judge, load_judge
from clnlos.study.judge.features import capture_features, mip_features
from clnlos.study.judge.real import binned_laterally, judge_config
from clnlos.study.judge.twins import JUDGE_MAX_POINTS, judge_reconstructions


@dataclass
class Verdict:
    """The judge's answer for one input: ``p_legible``, which model (``kind``: "capture" or
    "volume") and the features it read."""

    source: str
    kind: str
    p_legible: float
    features: dict

    def line(self) -> str:
        return f"{self.source}  P(legible) = {self.p_legible:.3f}  ({self.kind} model)"


def judge_from(model) -> Judge:
    """The judge of ``model``: a :class:`~clnlos.study.judge.model.Judge`, a study folder holding
    judge.json, or a judge.json file (an :class:`InputFileError` naming the path when it
    is none of these)."""
    if isinstance(model, Judge):
        return model
    p = Path(model)
    f = p / JUDGE_FILE if p.is_dir() else p
    if not f.is_file():
        raise InputFileError(f"{model}: no {JUDGE_FILE} (a study folder written by "
                             "`clnlos study` holds one)")
    try:
        return load_judge(f)
    except (ValueError, KeyError, TypeError) as exc:
        raise InputFileError(f"{f}: not a legibility judge ({JUDGE_FORMAT}): "
                             f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
                             ) from None


def is_volume_file(path) -> bool:
    """True for an HDF5 file holding a dataset ``volume`` (what clnlos reconstruct writes)."""
    p = Path(path)
    if not p.is_file() or not h5py.is_hdf5(p):
        return False
    with h5py.File(p, "r") as f:
        return "volume" in f


def judge_capture(capture: Capture, judge: Judge, path=None, device=None) -> Verdict:
    """The capture model's verdict on a capture (reconstructed with the judge's recipe)."""
    capture = binned_laterally(capture, judge.recipe.get("max_points", JUDGE_MAX_POINTS))
    cfg = judge_config(capture, path, judge.recipe)
    counts = np.rint(np.clip(np.asarray(capture.transient, np.float64), 0, None))
    full, h1, h2 = judge_reconstructions(replace(capture, transient=counts.astype(np.float32)),
                                         cfg, get_queue(device))
    f = capture_features(full, h1, h2)
    return Verdict(str(path or capture.source or "capture"), "capture",
                   judge.capture_proba(full, h1, h2), f)


def judge_volume(volume, judge: Judge, source: str = "volume") -> Verdict:
    """The volume model's verdict on a volume [z, y, x] or a MIP [y, x]."""
    v = np.asarray(volume)
    if v.ndim not in (2, 3) or not v.size:
        raise InputFileError(f"{source}: a volume [z, y, x] or an image [y, x] is needed, "
                             f"not an array of shape {list(v.shape)}")
    return Verdict(source, "volume", float(judge.volume_proba([v])[0]), mip_features(v))


def legibility(source, model, *, device=None) -> Verdict:
    """P(legible) of ``source`` by the judge in ``model`` (a study folder, its judge.json or a
    loaded :class:`~clnlos.study.judge.model.Judge`): ``source`` a capture or volume file, a
    :class:`~clnlos.io.capture.Capture`, a reconstruction (anything with a ``volume``) or an
    array. Returns a :class:`Verdict` (``.p_legible``)."""
    judge = judge_from(model)
    if isinstance(source, Capture):
        return judge_capture(source, judge, None, device)
    if hasattr(source, "volume"):
        return judge_volume(source.volume, judge, "reconstruction")
    if isinstance(source, np.ndarray):
        return judge_volume(source, judge, "array")
    path = Path(source)
    if not path.is_file():
        raise InputFileError(f"{source}: no such file")
    if is_volume_file(path):
        return judge_volume(read_volume(path)[0], judge, str(source))
    return judge_capture(read_capture(path), judge, path, device)
