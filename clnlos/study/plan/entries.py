"""The study's plan: its geometries, materials, sweeps and options (:class:`StudyOptions`,
the quick and the full study), and every (meta, sample) the study renders (:func:`study_plan`,
:func:`comparison_plan`). Pure: nothing is rendered here."""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field
from pathlib import Path

from clnlos.brdf.lobes import AUTO, retro_lobe
from clnlos.config import SNR_RULES
from clnlos.errors import ParameterError
from clnlos.inverse.methods import method_names
from clnlos.study.plan.scenes import StudyGrid, dataset_samples
from clnlos.study.score.legibility import GLYPHS
from clnlos.study.score.quality import DEFAULT_LABEL_METRIC
from clnlos.study.findings.transport import COMPARE_ANGLES, COMPARE_RINGS, bistatic_table


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
    judge_twins: int = 16               # twin scenes per twin geometry (clnlos.study.judge.twins;
    #                                     quick and full alike: docs/validation/legibility-judge.md)

    @classmethod
    def quick(cls) -> StudyOptions:
        """The built-in default (the README main job, about 5 minutes on 2 CPU cores): a
        24 x 24 scan with 64 ps bins (QUICK_GRID); one noise realisation per glyph; the
        BRDF-aware inversions and the tilt sweep (0 and 10 deg) on two glyphs ("auto" at the
        legible geometry only), the geometry sweeps on two; legibility sweeps at four letter
        heights and five exposures over four decades, the legible geometry's own (0.3 m, 0.1 s)
        among them: those points are the main set's samples, rendered once (docs/performance.md,
        the quick study's budget)."""
        return cls(n_dataset=0, seeds=1, grid=QUICK_GRID, sweep_glyphs=("E", "H"),
                   aware_glyphs=("E", "P"), auto_geometries=(LEGIBLE_GEOMETRY,),
                   tilts_deg=(0.0, 10.0),
                   tilt_glyphs=("E", "P"), tilt_inversions=("lambertian", "known"),
                   legibility_sweeps={"letter_height_m": (0.1, 0.15, 0.2, 0.3),
                                      "exposure_s": (1e-5, 1e-4, 0.001, 0.01, 0.1)},
                   geometry_sweep_materials=(SWEEP_MATERIALS[0], SWEEP_MATERIALS[-1]),
                   sweeps={"scan_width_m": (0.3, 0.6, 0.8), "depth_m": (0.3, 0.5, 0.7),
                           "slab_thickness_m": (0.0, 0.0254, 0.0508)}, label="quick",
                   transport="confocal")

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


def noise_seed(base: int, *parts) -> int:
    """A sample's noise seed from what identifies it (not from its geometry: one scene asked
    for by two parts of the study is rendered once)."""
    return base * 1_000_003 + zlib.crc32("|".join(str(p) for p in parts).encode()) % 1_000_000


def glyph_sample(glyph: str, material: str, *, scan_width_m: float, height_m: float,
                 stroke_m: float, depth_m: float, exposure_s: float, seed: int,
                 slab_thickness_m: float | None = None, tilt_deg: float = 0.0,
                 inversion: str = "lambertian") -> dict:
    """The sample (:mod:`clnlos.study.samples.render`) of one glyph, centred on the scan, facing it
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
    """A sample's ``brdf`` (:mod:`clnlos.study.samples.render`) for one of INVERSIONS: none for the
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
