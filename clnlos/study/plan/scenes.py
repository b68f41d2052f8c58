"""A study sample's scene (pure: nothing is rendered here; :mod:`clnlos.study.samples.render`
renders a sample).

A sample is a JSON-able dict: the target (``object``: "letters" with ``text``, ``height_m``
and ``stroke_m``; "pattern" with ``pattern`` and ``side_m``; "mask" with ``mask``, its
SHA-256 and ``width_m`` / ``height_m``; the random extras' "bars", "rectangle", "sphere"),
its ``depth_m`` and ``rotate_deg``, the scene ``material`` (a preset name or a BRDF texture's
absolute path, with ``material_sha256``) and ``albedo``, the ``exposure_s`` per scan point,
the noise ``seed``, and optional overrides: ``scan_width_m``, ``slab_thickness_m`` (0: no
slab), a ``transport`` table (the bistatic comparison), the inversion ``method`` and the
``brdf`` it assumes (:mod:`clnlos.brdf.lobes`; absent: Lambertian). With the rig
(:class:`~clnlos.study.file.spec.StudyGrid`) it defines one scene (:func:`scene_dict`) and
one reconstruction (:func:`reconstruction_window_m`).
"""

from __future__ import annotations

import math

import numpy as np

from clnlos.forward.geometry import rotation_matrix
from clnlos.physics.constants import C0
from clnlos.study.file.spec import StudyGrid
from clnlos.study.score.patterns import CHART_SCALE, pattern_objects

# glyphs of 4-5 cm bars: (centre x, centre y, width, height) in units of the glyph size L and
# bar width b, built into rectangles


def _bars(glyph: str, L: float, b: float) -> list[tuple[float, float, float, float]]:
    h = b / 2
    return {
        "T": [(0, L / 2 - h, L, b), (0, -b / 2, b, L - b)],
        "L": [(-L / 2 + h, 0, b, L), (b / 2, -L / 2 + h, L - b, b)],
        "H": [(-L / 2 + h, 0, b, L), (L / 2 - h, 0, b, L), (0, 0, L - 2 * b, b)],
        "U": [(-L / 2 + h, 0, b, L), (L / 2 - h, 0, b, L), (0, -L / 2 + h, L - 2 * b, b)],
        "plus": [(0, 0, L, b), (0, 0, b, L)],
    }[glyph]


BAR_GLYPHS = ("T", "L", "H", "U", "plus")


def _rotate_z(x: float, y: float, deg: float) -> tuple[float, float]:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return c * x - s * y, s * x + c * y


def scene_objects(sample: dict) -> list[dict]:
    """The [[objects]] of a sample (several rectangles for a bar glyph or a chart)."""
    ox, oy = sample.get("offset_m", [0.0, 0.0])
    z = sample["depth_m"]
    rot = [float(v) for v in sample.get("rotate_deg", [0.0, 0.0, 0.0])]
    base = {"rotate_deg": rot, "material": sample["material"],
            "albedo": float(sample.get("albedo", 1.0))}
    kind = sample["object"]
    if kind == "bars":
        out = []
        for cx, cy, w, h in _bars(sample["glyph"], sample["size_m"], sample["bar_m"]):
            px, py = _rotate_z(cx, cy, rot[2])
            out.append({**base, "shape": "rectangle", "size_m": [w, h],
                        "translate_m": [ox + px, oy + py, z]})
        return out
    if kind == "pattern":
        objs = pattern_objects(sample["pattern"], sample["side_m"] / CHART_SCALE, 0.0,
                               (ox, oy, z), base["material"], base["albedo"])
        return _rotated_chart(objs, rot, (ox, oy, z))
    obj = {**base, "shape": kind, "translate_m": [ox, oy, z]}
    if kind == "letters":
        obj.update(text=sample.get("text", "UT"), height_m=sample.get("height_m", 0.15),
                   stroke_m=sample.get("stroke_m", 0.04))
    elif kind == "mask":
        obj.update(path=sample["mask"], size_m=[sample["width_m"], sample["height_m"]])
    elif kind == "rectangle":
        obj.update(size_m=sample.get("size_m", [0.15, 0.1]))
    else:
        obj.update(radius_m=sample.get("radius_m", 0.08))
    return [obj]


def _rotated_chart(objs: list[dict], rot, centre) -> list[dict]:
    """A chart's rectangles turned as one plate about the chart's centre (R = Rz Ry Rx)."""
    R = rotation_matrix(rot)
    c = np.asarray(centre, float)
    out = []
    for o in objs:
        p = R @ (np.asarray(o["translate_m"], float) - c) + c
        out.append({**o, "translate_m": [float(v) for v in p], "rotate_deg": list(rot)})
    return out


def bistatic_table(rings: int, angles: int) -> dict:
    """The ``transport`` table of a bistatic sample (Eq. 8 in full, ``rings`` x ``angles``
    samples of the slab's face), passed to the scene by :func:`scene_dict`."""
    return {"model": "bistatic", "face_rings": int(rings), "face_angles": int(angles)}


BINS_PER_FWHM = 2  # the inversions' bins per temporal FWHM of the rig (docs/study-file.md)


def rig_temporal_fwhm_s(grid: StudyGrid) -> float:
    """The rig's temporal FWHM: pulse and capture bin in quadrature (s)."""
    return math.hypot(grid.pulse_width_s or 0.0, grid.bin_width_s)


WINDOW_STEP_M = 0.4


def window_m(sample: dict, grid: StudyGrid) -> float:
    """Reconstruction window (round-trip path, m): the rig's shortest, or for deep targets
    2 (depth + 0.3 m) rounded up to WINDOW_STEP_M (few distinct windows: each is a plan);
    never past the end of a recorded time axis."""
    need = 2.0 * (sample["depth_m"] + 0.3)
    w = max(grid.max_path_m, math.ceil(need / WINDOW_STEP_M - 1e-9) * WINDOW_STEP_M)
    if grid.bins is not None:
        w = min(w, C0 * (grid.start_s + grid.bins * grid.bin_width_s))
    return w


def capture_bins(sample: dict, grid: StudyGrid) -> int:
    """The capture's bins: the rig's recorded axis, else 30% past the reconstruction window
    (the deconvolution's guard bins)."""
    if grid.bins is not None:
        return grid.bins
    return int(math.ceil(1.3 * window_m(sample, grid) / (C0 * grid.bin_width_s)))


def slab_table(sample: dict, grid: StudyGrid) -> dict | None:
    """The sample's [slab] table: the rig's, its thickness swept where the sample says."""
    if grid.slab is None:
        return None
    thickness, mu_a, mu_s_prime, n = grid.slab
    thickness = sample.get("slab_thickness_m", thickness)
    if thickness <= 0:
        return None
    return {"thickness_m": thickness, "mu_a": mu_a, "mu_s_prime": mu_s_prime, "n": n}


def scene_dict(sample: dict, grid: StudyGrid) -> dict:
    """The scene table of a sample on the rig (every key of a scene file)."""
    width = sample.get("scan_width_m", grid.scan_width_m)
    slab = slab_table(sample, grid)
    d = {"seed": int(sample["seed"]),
         "scan": {"width_m": width, "points": grid.points},
         "time": {"bin_width_s": grid.bin_width_s, "bins": capture_bins(sample, grid),
                  "start_s": 0.0 if slab is not None else grid.start_s},
         "objects": scene_objects(sample),
         "detector": {"power_w": grid.power_w, "rep_rate_hz": grid.rep_rate_hz,
                      "exposure_s": sample["exposure_s"], "efficiency": grid.efficiency,
                      "wavelength_m": grid.wavelength_m, "etendue_m2_sr": grid.etendue_m2_sr,
                      "dark_count_rate_hz": grid.dark_count_rate_hz},
         "sampling": {"density_per_m2": grid.density_per_m2, "splat_order": 1}}
    if grid.pulse_width_s is not None:
        d["laser"] = {"pulse_width_s": grid.pulse_width_s}
    if slab is not None:
        d["slab"] = slab
    if "transport" in sample:  # the scene's [transport] table (absent: the confocal model)
        d["transport"] = dict(sample["transport"])
    return d


TEXTS = ("UT", "S", "T", "L", "H", "E", "F", "X", "O", "Z")


def dataset_samples(n: int, materials: list[dict], seed: int) -> list[dict]:
    """n samples spread so that quality varies for physical reasons: every material (each a
    sample's material keys: ``material``, ``albedo``, ...); letters, bar glyphs (4-5 cm
    bars), plates and spheres of several sizes; 0.35-0.75 m deep, up to 5 cm off the axis,
    tilted up to 20 degrees about x and y and turned about z; exposures log-uniform over
    5 ms - 0.3 s (photon counts over two decades)."""
    rng = np.random.default_rng(seed)
    kinds = ("letters", "bars", "rectangle", "sphere")
    out = []
    for k in range(n):
        kind = kinds[int(rng.integers(len(kinds)))]
        s = {**materials[int(rng.integers(len(materials)))], "object": kind,
             "depth_m": round(float(rng.uniform(0.35, 0.75)), 3),
             "offset_m": [round(float(v), 3) for v in rng.uniform(-0.05, 0.05, 2)],
             "rotate_deg": [round(float(rng.uniform(-20, 20)), 1),
                            round(float(rng.uniform(-20, 20)), 1),
                            round(float(rng.uniform(-45, 45)), 1)],
             "exposure_s": round(float(10 ** rng.uniform(math.log10(5e-3), math.log10(0.3))),
                                 5),
             "seed": int(seed * 100_003 + k)}
        if kind == "letters":
            h = round(float(rng.uniform(0.12, 0.2)), 3)
            s.update(text=TEXTS[int(rng.integers(len(TEXTS)))], height_m=h,
                     stroke_m=round(float(rng.uniform(0.03, 0.05)), 3))
        elif kind == "bars":
            s.update(glyph=BAR_GLYPHS[int(rng.integers(len(BAR_GLYPHS)))],
                     size_m=round(float(rng.uniform(0.14, 0.2)), 3),
                     bar_m=round(float(rng.uniform(0.04, 0.05)), 3))
        elif kind == "rectangle":
            s["size_m"] = [round(float(v), 3) for v in rng.uniform(0.05, 0.2, 2)]
        else:
            s["radius_m"] = round(float(rng.uniform(0.04, 0.1)), 3)
        out.append(s)
    return out
