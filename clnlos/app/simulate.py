"""``clnlos simulate``: a scene to a capture file and its figure (a pair written together)."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clnlos.app.progress import progress_bar, stage
from clnlos.errors import ParameterError
from clnlos.forward.model import ForwardModel
from clnlos.io.figures import transient_figure
from clnlos.io.files import capture_attrs, save_figure_file, write_h5_file
from clnlos.io.formats.tal import write_tal
from clnlos.io.outputs import provenance, write_group

FORMATS = ("clnlos", "tal")


@dataclass
class Simulated:
    transient: np.ndarray
    stages: list[str]
    seconds: float
    capture: Path
    figure: Path


def figure_path(out: Path) -> Path:
    return Path(out).with_suffix(".png")


def simulate_to_file(scene, out, *, fmt: str = "clnlos", dtype=np.float32, queue=None
                     ) -> Simulated:
    """Run the forward model of ``scene`` and write the capture (clnlos HDF5, or y-tal HDF5
    for ``fmt="tal"``) and a PNG of x-t / y-t slices beside it, atomically together."""
    if fmt not in FORMATS:
        raise ParameterError("--format", fmt, " or ".join(FORMATS))
    out = Path(out)

    t0 = time.perf_counter()
    fm = ForwardModel(scene, dtype=dtype, queue=queue)
    with progress_bar(len(fm.stages), "simulate", "stage") as bar:
        tau = fm.run(progress=lambda name: (stage(bar, name), bar.update(1)))
    seconds = time.perf_counter() - t0
    units = "photon counts" if scene.detector else "1/(m^2 sr) per bin"
    attrs = {**fm.setup_attrs(), **provenance(device=fm.queue.device.name.strip()),
             "seconds": seconds, "units": units}
    fig = transient_figure(tau, width_m=scene.width_m, start_s=scene.start_s,
                           bin_width_s=scene.bin_width_s,
                           title=f"{out.name}: {', '.join(fm.stages)}",
                           units="counts" if scene.detector else "1/(m^2 sr)")
    png = figure_path(out)
    with write_group([out, png]) as (tmp_cap, tmp_png):
        if fmt == "tal":
            write_tal(tmp_cap, tau, bin_width_s=scene.bin_width_s, start_s=scene.start_s,
                      scan_width_m=scene.width_m,
                      scene_info={"original_format": "clnlos", "units": units,
                                  "clnlos": {k: v for k, v in attrs.items()
                                             if isinstance(v, str | int | float)}})
        else:
            write_h5_file(tmp_cap, {"transient": np.asarray(tau, np.float32)},
                          capture_attrs(bin_width_s=scene.bin_width_s, start_s=scene.start_s,
                                        scan_width_m=scene.width_m, attrs=attrs,
                                        shape=np.shape(tau)))
        save_figure_file(fig, tmp_png)
    return Simulated(tau, list(fm.stages), seconds, out, png)
