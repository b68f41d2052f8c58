"""The material study: how a hidden target's surface material (BRDF) changes what NLOS imaging
can read, and how long a target of a given material must be exposed on a given rig.

``clnlos.study("STUDY.toml" | dict | "quick" | "full", out_dir)`` runs a study file (the
module itself is callable: it is :func:`run` with the study first); ``clnlos.study.run(...)``
takes the study as a keyword. The parts of a study live in the sub-packages
(:mod:`~clnlos.study.file`, :mod:`~clnlos.study.plan`, :mod:`~clnlos.study.samples`,
:mod:`~clnlos.study.judge`, :mod:`~clnlos.study.findings`, :mod:`~clnlos.study.report`,
:mod:`~clnlos.study.real`, :mod:`~clnlos.study.score`); :mod:`clnlos.study.run` runs them.
"""

from __future__ import annotations

import os
import sys
import types
from dataclasses import replace
from pathlib import Path

from clnlos.study.file.spec import (
    Classifier,
    Study,
    TransportComparison,
    load_study,
)
from clnlos.study.run import run_study
from clnlos.study.sections import real_capture_dir


def with_options(study: Study, *, method: str | None = None, labels: str | None = None,
                 real_data=None, transport: str | None = None,
                 n_dataset: int | None = None) -> Study:
    """A study with the command line's overrides: every inversion by ``method``; the
    table's CNN labels; the shared data folder; ``transport`` "both" adds the transport
    comparison, "confocal" drops it; ``n_dataset`` random extras."""
    changes: dict = {}
    if method is not None:
        changes["methods"] = (method,)
        changes["grid"] = replace(study.grid, method=method)
    if labels is not None or n_dataset is not None:
        c = study.classifier or Classifier()
        changes["classifier"] = replace(c, **({} if labels is None else {"labels": labels}),
                                        **({} if n_dataset is None else {"extras": n_dataset}))
    if transport == "confocal":
        changes["transport"] = None
    elif transport == "both" and study.transport is None:
        changes["transport"] = TransportComparison()
    if real_data is not None:
        changes["real_data"] = Path(real_data) if real_capture_dir(Path(real_data)) \
            or (Path(real_data) / "lct").is_dir() else None
    return replace(study, **changes)


def run(out_dir: str | os.PathLike = "out/study", *, study=None, full: bool = False,
        method: str | None = None, labels: str | None = None,
        real_data: str | os.PathLike | None = None, transport: str | None = None,
        n_dataset: int | None = None, workers: int | None = None,
        scheduler: str | None = None, device: str | None = None) -> dict:
    """Run a study and write ``out_dir/report.html`` and ``results.json``.

    ``study``: a study file's path, a dict of its tables, a :class:`~clnlos.study.file.spec.
    Study`, or a built-in's name; default the quick study (about 5 minutes on 2 CPU cores)
    or with ``full`` the full one. ``method`` (every inversion's method), ``labels`` (what the
    table's CNN learns: "legibility", "nr", "fft"), ``real_data`` (a folder whose ``cdt/`` and
    ``lct/`` hold the shared real captures), ``transport`` ("confocal" or "both") and
    ``n_dataset`` (random extras) override it. ``workers`` local Dask processes (default: CPU
    count; 1 serial) or ``scheduler`` the address of a running one; ``device`` an OpenCL
    device spec. Returns the results (what results.json holds)."""
    s = load_study(study if study is not None else ("full" if full else "quick"))
    s = with_options(s, method=method, labels=labels, real_data=real_data,
                     transport=transport, n_dataset=n_dataset)
    return run_study(Path(out_dir), s, workers=workers, scheduler=scheduler, device=device,
                     labels=labels)


class _StudyModule(types.ModuleType):
    """The package, callable: ``clnlos.study(study, out_dir, **options)`` is :func:`run`."""

    def __call__(self, study, out_dir: str | os.PathLike = "out/study", **options) -> dict:
        return run(out_dir, study=study, **options)


sys.modules[__name__].__class__ = _StudyModule
