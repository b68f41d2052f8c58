"""``clnlos study``: how a hidden target's surface material changes what NLOS imaging through
a scattering slab can *read* (seed sections 3.2, 4.2, 4.3, 5).

The question is answered with legibility, not with how well a blob covers the target:

1. Geometries (:data:`GEOMETRIES`), each stated in every table: the seed's Table 1
   (``seed_table1``: 0.3 m scan, letters 0.15 m tall with 4 cm strokes at 0.5 m, the strokes
   at the confocal resolution limit) and ``legible`` (0.6 m scan, letters 0.3 m tall with
   8 cm strokes at 0.5 m: the scale of the published CDT captures, where a Lambertian target
   reads at the default budget).
2. Materials: the ten presets, each reconstructing each of the K = 8 glyphs of
   :mod:`clnlos.study.legibility` (``seeds`` noise realisations each) at each geometry.
   Per material: identification accuracy (closest of the K blurred glyph templates, Wilson
   95% interval, chance 1/K), IoU beside the IoU of the filled box of the true mask (what a
   blob scores) and the excess over it; the seed's Figure 9 grouping beside ours.
3. Legibility sweeps at the legible geometry for a strong-specular, a mixed and a Lambertian
   material: letter height (strokes scaled with it) and exposure; the smallest legible
   letter and the exposure each material needs (identification >= LEGIBLE_ACCURACY).
4. The geometry sweeps (scan width, depth, slab thickness) at the seed's letter size,
   scored the same way.
5. Measured resolution (:mod:`clnlos.study.resolution`) and a real capture beside its
   simulation (:mod:`clnlos.study.real_capture`), when a folder of the real CDT captures
   is given (``real_data``, ``--real-data DIR``: its ``cdt/*.mat``).
6. The legibility judge (:mod:`clnlos.study.judge_study`): a calibrated logistic model on
   scale- and position-invariant measured features (:mod:`clnlos.study.judge_features`),
   the agreement of two binomial photon halves' reconstructions among them, trained on
   simulated twins of the real CDT and LCT capture families (:mod:`clnlos.study.twins`)
   to give P(legible) (identified and IoU above the box baseline), validated on held-out
   glyphs, geometries and materials against the majority and a one-feature baseline and by
   family on every real capture's thinning ladder (:mod:`clnlos.study.judge_real`), saved
   as judge.json (``clnlos legibility FILE... --model STUDY_DIR``) and applied to the real
   captures thinned to fewer photons (:mod:`clnlos.study.thinning_real`);
   ``--labels fft`` / ``nr`` add the seed's recipe (a torch CNN, :mod:`clnlos.study.classify`:
   FFT clarity / no-reference terciles), whose three classes label the materials.
7. With ``transport = "both"`` (``--transport both``): the materials at the legible geometry
   under the bistatic transport too (Eq. 8 in full, :mod:`clnlos.study.transport_compare`),
   their table and ranks under both and the rank correlation. Everything else is simulated
   with the confocal transport (the seed's Eq. 9).
8. Report (report.html, with the seed's Figure 8 side by side) and results.json.

Every sample is rendered (simulated, reconstructed, scored) by :mod:`clnlos.study.dataset`,
cached on disk and run through one pool of workers; identification is computed from the
cached MIPs, so a change of the matching rule reuses every sample.
"""

from __future__ import annotations

import json
import math
import time
import warnings
import zlib
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from scipy.special import stdtrit  # Student's t quantile (what scipy.stats.t.ppf calls)

from clnlos.app.progress import counter, progress_bar
from clnlos.brdf.lobes import AUTO, retro_lobe
from clnlos.brdf.models import BRDFModel
from clnlos.brdf.presets import preset_model, preset_table
from clnlos.config import SNR_RULES
from clnlos.errors import ParameterError
from clnlos.forward.scene import Scene
from clnlos.inverse.methods import method_names
from clnlos.io.files import atomic_path
from clnlos.io.outputs import stamp
from clnlos.study.clarity import label_thresholds
from clnlos.study.classify import SEED_EPOCHS, train_classifier
from clnlos.study.dataset import (
    StudyGrid,
    cpu_workers,
    dataset_samples,
    run_samples,
    scene_dict,
    window_m,
)
from clnlos.study.judge_study import study_judge
from clnlos.study.legibility import (
    GLYPHS,
    LEGIBLE_ACCURACY,
    best_shift,
    glyph_templates,
    identification_summary,
    identify,
    wilson_interval,
)
from clnlos.study.quality import DEFAULT_LABEL_METRIC, METRICS, pearson, validate_metrics
from clnlos.study.real_capture import (
    PUBLISHED_SCAN_WIDTH_M,
    compare_real_capture,
    real_capture_figure,
    reconstruct_chart,
)
from clnlos.study.report import write_report
from clnlos.study.resolution import (
    ResolutionGeometry,
    json_ready,
    measure_resolution,
    otoole_lateral_bound_m,
)
from clnlos.study.thinning_real import real_thinning
from clnlos.study.transport_compare import (
    COMPARE_ANGLES,
    COMPARE_RINGS,
    bistatic_table,
    comparison_table,
)

# The seed's Figure 9 grouping of its ten materials (1 clear, 2 medium, 3 fuzzy).
SEED_FIGURE9 = {
    "aluminium diffuse reflection plate": 1, "standard white plate": 1, "cement board": 1,
    "quartz glass": 2, "aluminium alloy sample": 2, "black anode plate": 2,
    "fuchsia lacquer board": 2,
    "gold-plated polyester film": 3, "painted steel plate": 3, "glass fibre": 3,
}
LABEL_METRICS = {"legibility": "identification", "nr": DEFAULT_LABEL_METRIC,
                 "fft": "fft_clarity"}
SWEEP_MATERIALS = ("aluminium alloy sample", "fuchsia lacquer board", "standard white plate")
SWEEPS = {"scan_width_m": (0.3, 0.45, 0.6, 0.8), "depth_m": (0.3, 0.5, 0.7, 0.9),
          "slab_thickness_m": (0.0, 0.0127, 0.0254, 0.0508)}
LEGIBILITY_SWEEPS = {"letter_height_m": (0.1, 0.2, 0.3, 0.5),
                     "exposure_s": (0.001, 0.01, 0.1, 1.0)}
TRANSPORT_CHOICES = ("confocal", "both")  # the study's transports: confocal; + bistatic
# the reflectance the iterative inversion assumes, per reconstruction: Lambertian (the physics
# of every method before), the material's own BRDF ("known"), or chosen from the capture
# ("auto", clnlos.inverse.brdf_choice)
INVERSIONS = ("lambertian", "known", "auto")
# the tilt sweep: glyphs rotated about the y axis at the legible geometry, matched up to a
# translation of at most TILT_MAX_SHIFT_M (a tilted mirror's light lands about z tan(tilt)
# away from the glyph)
TILTS_DEG = (0.0, 5.0, 10.0, 20.0)
TILT_MATERIALS = ("quartz glass", "aluminium alloy sample", "gold-plated polyester film",
                  "fuchsia lacquer board", "standard white plate")
TILT_MAX_SHIFT_M = 0.2
GAP_CLOSED = 1 / 8  # strong-specular identification within one glyph in eight of diffuse
STROKE_PER_HEIGHT = 0.04 / 0.15   # the seed's letters: 4 cm strokes on 15 cm
DEFAULT_EXPOSURE_S = 0.1          # per scan point (the seed's budget)
HELD_OUT_GLYPHS = ("U", "X")      # the CNN's validation: glyphs ...
HELD_OUT_HEIGHT_M = 0.2           # ... and a letter size it never saw


@dataclass(frozen=True)
class Geometry:
    """One study geometry: scan width (m), letters (height and stroke, m) and their depth."""

    name: str
    scan_width_m: float
    letter_height_m: float
    stroke_m: float
    depth_m: float
    description: str = ""


GEOMETRIES = (
    Geometry("seed_table1", 0.3, 0.15, 0.04, 0.5,
             "the seed's Table 1: 0.3 m scan, letters 15 cm tall with 4 cm strokes at 0.5 m"),
    Geometry("legible", 0.6, 0.3, 0.08, 0.5,
             "the published CDT captures' scale: 0.6 m scan, letters 30 cm tall with 8 cm "
             "strokes at 0.5 m"),
)
LEGIBLE_GEOMETRY = "legible"
SEED_GEOMETRY = "seed_table1"
MAIN_TARGET = {"object": "letters", "text": "UT", "height_m": 0.15, "stroke_m": 0.04,
               "depth_m": 0.5, "rotate_deg": [0.0, 0.0, 0.0], "exposure_s": DEFAULT_EXPOSURE_S}

# the quick study's grid: lateral pitch 2.5 cm at the legible geometry's 0.6 m scan (its
# strokes are 8 cm), 9.6 mm of depth per bin; about half the cost of a 32 x 32, 48 ps sample
QUICK_GRID = StudyGrid(points=24, bin_width_s=64e-12)


@dataclass
class StudyOptions:
    n_dataset: int = 200                # extra random reconstructions (metric validation)
    epochs: int | None = None           # the seed recipe's CNN (None: SEED_EPOCHS)
    grid: StudyGrid = field(default_factory=StudyGrid)
    materials: list[str] | None = None  # default: the ten presets
    seeds: int = 2                      # noise realisations per material, glyph, geometry
    sweep_seeds: int = 1
    sweep_materials: tuple[str, ...] = SWEEP_MATERIALS
    sweeps: dict = field(default_factory=lambda: dict(SWEEPS))
    legibility_sweeps: dict = field(default_factory=lambda: dict(LEGIBILITY_SWEEPS))
    glyphs: tuple[str, ...] = GLYPHS
    sweep_glyphs: tuple[str, ...] = GLYPHS  # glyphs reconstructed at each geometry-sweep point
    geometry_sweep_materials: tuple[str, ...] | None = None  # default: sweep_materials
    geometries: tuple[Geometry, ...] = GEOMETRIES
    labels: str = "legibility"
    seed: int = 0
    label: str = "full"
    real_data: Path | None = None       # folder holding cdt/*.mat (the real CDT captures)
    transport: str = "both"             # "both": also the bistatic comparison stage (--full);
    #                                     "confocal": the quick default (about 5 minutes)
    transport_glyphs: tuple[str, ...] | None = None  # the comparison's (default: glyphs)
    face_rings: int = COMPARE_RINGS     # the comparison's bistatic face samples
    face_angles: int = COMPARE_ANGLES
    inversions: tuple[str, ...] = INVERSIONS          # per material row (INVERSIONS)
    sweep_inversions: tuple[str, ...] = ("lambertian", "known")  # the legibility sweeps'
    auto_geometries: tuple[str, ...] | None = None  # where "auto" runs (default: every one)
    aware_glyphs: tuple[str, ...] | None = None  # what the BRDF-aware inversions
    #                                               reconstruct (default: glyphs)
    tilts_deg: tuple[float, ...] = TILTS_DEG
    tilt_materials: tuple[str, ...] = TILT_MATERIALS
    tilt_glyphs: tuple[str, ...] | None = None  # default: glyphs
    tilt_inversions: tuple[str, ...] = INVERSIONS
    judge_twins: int = 16               # twin scenes per twin geometry (clnlos.study.twins)

    @classmethod
    def quick(cls) -> StudyOptions:
        """The built-in default (the README main job, about 5 minutes on 2 CPU cores): a
        24 x 24 scan with 64 ps bins (QUICK_GRID); one noise realisation per glyph; the
        BRDF-aware inversions and the tilt sweep (0 and 10 deg) on two glyphs ("auto" at the
        legible geometry only), the geometry sweeps on two; legibility sweeps at the two
        sizes and exposures below the legible geometry's."""
        return cls(n_dataset=0, seeds=1, grid=QUICK_GRID, sweep_glyphs=("E", "H"),
                   aware_glyphs=("E", "P"), auto_geometries=(LEGIBLE_GEOMETRY,),
                   tilts_deg=(0.0, 10.0),
                   tilt_glyphs=("E", "P"), tilt_inversions=("lambertian", "known"),
                   legibility_sweeps={"letter_height_m": (0.1, 0.2),
                                      "exposure_s": (0.001, 0.01)},
                   geometry_sweep_materials=(SWEEP_MATERIALS[0], SWEEP_MATERIALS[-1]),
                   sweeps={"scan_width_m": (0.3, 0.6, 0.8), "depth_m": (0.3, 0.5, 0.7),
                           "slab_thickness_m": (0.0, 0.0254, 0.0508)}, label="quick",
                   transport="confocal", judge_twins=8)

    def validate(self) -> StudyOptions:
        if self.labels not in LABEL_METRICS:
            raise ParameterError("--labels", self.labels, " or ".join(LABEL_METRICS))
        if self.grid.method not in method_names():
            raise ParameterError("--method", self.grid.method, ", ".join(method_names()))
        if self.grid.snr_rule not in SNR_RULES:  # every method it is valid for (StudyGrid)
            raise ParameterError("snr_rule", self.grid.snr_rule, ", ".join(SNR_RULES))
        if self.judge_twins < 1:
            raise ParameterError("judge_twins", self.judge_twins, ">= 1")
        if self.n_dataset < 0:
            raise ParameterError("--n-dataset", self.n_dataset, ">= 0")
        if self.seeds < 1:
            raise ParameterError("seeds", self.seeds, ">= 1")
        if len(self.glyphs) < 2 or any(g not in GLYPHS for g in self.glyphs):
            raise ParameterError("glyphs", self.glyphs, f"two or more of {''.join(GLYPHS)}")
        if not self.sweep_glyphs or any(g not in self.glyphs for g in self.sweep_glyphs):
            raise ParameterError("sweep_glyphs", self.sweep_glyphs,
                                 f"one or more of {''.join(self.glyphs)}")
        if self.transport not in TRANSPORT_CHOICES:
            raise ParameterError("--transport", self.transport, " or ".join(TRANSPORT_CHOICES))
        if self.transport_glyphs is not None and (
                not self.transport_glyphs or any(g not in self.glyphs
                                                 for g in self.transport_glyphs)):
            raise ParameterError("transport_glyphs", self.transport_glyphs,
                                 f"one or more of {''.join(self.glyphs)}")
        if self.aware_glyphs is not None and (not self.aware_glyphs or any(
                g not in self.glyphs for g in self.aware_glyphs)):
            raise ParameterError("aware_glyphs", self.aware_glyphs,
                                 f"one or more of {''.join(self.glyphs)}")
        for name in ("inversions", "sweep_inversions", "tilt_inversions"):
            inv = getattr(self, name)
            if not inv or inv[0] != "lambertian" or any(v not in INVERSIONS for v in inv):
                raise ParameterError(name, inv, "\"lambertian\" first, then any of "
                                     + ", ".join(INVERSIONS[1:]))
        if any(not 0 <= t < 80 for t in self.tilts_deg):
            raise ParameterError("tilts_deg", self.tilts_deg, "tilts from 0 to below 80 deg")
        if self.tilt_glyphs is not None and (
                not self.tilt_glyphs or any(g not in self.glyphs for g in self.tilt_glyphs)):
            raise ParameterError("tilt_glyphs", self.tilt_glyphs,
                                 f"one or more of {''.join(self.glyphs)}")
        names = {g.name for g in self.geometries}
        if self.auto_geometries is not None and not set(self.auto_geometries) <= names:
            raise ParameterError("auto_geometries", self.auto_geometries,
                                 "names of the study's geometries: " + ", ".join(sorted(names)))
        if LEGIBLE_GEOMETRY not in names:
            raise ParameterError("geometries", [g.name for g in self.geometries],
                                 f"a list that includes {LEGIBLE_GEOMETRY!r}")
        return self

    def geometry(self, name: str) -> Geometry:
        return next(g for g in self.geometries if g.name == name)


def specular_fraction(model, theta_i_deg: float = 45.0, n: int = 64) -> float:
    """Share of the directional-hemispherical reflectance at theta_i not from the kd term
    (0 for Lambertian/Minnaert, 1 for a pure microfacet model)."""
    if model is None:
        return 0.0
    th = (np.arange(n) + 0.5) / n * np.pi / 2
    ph = (np.arange(2 * n) + 0.5) / (2 * n) * 2 * np.pi
    T, P = np.meshgrid(th, ph, indexing="ij")
    w = np.cos(T) * np.sin(T) * (np.pi / 2 / n) * (np.pi / n)
    ti = np.radians(theta_i_deg)
    total = float(np.sum(model(ti, 0.0, T, P) * w))
    if total <= 0:
        return 0.0
    spec = BRDFModel(model.name, {**model.params, "kd": 0.0})
    return float(np.clip(np.sum(spec(ti, 0.0, T, P) * w) / total, 0, 1))


def mean_interval(x) -> tuple[float, list[float]]:
    """Mean and its 95% t-interval [lo, hi] (the mean itself for one value)."""
    a = np.asarray(x, float)
    m = float(a.mean())
    if a.size < 2 or a.std() == 0:
        return m, [m, m]
    h = float(stdtrit(a.size - 1, 0.975) * a.std(ddof=1) / math.sqrt(a.size))
    return m, [m - h, m + h]


def noise_seed(base: int, *parts) -> int:
    """A sample's noise seed from what identifies it (not from its geometry: one scene asked
    for by two parts of the study is rendered once)."""
    return base * 1_000_003 + zlib.crc32("|".join(str(p) for p in parts).encode()) % 1_000_000


def glyph_sample(glyph: str, material: str, *, scan_width_m: float, height_m: float,
                 stroke_m: float, depth_m: float, exposure_s: float, seed: int,
                 slab_thickness_m: float | None = None, tilt_deg: float = 0.0,
                 inversion: str = "lambertian") -> dict:
    """The sample (:mod:`clnlos.study.dataset`) of one glyph, centred on the scan, facing it
    (or tilted by ``tilt_deg`` about the y axis), reconstructed with ``inversion``
    (:func:`inversion_brdf`)."""
    s = {"object": "letters", "text": glyph, "height_m": round(height_m, 6),
         "stroke_m": round(stroke_m, 6), "depth_m": depth_m, "scan_width_m": scan_width_m,
         "rotate_deg": [0.0, float(tilt_deg), 0.0], "exposure_s": exposure_s,
         "material": material, "seed": int(seed)}
    if slab_thickness_m is not None:
        s["slab_thickness_m"] = slab_thickness_m
    s.update(inversion_brdf(inversion, material))
    return s


def inversion_brdf(inversion: str, material: str) -> dict:
    """A sample's ``brdf`` (:mod:`clnlos.study.dataset`) for one of INVERSIONS: none for the
    Lambertian inversion and for a material whose lobe is flat (the same reconstruction up
    to the albedo, which the normalised MIP drops: one sample serves both); the material
    itself for "known"; "auto"."""
    if inversion == "lambertian" or (inversion == "known" and retro_lobe(material).flat):
        return {}
    return {"brdf": material if inversion == "known" else AUTO}


def _glyph_entries(opts: StudyOptions, geo: Geometry, material: str, glyphs, seeds: int,
                   meta: dict, *, height_m=None, exposure_s=DEFAULT_EXPOSURE_S,
                   scan_width_m=None, depth_m=None, slab_thickness_m=None, tilt_deg=0.0,
                   inversions=("lambertian",), aware_glyphs=None) -> list:
    """The plan entries of one material at one geometry: each glyph, noise realisation and
    inversion; the inversions other than the Lambertian for ``aware_glyphs`` only (None:
    every glyph)."""
    h = geo.letter_height_m if height_m is None else height_m
    stroke = geo.stroke_m if height_m is None else STROKE_PER_HEIGHT * h
    out = []
    aware = set(glyphs if aware_glyphs is None else aware_glyphs)
    for g in glyphs:
        for k in range(seeds):
            for inv in (v for v in inversions if v == "lambertian" or g in aware):
                s = glyph_sample(g, material, scan_width_m=scan_width_m or geo.scan_width_m,
                                 height_m=h, stroke_m=stroke, depth_m=depth_m or geo.depth_m,
                                 exposure_s=exposure_s,
                                 seed=noise_seed(opts.seed, material, g, k),
                                 slab_thickness_m=slab_thickness_m, tilt_deg=tilt_deg,
                                 inversion=inv)
                out.append(({**meta, "glyph": g, "material": material, "k": k,
                             "geometry": geo.name, "inversion": inv}, s))
    return out


def study_plan(materials, opts: StudyOptions) -> list[tuple[dict, dict]]:
    """Every (meta, sample) of the study: the materials at each geometry, the legibility
    sweeps (legible geometry; on ``aware_glyphs`` where set, for every inversion alike), the
    tilt sweep, the geometry sweeps (the seed's letters), the random extras."""
    plan = []
    for geo in opts.geometries:
        invs = tuple(i for i in opts.inversions if i != AUTO or opts.auto_geometries is None
                     or geo.name in opts.auto_geometries)
        for m in materials:
            plan += _glyph_entries(opts, geo, m, opts.glyphs, opts.seeds, {"set": "main"},
                                   inversions=invs, aware_glyphs=opts.aware_glyphs)
    legible = opts.geometry(LEGIBLE_GEOMETRY)
    for var, values in opts.legibility_sweeps.items():
        for v in values:
            for m in opts.sweep_materials:
                kw = {"height_m": v} if var == "letter_height_m" else {"exposure_s": v}
                # every inversion on the same glyphs: "smallest legible" compares them
                plan += _glyph_entries(opts, legible, m, opts.aware_glyphs or opts.glyphs,
                                       opts.sweep_seeds,
                                       {"set": "legibility_sweep", "variable": var,
                                        "value": float(v)},
                                       inversions=opts.sweep_inversions, **kw)
    for t in opts.tilts_deg:
        for m in opts.tilt_materials:
            plan += _glyph_entries(opts, legible, m, opts.tilt_glyphs or opts.glyphs,
                                   opts.sweep_seeds,
                                   {"set": "tilt_sweep", "variable": "tilt_deg",
                                    "value": float(t)}, tilt_deg=t,
                                   inversions=opts.tilt_inversions)
    seed_geo = next((g for g in opts.geometries if g.name == SEED_GEOMETRY),
                    opts.geometries[0])
    for var, values in opts.sweeps.items():
        for v in values:
            for m in opts.geometry_sweep_materials or opts.sweep_materials:
                kw = {var: float(v)}
                plan += _glyph_entries(opts, seed_geo, m, opts.sweep_glyphs, opts.sweep_seeds,
                                       {"set": "geometry_sweep", "variable": var,
                                        "value": float(v)}, **kw)
    for k, s in enumerate(dataset_samples(opts.n_dataset, list(materials), opts.seed)):
        plan.append(({"set": "dataset", "k": k, "material": s["material"]}, s))
    return plan


def render_plan(plan, grid: StudyGrid, cache: Path, **kw) -> list[dict]:
    """The result of every plan entry; each distinct scene rendered once (cached)."""
    keys = [json.dumps(s, sort_keys=True) for _, s in plan]
    unique = list(dict.fromkeys(keys))
    res = run_samples([json.loads(k) for k in unique], grid, cache, **kw)
    by_key = dict(zip(unique, res, strict=True))
    return [by_key[k] for k in keys]


def label_of(value: float, thresholds: tuple[float, float]) -> int:
    t_clear, t_fuzzy = thresholds
    return 1 if value >= t_clear else (3 if value < t_fuzzy else 2)


def legibility_label(identified: bool, iou: float, iou_box: float) -> int:
    """A reconstruction's legibility class: 1 identified and its IoU above the box baseline,
    2 one of the two, 3 neither."""
    return 1 if identified and iou > iou_box else (2 if identified or iou > iou_box else 3)


def material_class(ident: dict) -> int:
    """A material's legibility at a geometry: 1 identification >= LEGIBLE_ACCURACY, 3 not
    above chance (the Wilson interval reaches 1/K), 2 between."""
    if ident["accuracy"] >= LEGIBLE_ACCURACY:
        return 1
    return 3 if ident["ci"][0] <= ident["chance"] else 2


def resolution_geometry(geo: Geometry, grid: StudyGrid) -> ResolutionGeometry:
    """Where :func:`~clnlos.study.resolution.measure_resolution` measures a study geometry:
    its scan, depth, slab and letters on the study's grid (bins, pulse, window, iterations)."""
    return ResolutionGeometry(
        scan_width_m=geo.scan_width_m, points=grid.points, depth_m=geo.depth_m,
        bin_width_s=grid.bin_width_s, pulse_width_s=grid.pulse_width_s,
        max_path_m=window_m({"depth_m": geo.depth_m}, grid), iterations=grid.iterations,
        snr_rule=grid.snr_rule,
        text="E", letter_height_m=geo.letter_height_m, stroke_m=geo.stroke_m)


def study_resolution(opts: StudyOptions, device) -> tuple[dict, dict[str, float]]:
    """(results.json ``resolution``: every method, noise-free and at the budget, at the seed
    geometry; the study method's noise-free lateral FWHM at each geometry, m). A FWHM that
    cannot be measured (the profile never falls to half) falls back to O'Toole's bound."""
    seed_geo = next((g for g in opts.geometries if g.name == SEED_GEOMETRY),
                    opts.geometries[0])
    method = opts.grid.method
    res = measure_resolution(resolution_geometry(seed_geo, opts.grid), grid=opts.grid,
                             queue=device, exposure_s=DEFAULT_EXPOSURE_S)
    res = json_ready(res)
    gamma = res["effective_temporal_fwhm_s"]
    lateral = {}
    for geo in opts.geometries:
        r = res if geo.name == seed_geo.name else measure_resolution(
            resolution_geometry(geo, opts.grid), grid=opts.grid, queue=device,
            exposure_s=None, methods=(method,))
        fwhm = r[method]["lateral_fwhm_m"]
        lateral[geo.name] = (fwhm if fwhm is not None else
                             otoole_lateral_bound_m(geo.scan_width_m, geo.depth_m, gamma))
    return res, lateral


def identification_of(plan, results, opts: StudyOptions, gamma_s: float,
                      lateral: dict[str, float]) -> None:
    """Adds ``identified``, ``identified_as``, ``margin`` and ``legibility`` to every glyph
    result: its MIP matched to the closest of the K templates blurred to the lateral
    resolution (measured at the study's geometries, O'Toole's bound with the measured
    temporal FWHM elsewhere)."""
    measured = {(g.scan_width_m, g.depth_m): lateral[g.name] for g in opts.geometries}
    templates = {}
    for (meta, s), r in zip(plan, results, strict=True):
        if meta["set"] == "dataset":
            continue
        key = (s["scan_width_m"], s["height_m"], s["stroke_m"], s["depth_m"])
        if key not in templates:
            scene = Scene.from_dict(scene_dict(s, opts.grid))
            fwhm = measured.get((s["scan_width_m"], s["depth_m"]))
            if fwhm is None:  # resolution depends on the scan and the depth only
                fwhm = otoole_lateral_bound_m(s["scan_width_m"], s["depth_m"], gamma_s)
            templates[key] = glyph_templates(s["height_m"], s["stroke_m"], (0.0, 0.0),
                                             scene.scan_centres(), fwhm, opts.glyphs)
        best, margin, scores = identify(r["mip"], templates[key])
        r["identified_as"], r["margin"] = best, margin
        # the true glyph's NCC and its margin over the best other (> 0: identified)
        r["ncc_true"] = scores[s["text"]]
        r["true_margin"] = scores[s["text"]] - max(
            (v for g, v in scores.items() if g != s["text"]), default=-1.0)
        r["identified"] = bool(best == s["text"])
        # the time-integrated measurement matched the same way (no reconstruction at all)
        r["measurement_identified"] = bool(identify(r["meas_image"], templates[key])[0]
                                           == s["text"])
        r["legibility"] = legibility_label(r["identified"], r["iou"], r["iou_box_baseline"])
        if meta["set"] == "tilt_sweep":
            translation_identification(r, s, templates[key], opts.grid)


def translation_identification(r: dict, sample: dict, templates: dict, grid: StudyGrid) -> None:
    """The tilt sweep's identification (keys ``tilt_*``, beside the plain ones a tilt of 0
    shares with the main set): the MIP and the measurement matched up to a translation of
    TILT_MAX_SHIFT_M, with the displacement (m) of the true glyph's best match."""
    pitch = sample["scan_width_m"] / grid.points
    shift = int(math.ceil(TILT_MAX_SHIFT_M / pitch))
    truth = templates[sample["text"]]
    for prefix, img in (("tilt", r["mip"]), ("tilt_measurement", r["meas_image"])):
        r[f"{prefix}_identified"] = bool(identify(img, templates, shift)[0] == sample["text"])
        dy, dx = best_shift(img, truth, shift)
        r[f"{prefix}_shift_m"] = float(math.hypot(dy, dx) * pitch)


def tilt_rows(plan, results, chance: float) -> list[dict]:
    """One row per (tilt, material): identification up to translation per inversion and of
    the measurement alone, each with the mean displacement of the glyph (m), beside a
    mirror's z tan(tilt)."""
    groups: dict = {}
    for (meta, s), r in zip(plan, results, strict=True):
        if meta["set"] == "tilt_sweep":
            groups.setdefault((meta["value"], meta["material"]), []).append((meta, s, r))
    rows = []
    for (tilt, m), entries in sorted(groups.items()):
        row = {"tilt_deg": tilt, "material": m,
               "mirror_shift_m": entries[0][1]["depth_m"] * math.tan(math.radians(tilt))}
        for inv in dict.fromkeys(meta["inversion"] for meta, _, _ in entries):
            rs = [r for meta, _, r in entries if meta["inversion"] == inv]
            row[inv] = {"identification": identification_summary(
                [r["tilt_identified"] for r in rs], chance),
                "shift_m": float(np.mean([r["tilt_shift_m"] for r in rs]))}
        rs = [r for meta, _, r in entries if meta["inversion"] == "lambertian"]
        row["measurement"] = {"identification": identification_summary(
            [r["tilt_measurement_identified"] for r in rs], chance),
            "shift_m": float(np.mean([r["tilt_measurement_shift_m"] for r in rs]))}
        rows.append(row)
    return rows


def _summary(rows: list[dict], chance: float) -> dict:
    iou_mean, iou_ci = mean_interval([r["iou"] for r in rows])
    box = float(np.mean([r["iou_box_baseline"] for r in rows]))
    return {"identification": identification_summary([r["identified"] for r in rows], chance),
            "measurement_identification": identification_summary(
                [r["measurement_identified"] for r in rows], chance),
            "iou": iou_mean, "iou_ci": iou_ci, "iou_box_baseline": box,
            "iou_excess": iou_mean - box}


def material_entries(materials, plan, results, geo: Geometry, opts: StudyOptions, table,
                     label_metric: str, thresholds, fft_thresholds, predict) -> list[dict]:
    chance = 1.0 / len(opts.glyphs)
    out = []
    for m in materials:
        by_inv: dict[str, list[dict]] = {}
        for (meta, _), r in zip(plan, results, strict=True):
            if (meta["set"] == "main" and meta["geometry"] == geo.name
                    and meta["material"] == m):
                by_inv.setdefault(meta["inversion"], []).append(r)
        rs = by_inv["lambertian"]
        e = {"name": m, "geometry": geo.name, "brdf_class": table[m]["class"],
             **_summary(rs, chance), "iou_seeds": [float(r["iou"]) for r in rs],
             "inversions": {inv: {**_summary(v, chance),
                                  "lobe_halfwidth_deg": [float(r["lobe_halfwidth_deg"])
                                                         for r in v]}
                            for inv, v in by_inv.items()}}
        if label_metric == "identification":
            value = e["identification"]["accuracy"]
            label = material_class(e["identification"])
        else:
            value = float(np.mean([r[f"q_{label_metric}"] for r in rs]))
            label = label_of(value, thresholds)
        fft_mean = float(np.mean([r["q_fft_clarity"] for r in rs]))
        cnn_label, p = cnn_material_label(predict, np.stack([r["mip"] for r in rs]),
                                          label_metric, chance)
        e.update({
            "label": label, "label_metric_value": value,
            "cnn_label": cnn_label, "cnn_probabilities": [float(v) for v in p],
            "seed_label": SEED_FIGURE9.get(m),
            "clarity_score": fft_mean, "clarity_label": label_of(fft_mean, fft_thresholds),
            "depth_error_m": float(np.mean([r["depth_error_m"] for r in rs])),
            "psnr_db": float(np.mean([r["psnr_db"] for r in rs])),
            "photon_counts": float(np.mean([r["counts"] for r in rs])),
            "specular_fraction": specular_fraction(preset_model(m)),
            "provenance": table[m].get("provenance", "")})
        out.append(e)
    return out


def cnn_material_label(predict, mips: np.ndarray, label_metric: str,
                       chance: float) -> tuple[int, np.ndarray]:
    """(the CNN's class of a material, its mean probabilities) from the material's MIPs.
    The legibility classifier (``predict``: images -> P(legible)) gives [P, 1 - P], the mean
    P being its expected share of legible reconstructions, classed like identification
    (:func:`material_class`, the interval of that share of the n MIPs); the seed's recipe
    (``predict``: images -> (labels, probabilities)) the class of its mean probabilities."""
    if label_metric == "identification":
        p = float(np.mean(predict(mips)))
        n = len(mips)
        ident = {"accuracy": p, "ci": wilson_interval(int(round(p * n)), n), "chance": chance}
        return material_class(ident), np.array([p, 1.0 - p])
    _, probs = predict(mips)
    p = probs.mean(axis=0)
    return int(np.argmax(p) + 1), p


def sweep_rows(plan, results, which: str, chance: float) -> list[dict]:
    """One row per (variable, value, material, inversion) of a sweep set."""
    groups: dict = {}
    for (meta, _), r in zip(plan, results, strict=True):
        if meta["set"] == which:
            groups.setdefault((meta["variable"], meta["value"], meta["material"],
                               meta["inversion"]), []).append(r)
    rows = []
    for (var, v, m, inv), rs in groups.items():
        rows.append({"variable": var, "value": v, "material": m, "inversion": inv,
                     "n": len(rs),
                     **_summary(rs, chance),
                     "photon_counts": float(np.mean([r["counts"] for r in rs])),
                     "depth_error_m": float(np.mean([r["depth_error_m"] for r in rs]))})
    return rows


def smallest_legible(rows: list[dict], materials, inversions=("lambertian",)) -> list[dict]:
    """Per material and inversion: the smallest letter height and the smallest exposure whose
    identification reaches LEGIBLE_ACCURACY (None where no swept value does); per material
    also the best over the inversions (``inversion = "best"``, naming which one gave each
    number)."""
    def first(var, m, inv):
        ok = sorted(r["value"] for r in rows if r["variable"] == var and r["material"] == m
                    and r["inversion"] == inv
                    and r["identification"]["accuracy"] >= LEGIBLE_ACCURACY)
        return ok[0] if ok else None

    out = []
    for m in materials:
        per = [{"material": m, "inversion": inv, "letter_height_m": first("letter_height_m",
                                                                          m, inv),
                "exposure_s": first("exposure_s", m, inv)} for inv in inversions]
        best = {"material": m, "inversion": "best"}
        for var in ("letter_height_m", "exposure_s"):  # a tie goes to the earlier inversion
            have = [(p[var], k, p["inversion"]) for k, p in enumerate(per) if p[var] is not None]
            best[var], _, best[f"{var}_inversion"] = min(have) if have else (None, None, None)
        out += per + [best]
    return out


def _samples_labels(results, idx, label_metric, thresholds) -> np.ndarray:
    if label_metric == "identification":
        return np.array([results[i]["legibility"] for i in idx])
    return np.array([label_of(results[i][f"q_{label_metric}"], thresholds) for i in idx])


def cnn_samples(plan, label_metric: str) -> list[int]:
    """Plan indices of the seed recipe's images: every glyph reconstruction (and the random
    extras for the metric labels), one per distinct scene."""
    use = [i for i, (meta, _) in enumerate(plan)
           if meta["set"] != "dataset" or label_metric != "identification"]
    seen, idx = set(), []
    for i in use:
        key = json.dumps(plan[i][1], sort_keys=True)
        if key not in seen:
            seen.add(key)
            idx.append(i)
    return idx


def train_cnn(plan, results, opts: StudyOptions, label_metric: str, thresholds):
    """The seed's recipe (``--labels fft`` / ``nr``) on :func:`cnn_samples`: validation on
    the held-out glyphs and letter size."""
    idx = cnn_samples(plan, label_metric)
    held = np.array([plan[i][0].get("glyph") in HELD_OUT_GLYPHS
                     or (plan[i][0].get("variable") == "letter_height_m"
                         and plan[i][0].get("value") == HELD_OUT_HEIGHT_M) for i in idx])
    labels = _samples_labels(results, idx, label_metric, thresholds)
    images = np.stack([results[i]["mip"] for i in idx])
    with progress_bar(None, "study CNN", "batch") as bar:
        predict, report = train_classifier(images, labels, epochs=opts.epochs or SEED_EPOCHS,
                                           seed=opts.seed, progress=counter(bar),
                                           val_mask=held)
    report["held_out"] = {"glyphs": list(HELD_OUT_GLYPHS), "letter_height_m": HELD_OUT_HEIGHT_M}
    return predict, report, labels


def real_capture_dir(root: Path | None) -> Path | None:
    """``root/cdt`` when it holds at least one of the real CDT captures, else None (with a
    one-line warning when ``root`` was given: the study goes on without the real data)."""
    if root is None:
        return None
    cdt = Path(root) / "cdt"
    if any((cdt / f"{n}.mat").is_file() for n in PUBLISHED_SCAN_WIDTH_M):
        return cdt
    warnings.warn(f"--real-data {root}: no real CDT capture ({', '.join(PUBLISHED_SCAN_WIDTH_M)}"
                  ".mat) in its cdt/ folder; the report goes without the real captures",
                  UserWarning, stacklevel=2)
    return None


def real_captures_cnn(rows: list[dict], predict, label_metric: str) -> list[dict]:
    """The CNN's verdict on each real capture at all its photons (the fraction-1 rows of
    :func:`clnlos.study.thinning_real.real_thinning`): the legibility classifier's
    ``p_legible`` (label 1 legible at P >= 1/2, else 3), or the seed recipe's class."""
    out = []
    for r in rows:
        if r["fraction"] != 1.0:
            continue
        if label_metric == "identification":
            label, probs = (1 if r["p_legible"] >= 0.5 else 3), [r["p_legible"]]
        else:
            lab, pr = predict(r["mip"][None])
            label, probs = int(lab[0]), [float(v) for v in pr[0]]
        out.append({"name": r["capture"], "cnn_label": int(label), "p_legible": r["p_legible"],
                    "cnn_probabilities": probs, "mip": r["mip"]})
    return out


def real_data_study(cdt: Path, predict, grid: StudyGrid, device=None, *, legibility,
                    label_metric: str = "identification", cache: Path | None = None) -> dict:
    """The real captures in ``cdt``: letters_ut beside a simulation of a comparable scene
    (:func:`clnlos.study.real_capture.compare_real_capture`, its figure), the resolution
    chart's resolved features, every capture thinned to THINNING_FRACTIONS of its photons
    with the ``legibility`` classifier's P(legible) (``thinning``) and the CNN's verdict at
    all its photons (``cnn``)."""
    out: dict = {"summary": None, "figure": None, "chart": None}
    if (cdt / "letters_ut.mat").is_file():
        cmp = compare_real_capture(cdt / "letters_ut.mat", grid.method,
                                   iterations=grid.iterations, grid=grid, queue=device)
        out["figure"] = real_capture_figure(cmp)
        cmp.pop("arrays")
        out["summary"] = cmp
    if (cdt / "resolution_70.mat").is_file():
        chart = reconstruct_chart(cdt / "resolution_70.mat", "lct", queue=device)
        chart.pop("arrays", None)
        out["chart"] = chart
    t0 = time.perf_counter()
    with progress_bar(None, "real captures thinned", "reconstruction") as bar:
        out["thinning"] = real_thinning(cdt, grid, legibility.predict_proba, cache=cache,
                                        device=device, progress=counter(bar))
    out["thinning_s"] = time.perf_counter() - t0
    out["cnn"] = real_captures_cnn(out["thinning"], predict, label_metric)
    return out


def run_study(out_dir: Path, opts: StudyOptions, *, workers: int | None = None,
              scheduler: str | None = None, device: str | None = None) -> dict:
    opts = opts.validate()
    out_dir.mkdir(parents=True, exist_ok=True)
    cache = out_dir / "cache"
    table = preset_table()
    materials = opts.materials or list(table)
    unknown = [m for m in materials if m not in table]
    if unknown:
        raise ParameterError("materials", unknown[0], "the preset names: " + ", ".join(table))
    nw = cpu_workers(workers) if scheduler is None else 1
    timings = {}
    chance = 1.0 / len(opts.glyphs)

    # -- every sample through one pool (cached)
    plan = study_plan(materials, opts)
    t0 = time.perf_counter()
    results = render_plan(plan, opts.grid, cache, workers=nw, scheduler=scheduler,
                          device=device, desc="study samples")
    timings["samples_s"] = time.perf_counter() - t0

    # -- resolution, identification
    t0 = time.perf_counter()
    resolution, lateral = study_resolution(opts, device)
    identification_of(plan, results, opts, resolution["effective_temporal_fwhm_s"], lateral)
    timings["resolution_s"] = time.perf_counter() - t0

    # -- metrics, labels
    glyph_idx = [i for i, (meta, _) in enumerate(plan) if meta["set"] != "dataset"]
    truth = {k: np.array([results[i][k] for i in glyph_idx], float)
             for k in ("iou", "depth_error_m", "psnr_db", "identified")}
    truth["iou_excess"] = np.array([results[i]["iou"] - results[i]["iou_box_baseline"]
                                    for i in glyph_idx])
    values = {m: np.array([results[i][f"q_{m}"] for i in glyph_idx]) for m in METRICS}
    validation = validate_metrics(values, truth)
    label_metric = LABEL_METRICS[opts.labels]
    all_values = {m: np.array([r[f"q_{m}"] for r in results]) for m in METRICS}
    thresholds = ((0.5, 0.5) if label_metric == "identification"
                  else label_thresholds(all_values[label_metric]))
    fft_thresholds = label_thresholds(all_values["fft_clarity"])

    # -- the materials under both transports (legible geometry)
    comparison = None
    if opts.transport == "both":
        t0 = time.perf_counter()
        comparison = transport_comparison(materials, opts, cache, resolution, lateral,
                                          table, workers=nw, scheduler=scheduler,
                                          device=device)
        timings["transport_s"] = time.perf_counter() - t0

    # -- CNN: the legibility classifier on every reconstruction with ground truth (each
    #    rendered plan's) and, for --labels fft / nr, the seed's recipe, whose classes then
    #    label the materials
    t0 = time.perf_counter()
    rendered = [(plan, results)] + ([] if comparison is None else
                                    [(comparison["plan"], comparison["results"])])
    with progress_bar(None, "legibility judge twins", "scene") as bar:
        legibility, classifier, judge, family = study_judge(
            [(s, r) for p, rs in rendered for (_, s), r in zip(p, rs, strict=True)], out_dir,
            per_geometry=opts.judge_twins, seed=opts.seed, cache=cache,
            real_root=opts.real_data, device=device, progress=counter(bar))
    classifier_splits = classifier["splits"]
    predict, seed_cnn = legibility.predict_proba, None
    labels = _samples_labels(results, cnn_samples(plan, label_metric), label_metric,
                             thresholds)
    if label_metric != "identification":
        predict, seed_cnn, labels = train_cnn(plan, results, opts, label_metric, thresholds)
    timings["cnn_s"] = time.perf_counter() - t0

    # -- materials per geometry
    geometries = []
    for geo in opts.geometries:
        ents = material_entries(materials, plan, results, geo, opts, table, label_metric,
                                thresholds, fft_thresholds, predict)
        geometries.append({**asdict(geo), "lateral_resolution_m": lateral[geo.name],
                           "stroke_over_resolution": geo.stroke_m / lateral[geo.name],
                           "materials": ents})
    main_geo = next(g for g in geometries if g["name"] == LEGIBLE_GEOMETRY)
    per_material = main_geo["materials"]
    agreement = {g["name"]: sum(m["label"] == m["seed_label"] for m in g["materials"]
                                if m["seed_label"] is not None) for g in geometries}
    cnn_agreement = sum(m["cnn_label"] == m["seed_label"] for m in per_material
                        if m["seed_label"] is not None)

    # -- sweeps
    legibility_rows = sweep_rows(plan, results, "legibility_sweep", chance)
    geometry_rows = sweep_rows(plan, results, "geometry_sweep", chance)
    tilts = tilt_rows(plan, results, chance)
    need = smallest_legible(legibility_rows, opts.sweep_materials, opts.sweep_inversions)

    # -- real captures (shared data): the simulated twin, the CNN's verdict
    t0 = time.perf_counter()
    cdt = real_capture_dir(opts.real_data)
    real = None if cdt is None else real_data_study(
        cdt, predict, opts.grid, device, legibility=legibility, label_metric=label_metric,
        cache=cache)
    if real is not None and real["chart"] is not None:
        resolution["real_chart"] = real["chart"]
    timings["real_capture_s"] = time.perf_counter() - t0
    if real is not None:
        timings["real_thinning_s"] = real["thinning_s"]

    findings = make_findings(geometries, need, geometry_rows, validation, label_metric,
                             classifier_splits, agreement, opts, tilts)
    ious = np.array([r["iou"] for r in results])
    hist, edges = np.histogram(ious, bins=10, range=(0, 1))
    results_json = {
        "study": opts.label,
        "options": {**asdict(opts), "grid": asdict(opts.grid), "workers": nw,
                    "real_data": None if opts.real_data is None else str(opts.real_data)},
        "materials": per_material,
        "geometries": geometries, "legible_geometry": LEGIBLE_GEOMETRY,
        "seed_geometry": next((g["name"] for g in geometries if g["name"] == SEED_GEOMETRY),
                              geometries[0]["name"]),
        "resolution": resolution,
        "inversions": list(opts.inversions),
        "legibility_sweeps": [{"variable": r["variable"], "value": r["value"],
                               "material": r["material"], "inversion": r["inversion"],
                               "identification": r["identification"], "iou": r["iou"],
                               "iou_box_baseline": r["iou_box_baseline"],
                               "iou_excess": r["iou_excess"],
                               "photon_counts": r["photon_counts"], "n": r["n"]}
                              for r in legibility_rows],
        "smallest_legible": need, "tilt_sweep": tilts, "tilt_max_shift_m": TILT_MAX_SHIFT_M,
        "real_capture": None if real is None else real["summary"],
        "real_captures_cnn": None if real is None else [
            {k: v for k, v in c.items() if k != "mip"} for c in real["cnn"]],
        "classifier": {**classifier, "real_thinning": [] if real is None else [
            {k: r[k] for k in ("capture", "fraction", "photons", "p_legible")}
            for r in real["thinning"]]},
        "judge": judge, **({} if seed_cnn is None else {"cnn_seed_recipe": seed_cnn}),
        "labels": {"source": opts.labels, "metric": label_metric,
                   "corr_with_iou": validation[label_metric]["iou"]
                   if label_metric in validation else pearson(truth["identified"],
                                                               truth["iou"]),
                   "thresholds": list(thresholds),
                   "counts": {str(k): int((labels == k).sum()) for k in (1, 2, 3)}},
        "metrics": {m: validation[m]["iou"] for m in METRICS},
        "metric_validation": validation,
        "clarity_thresholds": list(fft_thresholds),
        "label_counts": {str(k): int((labels == k).sum()) for k in (1, 2, 3)},
        "seed_figure9_agreement": int(agreement[LEGIBLE_GEOMETRY]),
        "seed_figure9_agreement_by_geometry": agreement,
        "seed_figure9_agreement_cnn": int(cnn_agreement),
        "sweeps": geometry_rows,
        "dataset": {"n": len(results), "iou_median": float(np.median(ious)),
                    "iou_histogram": {"edges": edges.tolist(), "counts": hist.tolist()},
                    "iou_zero_fraction": float(np.mean(ious == 0))},
        "findings": findings, "timings_s": timings, "n_dataset": len(results)}
    if comparison is not None:
        results_json["transport_comparison"] = {
            **{k: v for k, v in comparison.items() if k not in ("plan", "results")},
            "face_rings": opts.face_rings, "face_angles": opts.face_angles,
            "glyphs": list(opts.transport_glyphs or opts.glyphs),
            "geometry": LEGIBLE_GEOMETRY}
    t0 = time.perf_counter()
    results_json["cost"] = study_cost(plan, results, timings, comparison)
    if real is not None:
        real["family"] = family  # the family split's MIPs, for the report's figure
    write_report(out_dir, results_json, plan, results, real)
    timings["report_s"] = time.perf_counter() - t0
    results_json["cost"] = study_cost(plan, results, timings, comparison)
    with atomic_path(out_dir / "results.json") as tmp:
        tmp.write_text(json.dumps(stamp(results_json), indent=1))
    return results_json


def study_cost(plan, results, timings: dict, comparison: dict | None = None) -> dict:
    """Where the study's time goes: per part of the plan (the main table, each sweep, the
    random extras, the transport comparison) its entries, the distinct samples they need
    and the seconds those samples took to simulate and to reconstruct (summed over the
    workers, as each sample recorded when it was rendered: a sample read from the cache
    costs nothing now); and each stage's wall time (``timings``)."""
    parts: dict[str, dict] = {}
    seen: set[str] = set()
    entries = list(zip(plan, results, strict=True))
    if comparison is not None:
        entries += [(({"set": "transport_comparison"}, s), r) for (_, s), r in
                    zip(comparison["plan"], comparison["results"], strict=True)]
    for (meta, sample), r in entries:
        row = parts.setdefault(meta["set"], {"part": meta["set"], "entries": 0, "samples": 0,
                                             "simulate_s": 0.0, "reconstruct_s": 0.0})
        row["entries"] += 1
        key = json.dumps(sample, sort_keys=True)
        if key in seen:
            continue  # rendered once, counted where first asked for
        seen.add(key)
        row["samples"] += 1
        row["simulate_s"] += float(r.get("simulate_s", 0.0))
        row["reconstruct_s"] += float(r.get("reconstruct_s", 0.0))
    return {"parts": list(parts.values()), "stages_s": dict(timings),
            "total_s": float(sum(timings.values()))}


def transport_comparison(materials, opts: StudyOptions, cache: Path, resolution: dict,
                         lateral: dict[str, float], table=None, **kw) -> dict:
    """The materials at the legible geometry under the confocal and the bistatic transport
    (:mod:`clnlos.study.transport_compare`): its table, with ``plan`` and ``results``."""
    plan = comparison_plan(materials, opts)
    results = render_plan(plan, opts.grid, cache, desc="transport comparison", **kw)
    identification_of(plan, results, opts, resolution["effective_temporal_fwhm_s"], lateral)
    out = comparison_table(materials, plan, results, 1.0 / len(opts.glyphs), table)
    return {**out, "plan": plan, "results": results}


def _class_mean(entries, classes, key) -> float | None:
    vals = [key(m) for m in entries if m["brdf_class"] in classes]
    return float(np.mean(vals)) if vals else None


def inversion_accuracy(m: dict, inversion: str) -> float | None:
    """A material entry's identification accuracy with one inversion (None if not run)."""
    if inversion == "lambertian":
        return m["identification"]["accuracy"]
    v = m.get("inversions", {}).get(inversion)
    return None if v is None else v["identification"]["accuracy"]


def make_findings(geometries, need, geometry_rows, validation, label_metric,
                  classifier_splits, agreement, opts: StudyOptions, tilts=()) -> dict:
    """The study's answer in numbers."""
    def acc(m):
        return m["identification"]["accuracy"]

    def by_class(ms, classes, inv):
        vals = [inversion_accuracy(m, inv) for m in ms if m["brdf_class"] in classes]
        vals = [v for v in vals if v is not None]
        return float(np.mean(vals)) if vals else None

    f: dict = {"by_geometry": {}}
    for g in geometries:
        ms = g["materials"]
        spec = np.array([m["specular_fraction"] for m in ms])
        f["by_geometry"][g["name"]] = {
            "identification_lambertian_and_diffuse": _class_mean(
                ms, ("Lambertian", "strong diffuse"), acc),
            "identification_strong_specular": _class_mean(ms, ("strong specular",), acc),
            "measurement_identification_strong_specular": _class_mean(
                ms, ("strong specular",),
                lambda m: m["measurement_identification"]["accuracy"]),
            "measurement_identification_lambertian_and_diffuse": _class_mean(
                ms, ("Lambertian", "strong diffuse"),
                lambda m: m["measurement_identification"]["accuracy"]),
            "identification_specular_plus_diffuse": _class_mean(
                ms, ("strong specular + diffuse",), acc),
            "iou_excess_lambertian_and_diffuse": _class_mean(
                ms, ("Lambertian", "strong diffuse"), lambda m: m["iou_excess"]),
            "iou_excess_strong_specular": _class_mean(ms, ("strong specular",),
                                                      lambda m: m["iou_excess"]),
            "corr_specular_fraction_vs_identification": pearson(
                spec, np.array([acc(m) for m in ms])),
            "stroke_over_resolution": g["stroke_over_resolution"],
            "by_inversion": {inv: {
                "strong_specular": by_class(ms, ("strong specular",), inv),
                "specular_plus_diffuse": by_class(ms, ("strong specular + diffuse",), inv),
                "lambertian_and_diffuse": by_class(ms, ("Lambertian", "strong diffuse"), inv)}
                for inv in opts.inversions}}
    main = f["by_geometry"][LEGIBLE_GEOMETRY]
    seed = f["by_geometry"].get(SEED_GEOMETRY)
    # keep today's keys, now about the legible geometry
    legible_ms = next(g for g in geometries if g["name"] == LEGIBLE_GEOMETRY)["materials"]
    ious = np.array([m["iou"] for m in legible_ms])
    spec = np.array([m["specular_fraction"] for m in legible_ms])
    f.update({
        "corr_specular_fraction_vs_iou_materials": pearson(spec, ious),
        "iou_mean_lambertian_and_diffuse": _class_mean(legible_ms, ("Lambertian",
                                                                    "strong diffuse"),
                                                       lambda m: m["iou"]),
        "iou_mean_strong_specular": _class_mean(legible_ms, ("strong specular",),
                                                lambda m: m["iou"]),
        "iou_mean_specular_plus_diffuse": _class_mean(legible_ms,
                                                      ("strong specular + diffuse",),
                                                      lambda m: m["iou"]),
        "iou_spread_materials": float(ious.max() - ious.min()),
        "label_corr_with_iou": validation.get(label_metric, {}).get("iou"),
        "corr_clarity_vs_iou_dataset": validation["fft_clarity"]["iou"],
        "corr_clarity_vs_identified": validation["fft_clarity"]["identified"],
        "corr_nr_clarity_vs_identified": validation["nr_clarity"]["identified"],
        "corr_clarity_vs_depth_error_dataset": validation["fft_clarity"]["depth_error_m"],
        "corr_clarity_vs_psnr_dataset": validation["fft_clarity"]["psnr_db"],
        "cnn_balanced_accuracy": {k: v["balanced_accuracy"]
                                  for k, v in classifier_splits.items()},
        "cnn_one_feature_baseline": {k: v["baseline"] for k, v in classifier_splits.items()},
        "seed_figure9_agreement": agreement[LEGIBLE_GEOMETRY]})
    # material cost in photons and size, per inversion and with the best for each
    f["smallest_legible"] = need
    f["sweeps"] = geometry_sweep_effects(geometry_rows)
    spread = [(float(np.ptp([s["identification"]["accuracy"] for s in geometry_rows
                             if (s["variable"], s["value"]) == key])), key)
              for key in {(s["variable"], s["value"]) for s in geometry_rows}]
    if spread:
        best, (var, val) = max(spread)
        f["largest_material_spread"] = {"variable": var, "value": val,
                                        "identification_spread": best}
    ld, sp = main["identification_lambertian_and_diffuse"], main["identification_strong_specular"]
    f["seed_conclusion_holds"] = bool(ld is not None and sp is not None and ld > sp)
    aware = [inv for inv in opts.inversions if inv != "lambertian"]
    best_sp = max([v for v in (main["by_inversion"][inv]["strong_specular"] for inv in aware)
                   if v is not None], default=None)
    f["brdf_aware_closes_gap"] = bool(best_sp is not None and ld is not None
                                      and best_sp >= ld - GAP_CLOSED)
    f["tilt"] = tilt_findings(tilts, opts.tilt_inversions)
    f["statement"] = study_statement(main, seed, need, f, opts)
    return f


def geometry_sweep_effects(geometry_rows) -> dict:
    """Per geometry variable: the identification range per material (geometry's effect)
    beside the spread across materials at each value (the material's effect)."""
    effect = {}
    for var in sorted({s["variable"] for s in geometry_rows}):
        rows = [s for s in geometry_rows if s["variable"] == var]
        per_m = {}
        for m in sorted({s["material"] for s in rows}):
            ys = [s["identification"]["accuracy"] for s in rows if s["material"] == m]
            per_m[m] = {"min": float(min(ys)), "max": float(max(ys)),
                        "range": float(max(ys) - min(ys))}
        geometry = float(np.mean([v["range"] for v in per_m.values()]))
        vals = sorted({s["value"] for s in rows})
        material = float(np.mean([np.ptp([s["identification"]["accuracy"] for s in rows
                                           if s["value"] == v]) for v in vals]))
        effect[var] = {"per_material": per_m, "geometry_effect": geometry,
                       "material_effect": material,
                       "dominant": "geometry" if geometry > material else "material"}
    return effect


def tilt_findings(tilts, inversions) -> dict:
    """Per tilt: the mean identification (up to translation) of the strong-specular tilt
    materials per inversion and of the measurement, and the worst gap of any (material, tilt)
    cell's best inversion below the measurement."""
    table = preset_table()
    out: dict = {"per_tilt": {}, "worst_gap_below_measurement": None}
    gaps = []
    for t in sorted({r["tilt_deg"] for r in tilts}):
        rows = [r for r in tilts if r["tilt_deg"] == t]
        spec = [r for r in rows if table.get(r["material"], {}).get("class") == "strong specular"]
        entry = {}
        for inv in (*inversions, "measurement"):
            vals = [r[inv]["identification"]["accuracy"] for r in spec if inv in r]
            entry[inv] = float(np.mean(vals)) if vals else None
        out["per_tilt"][f"{t:g}"] = entry
        for r in rows:
            best = max(r[inv]["identification"]["accuracy"] for inv in inversions if inv in r)
            gaps.append((r["measurement"]["identification"]["accuracy"] - best,
                         r["material"], t))
    if gaps:
        g, m, t = max(gaps)
        out["worst_gap_below_measurement"] = {"gap": float(g), "material": m, "tilt_deg": t}
    return out


def study_statement(main: dict, seed: dict | None, need: list[dict], f: dict,
                    opts: StudyOptions) -> str:
    """The study's answer in words, every number naming the inversion it comes from."""
    chance = 1.0 / len(opts.glyphs)

    def pct(v):
        return "n/a" if v is None else f"{100 * v:.0f}%"

    inv = main["by_inversion"]
    aware = [i for i in opts.inversions if i != "lambertian"]
    names = {"known": "with the material's own BRDF", "auto": "with the lobe chosen from the "
             "capture (brdf auto)"}
    aware_txt = "; ".join(
        f"{names[i]}: strong-specular {pct(inv[i]['strong_specular'])}, mixed "
        f"{pct(inv[i]['specular_plus_diffuse'])}, Lambertian and strong-diffuse "
        f"{pct(inv[i]['lambertian_and_diffuse'])}" for i in aware)
    best = [n for n in need if n["inversion"] == "best"]

    def cost(n, var, unit):
        if n[var] is None:
            return f"{n['material']}: not within the swept values"
        return f"{n['material']}: {n[var]:g} {unit} ({n[f'{var}_inversion']} inversion)"

    tilt = f["tilt"]["per_tilt"]
    tilt_txt = "; ".join(
        f"{t} deg: " + ", ".join(f"{k} {pct(v)}" for k, v in e.items()) for t, e in tilt.items())
    text = (
        f"At the legible geometry (stroke / resolution {main['stroke_over_resolution']:.1f}) "
        f"the Lambertian inversion identifies Lambertian and strong-diffuse targets in "
        f"{pct(main['identification_lambertian_and_diffuse'])} of reconstructions, "
        f"strong-specular ones in {pct(main['identification_strong_specular'])} and mixed "
        f"ones in {pct(main['identification_specular_plus_diffuse'])} (chance "
        f"{pct(chance)}). The time-integrated measurement alone is identified in "
        f"{pct(main['measurement_identification_strong_specular'])} for strong-specular "
        f"targets: their data hold the glyph. A BRDF-aware inversion reads what the data "
        f"hold ({aware_txt}). "
        + (f"At the seed's Table 1 geometry (stroke / resolution "
           f"{seed['stroke_over_resolution']:.1f}) the Lambertian inversion identifies diffuse "
           f"targets in {pct(seed['identification_lambertian_and_diffuse'])} and "
           f"strong-specular ones in {pct(seed['identification_strong_specular'])}; "
           + "; ".join(f"{names[i]} strong-specular "
                       f"{pct(seed['by_inversion'][i]['strong_specular'])}" for i in aware
                       if seed["by_inversion"][i]["strong_specular"] is not None)
           + ". " if seed else "")
        + f"Smallest legible letters (identification >= {LEGIBLE_ACCURACY:g}, the best "
        f"inversion for each material): "
        + "; ".join(cost(n, "letter_height_m", "m") for n in best)
        + ". Exposure per scan point needed: "
        + "; ".join(cost(n, "exposure_s", "s") for n in best) + ". "
        + (f"Tilted strong-specular glyphs, matched up to a translation (identification): "
           f"{tilt_txt}. " if tilt else "")
        + ("With the Lambertian inversion less specular targets are read more often, as the "
           "seed concluded; " if f["seed_conclusion_holds"] else
           "With the Lambertian inversion the seed's conclusion (less specular -> clearer) is "
           "not supported; ")
        + ("with an inversion that knows the lobe, strong-specular targets are read about as "
           "often as diffuse ones: the seed's ranking is the Lambertian assumption's, not the "
           "material's." if f["brdf_aware_closes_gap"] else
           "a BRDF-aware inversion does not close the gap: the material itself costs "
           "legibility here."))
    return text


def comparison_plan(materials, opts) -> list[tuple[dict, dict]]:
    """(meta, sample) of every comparison sample: per material, glyph and noise realisation
    at the legible geometry, once confocal (the study's main sample itself) and once
    bistatic (the same sample with a ``transport`` table)."""
    geo = opts.geometry(LEGIBLE_GEOMETRY)
    table = bistatic_table(opts.face_rings, opts.face_angles)
    plan = []
    for m in materials:
        for meta, s in _glyph_entries(opts, geo, m, opts.transport_glyphs or opts.glyphs,
                                      opts.seeds,
                                      {"set": "transport"}):
            plan.append(({**meta, "transport": "confocal"}, s))
            plan.append(({**meta, "transport": "bistatic"}, {**s, "transport": table}))
    return plan
