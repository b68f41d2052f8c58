"""How far the confocal model (seed Eq. 9) is from Eq. 8 for each material at the study
geometry (:mod:`clnlos.forward.bistatic` as truth)."""

from __future__ import annotations

import math
import time

import numpy as np

from clnlos.brdf.presets import preset_names
from clnlos.config import slab_table
from clnlos.forward.bistatic import face_quadrature, footprint_spread_rad, lobe_halfwidth_rad
from clnlos.forward.model import ForwardModel
from clnlos.forward.sampling import material_retro
from clnlos.forward.scene import Scene
from clnlos.physics.slab import CDT_SLAB
from clnlos.study.file.spec import StudyGrid

# ------------------------------------------------------------------ Eq. 9 against Eq. 8
# The specular test scene at the study geometry (clnlos.study: 0.3 m scan of 32 x 32
# points, 48 ps bins, 4e4 elements/m^2, target 0.5 m behind the CDT slab): a 6 cm square
# patch tilted 5 degrees about y, centred on the scan.
ERROR_PATCH = {"shape": "rectangle", "size_m": [0.06, 0.06], "rotate_deg": [0.0, 5.0, 0.0]}
ERROR_DEPTH_M = 0.5           # the seed's Table 1 depth


ERROR_BINS = 160              # 7.7 ns at 48 ps: the return and the slab's tail


REFINED = {"face_rings": 6, "face_angles": 12, "texture_theta": 128, "texture_dphi": 128}


SIGNIFICANT = 0.01            # scan points holding at least this fraction of the brightest


def study_patch_scene(material, model: str = "confocal", *, points: int | None = None,
                      bins: int = ERROR_BINS, bin_width_s: float | None = None,
                      width_m: float | None = None, transport: dict | None = None):
    """:data:`ERROR_PATCH` of ``material`` at the study geometry (scan points, width and
    bin width overridable), ``[transport] model``."""
    g = StudyGrid()
    obj = {**ERROR_PATCH, "translate_m": [0.0, 0.0, ERROR_DEPTH_M],
           "material": material}
    return Scene.from_dict({
        "scan": {"width_m": width_m or g.scan_width_m, "points": points or g.points},
        "time": {"bin_width_s": bin_width_s or g.bin_width_s, "bins": bins}, "objects": [obj],
        "slab": slab_table(CDT_SLAB), "sampling": {"density_per_m2": g.density_per_m2},
        "transport": {"model": model, **(transport or {})}})


def _rel(a, b) -> float:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-300))


def confocal_error(material, *, points: int | None = None, refine: bool = True,
                   queue=None) -> dict:
    """How far the confocal model (Eq. 9) is from Eq. 8 for ``material`` on
    :func:`study_patch_scene` (Eq. 8 at the default quadrature as truth).

    Fields: ``total_ratio`` (Eq. 9 / Eq. 8, whole capture), ``rel_l2`` (relative L2 of the
    difference), ``worst_point_ratio`` (the scan point's Eq. 9 / Eq. 8 furthest from 1
    among those holding SIGNIFICANT of the brightest), ``shape_error_peak`` (relative L2 of
    the normalised transients at the brightest point), ``eq8_quadrature_error`` (relative L2
    of Eq. 8 at the defaults against REFINED; only with ``refine``), the "auto" rule's
    numbers and choice, and seconds of each model."""
    out = {"material": material}
    runs = {}
    models = [("confocal", None), ("bistatic", None)] + ([("bistatic", REFINED)] if refine
                                                          else [])
    for model, extra in models:
        fm = ForwardModel(study_patch_scene(material, model, points=points, transport=extra),
                          queue=queue)
        t0 = time.perf_counter()
        runs[(model, extra is not None)] = fm.run().astype(np.float64)
        out[f"seconds_{model}{'_refined' if extra else ''}"] = time.perf_counter() - t0
    conf, eq8 = runs[("confocal", False)], runs[("bistatic", False)]
    per_c, per_8 = conf.sum(axis=0), eq8.sum(axis=0)
    sig = per_8 >= SIGNIFICANT * per_8.max()
    ratios = per_c[sig] / per_8[sig]
    peak = np.unravel_index(int(np.argmax(per_8)), per_8.shape)
    out.update(total_ratio=float(conf.sum() / eq8.sum()), rel_l2=_rel(conf, eq8),
               worst_point_ratio=float(ratios[np.argmax(np.abs(ratios - 1))]),
               shape_error_peak=_rel(conf[:, peak[0], peak[1]] / per_c[peak],
                                     eq8[:, peak[0], peak[1]] / per_8[peak]))
    if refine:
        out["eq8_quadrature_error"] = _rel(eq8, runs[("bistatic", True)])
    auto = ForwardModel(study_patch_scene(material, "auto", points=2), queue=queue)
    quad = face_quadrature(auto.scene.slab, bins=auto.scene.bins,
                           bin_width_s=auto.scene.bin_width_s, rings=1, angles=1,
                           queue=auto.queue)

    retro = material_retro(auto.scene.objects[0], auto.scene.base_dir)
    z = float(auto.samples.elements.pos[:, 2].min())
    out.update(lobe_halfwidth_deg=math.degrees(lobe_halfwidth_rad(retro)),
               footprint_spread_deg=math.degrees(footprint_spread_rad(quad.rms_m, z)),
               auto=auto.transport)
    return out


def confocal_error_table(materials=None, **kw) -> list[dict]:
    """:func:`confocal_error` for each material (default: the seed's ten presets)."""
    return [confocal_error(m, **kw) for m in (materials or preset_names())]
