"""``clnlos simulate``: a scene to a capture file and its figure (a pair written together)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clnlos.api import simulate
from clnlos.checks import ALLOW_IMPLAUSIBLE
from clnlos.io.progress import progress_bar, stage
from clnlos.errors import ParameterError
from clnlos.io.figures import transient_figure
from clnlos.io.files import capture_attrs, save_figure_file, write_h5_file
from clnlos.io.formats.tal import write_tal
from clnlos.io.outputs import write_group

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


def _stage_done(bar, name: str, total: int) -> None:
    """A forward stage finished: the bar learns the total, names the stage and moves."""
    bar.total = total
    stage(bar, name)
    bar.update(1)


def simulate_to_file(scene, out, *, fmt: str = "clnlos", dtype=np.float32, queue=None,
                     allow_implausible: bool = False) -> Simulated:
    """Run the forward model of ``scene`` (:func:`clnlos.api.simulate`; ``allow_implausible``:
    accept geometry no NLOS capture can have) and write the capture (clnlos HDF5, or y-tal
    HDF5 for ``fmt="tal"``) and a PNG of x-t / y-t slices beside it, atomically together."""
    if fmt not in FORMATS:
        raise ParameterError("--format", fmt, " or ".join(FORMATS))
    out = Path(out)

    with progress_bar(None, "simulate", "stage") as bar:
        capture = simulate(scene, dtype=dtype, device=queue,
                           progress=lambda name, done, total: _stage_done(bar, name, total),
                           allow_implausible=allow_implausible,
                           names={"allow_implausible": ALLOW_IMPLAUSIBLE})
    tau, attrs = capture.transient, capture.attrs
    seconds, stages = attrs["seconds"], json.loads(attrs["stages"])
    fig = transient_figure(tau, width_m=scene.width_m, start_s=scene.start_s,
                           bin_width_s=scene.bin_width_s,
                           title=f"{out.name}: {', '.join(stages)}",
                           units="counts" if scene.detector else "1/(m^2 sr)")
    png = figure_path(out)
    with write_group([out, png]) as (tmp_cap, tmp_png):
        if fmt == "tal":
            write_tal(tmp_cap, tau, bin_width_s=scene.bin_width_s, start_s=scene.start_s,
                      scan_width_m=scene.width_m,
                      scene_info={"original_format": "clnlos", "units": attrs["units"],
                                  "clnlos": {k: v for k, v in attrs.items()
                                             if isinstance(v, str | int | float)}})
        else:
            write_h5_file(tmp_cap, {"transient": np.asarray(tau, np.float32)},
                          capture_attrs(bin_width_s=scene.bin_width_s, start_s=scene.start_s,
                                        scan_width_m=scene.width_m, attrs=attrs,
                                        shape=np.shape(tau)))
        save_figure_file(fig, tmp_png)
    return Simulated(tau, stages, seconds, out, png)
