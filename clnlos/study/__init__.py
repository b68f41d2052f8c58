"""The material study: how a hidden target's BRDF changes what NLOS reconstruction recovers.

``run`` is the study of ``clnlos study`` (``clnlos.study.run(...)`` from Python); the
stages live in ``clnlos.study.run`` (the module, imported by name:
``from clnlos.study.run import StudyOptions``)."""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

from clnlos.study.run import StudyOptions, real_capture_dir, run_study


def run(out_dir: str | os.PathLike = "out/study", *, full: bool = False,
        options: StudyOptions | None = None, method: str | None = None,
        labels: str | None = None, real_data: str | os.PathLike | None = None,
        transport: str | None = None, n_dataset: int | None = None,
        workers: int | None = None, scheduler: str | None = None,
        device: str | None = None) -> dict:
    """Run the material study and write ``out_dir/report.html`` and ``results.json``.

    ``options``: a ``clnlos.study.run.StudyOptions``; default the quick study
    (``StudyOptions.quick()``, about 5 minutes on 2 CPU cores) or with ``full`` the full one.
    ``method`` (reconstruction method), ``labels`` (what the CNN learns: "legibility", "nr",
    "fft"), ``real_data`` (a folder whose ``cdt/`` holds the real CDT captures),
    ``transport`` ("confocal" or "both") and ``n_dataset`` (extra random samples) override
    it. ``workers`` local Dask processes (default: CPU count; 1 serial) or ``scheduler`` the
    address of a running one; ``device`` an OpenCL device spec. Needs the ``ml`` extra
    (torch) and, with workers, the ``study`` extra (dask). Returns the results (what
    results.json holds)."""
    opts = options if options is not None else (StudyOptions() if full
                                                 else StudyOptions.quick())
    if method is not None:
        opts = replace(opts, grid=replace(opts.grid, method=method))
    changes = {k: v for k, v in (("labels", labels), ("transport", transport),
                                 ("n_dataset", n_dataset)) if v is not None}
    if real_data is not None:
        changes["real_data"] = Path(real_data) if real_capture_dir(Path(real_data)) else None
    opts = replace(opts, **changes)
    return run_study(Path(out_dir), opts.validate(), workers=workers, scheduler=scheduler,
                     device=device)
