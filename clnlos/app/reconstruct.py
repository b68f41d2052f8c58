"""The reconstruct front: a capture in, the volume (HDF5) and its figure (PNG) out, atomically,
with provenance and a progress bar for the iterative method."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from clnlos.api import reconstruct
from clnlos.io.progress import progress_bar, stage
from clnlos.config import ReconstructionConfig
from clnlos.inverse.pipeline import Reconstruction
from clnlos.io.capture import Capture
from clnlos.io.deflate import DeflatedArray
from clnlos.io.figures import volume_figure as figure
from clnlos.io.files import save_figure_file, write_h5_file
from clnlos.io.outputs import provenance, write_group
from clnlos.runtime.device import get_queue


def volume_figure(rec: Reconstruction, title: str = ""):
    """The figure of a reconstruction (:func:`clnlos.io.figures.volume_figure`)."""
    return figure(rec.volume, rec.extents, title)


def volume_attrs(rec: Reconstruction) -> dict:
    """The HDF5 attributes of a volume file (format clnlos-volume-1)."""
    return {**rec.extents, "bin_width_s": rec.bin_width_s, "scan_width_m": rec.scan_width_m,
            "stages": json.dumps(rec.stages), "timings_s": json.dumps(rec.timings_s),
            "params": json.dumps(rec.params), "noise": json.dumps(rec.noise),
            "solver": json.dumps(rec.solver), "notes": json.dumps(rec.notes),
            "brdf": rec.params.get("brdf_used", "lambertian"),
            "axes": "volume[z, y, x]; +x with column index, +y with row index",
            "capture_axes": rec.params.get("axes_used", "t,y,x"),
            "capture_axes_source": rec.params.get("axes_source", "recorded by the file"),
            "format": "clnlos-volume-1"}


def _iteration(bar, done: int, total: int) -> None:
    """Iteration ``done`` of ``total`` finished: the set-up note (if any) goes, the bar takes
    the total the solver runs to (the config's iterations, or fewer where the stop rule
    says, clnlos.inverse.iterative) and moves to ``done``."""
    if bar.postfix:
        bar.set_postfix_str("", refresh=False)
    if bar.total != total:
        bar.total = total
    bar.update(done - bar.n)


def reconstruct_to_files(capture: Capture, out, config: ReconstructionConfig, *,
                         dtype=np.float32, queue=None, title_extra: str = "",
                         show_progress: bool = True, no_slab: bool = False,
                         names: dict[str, str] | None = None, log=None) -> Reconstruction:
    """Reconstruct (:func:`clnlos.api.reconstruct`: the slab the capture recorded unless the
    config names one or ``no_slab``; its note to ``log``) and write the volume (HDF5) and its
    figure (PNG beside it) together, atomically, with the provenance of the result; the
    iterative method shows a progress bar (:mod:`clnlos.io.progress`), its set-up steps
    beside it, then its iterations."""
    out = Path(out)
    queue = get_queue(queue)
    bar = None
    if show_progress and config.method == "iterative":
        bar = progress_bar(config.iterations, "iterative", "it")
    try:
        rec = reconstruct(capture, config=config, no_slab=no_slab, dtype=dtype, device=queue,
                          names=names, log=log,
                          progress=None if bar is None else (
                              lambda k, n: _iteration(bar, k, n)),
                          setup=None if bar is None else (
                              lambda step: stage(bar, f"setup: {step}")))
    finally:
        if bar is not None:
            bar.close()
    attrs = {**volume_attrs(rec), "dtype": np.dtype(dtype).name,
             **provenance(capture=capture.source if capture.source and
                          Path(capture.source).exists() else None,
                          device=queue.device.name.strip())}
    name = Path(capture.source).name if capture.source else "capture"
    title = f"{title_extra + ': ' if title_extra else ''}{name} ({config.method})"
    volume = DeflatedArray(np.asarray(rec.volume, np.float32))  # compressed as the figure draws
    fig = figure(rec.volume, rec.extents, title)
    with write_group([out, out.with_suffix(".png")]) as (tmp_h5, tmp_png):
        write_h5_file(tmp_h5, {"volume": volume}, attrs)
        save_figure_file(fig, tmp_png)
    return rec
