"""Simulated twins of the real capture families: the legibility judge's training data.

Two families of real captures with known content exist (the study's ``--real-data``): ``cdt``
(Lindell & Wetzstein 2020: letters filling a 0.6-0.7 m scan, 0.4-0.6 m behind a 2.54 cm
scattering slab) and ``lct`` (O'Toole et al. 2018: no slab, targets 0.4-1.2 m around a corner,
0.4-1.0 m scans, diffuse and retroreflective). Their twins (:data:`TWIN_GEOMETRIES`, five
geometries) hold the patterns of :mod:`clnlos.study.score.patterns` (capital letters of the
stroke font, bar groups and dot grids: what real targets are) in the real rigs' kinds of
material (TWIN_MATERIALS: two diffuse, a mixed and the retroreflective), each scaled and
moved at random within the scan (pattern height x U[TWIN_ZOOM], its side at most
TWIN_MAX_FILL of the scan width: real targets fill most of the scan; centre within
TWIN_SHIFT of the scan width and the pattern inside the scan), simulated once noise free
(the confocal light cone, the scene's slab) and then

    y ~ Poisson(N mu / sum(mu) + b N / (T P)),

N the signal photons (TWIN_PHOTONS_PER_POINT per scan point, P points, T bins) and b a
uniform background floor over the signal, drawn log-uniformly in TWIN_BACKGROUND (what the
real captures' late floor shows), then binomially thinned (nested,
:func:`clnlos.study.real.thinning.thinned_series`) to TWIN_FRACTIONS: a ladder from clear to
noise per scene, the real captures' thinning ladders' span of photons per scan point. Each
rung is also seen under a smooth lateral gain (:func:`gain_field`, up to TWIN_GAIN across
the scan; the label unchanged): real targets are unevenly bright. Each rung is split into
two binomial halves (:func:`clnlos.inverse.thinning.thin_counts`) and the rung and both
halves reconstructed with the judge's recipe (:data:`JUDGE_METHOD`, the SNR rule
JUDGE_SNR_RULE).

The label of a rung (simulations only): legible when the template rule identifies its
pattern among all the twins' patterns (:func:`clnlos.study.score.legibility.identify`, templates
blurred to O'Toole's lateral bound with the pulse and bin widths) *and* the IoU of its Otsu
mask with the true mask beats the filled box's
(:func:`clnlos.study.score.legibility.box_baseline_iou`): the study's label.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np

from clnlos.config import ReconstructionConfig
from clnlos.forward.model import ForwardModel
from clnlos.forward.scene import Scene
from clnlos.inverse.pipeline import reconstruct
from clnlos.inverse.thinning import thin_counts
from clnlos.physics.constants import C0
from clnlos.physics.slab import CDT_SLAB
from clnlos.runtime.device import get_queue
from clnlos.study.judge.features import capture_features, foreground, mip_of
from clnlos.study.score.legibility import (
    box_baseline_iou,
    glyph_coverage,
    glyph_templates,
    identify,
)
from clnlos.study.score.metrics import iou
from clnlos.study.score.patterns import (
    CHART_SCALE,
    TWIN_PATTERNS,
    is_chart,
    pattern_mask,
    pattern_objects,
)
from clnlos.study.samples.resolution import otoole_lateral_bound_m
from clnlos.study.real.thinning import thinned_series

JUDGE_METHOD = "lct"      # the judge reconstructs a capture (and its halves) this way: the
JUDGE_SNR_RULE = "gcv"    # closed-form inversion, 3 per capture in well under a second
JUDGE_MAX_BINS = 256      # a capture from elsewhere keeps at most this many time bins
JUDGE_MAX_POINTS = 32     # ... and this many scan points a side (k x k blocks summed)


@dataclass(frozen=True)
class TwinGeometry:
    """A twin geometry: family, scan width, target depth, letter height and stroke (m), slab
    thickness (m; 0: none)."""

    name: str
    family: str
    scan_width_m: float
    depth_m: float
    height_m: float
    stroke_m: float
    slab_thickness_m: float


TWIN_GEOMETRIES = (
    TwinGeometry("cdt_70", "cdt", 0.7, 0.5, 0.38, 0.1, CDT_SLAB.thickness_m),
    TwinGeometry("cdt_60", "cdt", 0.6, 0.6, 0.3, 0.08, CDT_SLAB.thickness_m),
    TwinGeometry("lct_40", "lct", 0.4, 0.4, 0.22, 0.05, 0.0),
    TwinGeometry("lct_70", "lct", 0.7, 0.6, 0.36, 0.09, 0.0),
    TwinGeometry("lct_100", "lct", 1.0, 1.2, 0.5, 0.13, 0.0),
)
# the real rigs' targets: two diffuse presets, a mixed one and the retroreflective material
# (clnlos.physics.retroreflector: the LCT release's charts and letters); no specular one
# (a mirror-like target's confocal image is its glint: not what the judge is for)
TWIN_MATERIALS = ("standard white plate", "cement board", "fuchsia lacquer board",
                  "retroreflective")
TWIN_FRACTIONS = (0.1, 1e-3, 1e-4, 1e-5)   # of the photons: 1e5 ... 10 per point (the real
#                                             ladders' span; why these four: the docs)
TWIN_PHOTONS_PER_POINT = 1e6   # signal photons per scan point at the top of the ladder
TWIN_BACKGROUND = (0.03, 3.0)  # the floor's photons over the signal's, log-uniform (what
#                                the LCT release shows: docs/validation/legibility-judge.md)
TWIN_ZOOM = (0.75, 1.75)       # pattern height: the geometry's letter height x U[a, b] ...
TWIN_MAX_FILL = 0.9            # ... up to this share of the scan width for the pattern's side)
TWIN_SHIFT = 0.1               # centre within +-this share of the scan width
TWIN_GAIN = 4.0                # each rung also seen under a lateral gain of up to this ratio
GAIN_KINDS = ("ramp",)        # ... smooth (a step, gain_field's "step", carves blobs into
#                                shapes: held out by material 0.61 balanced accuracy)
TWIN_PULSE_S = 35e-12


@dataclass(frozen=True)
class TwinGrid:
    """The twins' scan points and time bins (small: what the quick study can pay for)."""

    points: int = 24
    bin_width_s: float = 48e-12


def window_path_m(depth_m: float) -> float:
    """The reconstruction window (round-trip path, m): 2 (depth + 0.3 m)."""
    return 2.0 * (depth_m + 0.3)


def twin_scene(geo: TwinGeometry, glyph: str, material: str, height_m: float,
               offset_m, grid: TwinGrid, seed: int) -> dict:
    """The scene table of one twin (noise free: no detector)."""
    bins = int(math.ceil(1.3 * window_path_m(geo.depth_m) / (C0 * grid.bin_width_s)))
    d = {"seed": int(seed), "scan": {"width_m": geo.scan_width_m, "points": grid.points},
         "time": {"bin_width_s": grid.bin_width_s, "bins": bins, "start_s": 0.0},
         "objects": pattern_objects(glyph, height_m, geo.stroke_m * height_m / geo.height_m,
                                    (offset_m[0], offset_m[1], geo.depth_m), material),
         "laser": {"pulse_width_s": TWIN_PULSE_S},
         "sampling": {"density_per_m2": 4e4, "splat_order": 1}}
    if geo.slab_thickness_m > 0:
        d["slab"] = {"thickness_m": geo.slab_thickness_m, "mu_a": CDT_SLAB.mu_a,
                     "mu_s_prime": CDT_SLAB.mu_s_prime, "n": CDT_SLAB.n}
    return d


def judge_reconstructions(capture, config: ReconstructionConfig, device=None,
                          seed: int | None = None):
    """(full, half 1, half 2) volumes of a photon-count capture with ``config``: the capture
    and its two binomial halves (:func:`clnlos.inverse.thinning.thin_counts`)."""
    kw = {} if seed is None else {"seed": seed}
    h1, h2 = thin_counts(np.asarray(capture.transient), **kw)
    return tuple(reconstruct(replace(capture, transient=y), config, device=device).volume
                 for y in (capture.transient, h1, h2))


def twin_label(mip: np.ndarray, glyph: str, templates: dict, truth: np.ndarray) -> dict:
    """The study's label of a twin's MIP: identified and IoU above the box baseline."""
    best, margin, _ = identify(mip, templates)
    i = iou(foreground(mip), truth)
    base = box_baseline_iou(truth)
    return {"identified": bool(best == glyph), "iou": i, "iou_box_baseline": base,
            "legible": bool(best == glyph and i > base), "margin": margin}


def twin_plan(geometries=TWIN_GEOMETRIES, glyphs=TWIN_PATTERNS, materials=TWIN_MATERIALS,
              seed: int = 0, per_geometry: int | None = None) -> list[dict]:
    """Every twin scene: each geometry with each glyph (or ``per_geometry`` of them), the
    glyphs in turn over the whole plan (scene i: glyph i mod G) and the materials in turn
    shifted by one per round of the glyphs (material (i + i // G) mod M: every glyph meets
    every material, so that no split holds out one with the other), a random zoom, shift,
    floor and seed."""
    rng = np.random.default_rng(seed)
    plan = []
    n = len(glyphs) if per_geometry is None else per_geometry
    for g, geo in enumerate(geometries):
        for k in range(n):
            i = g * n + k
            glyph = glyphs[i % len(glyphs)]
            plan.append({
                "geometry": geo.name, "family": geo.family, "glyph": glyph,
                "material": materials[(i + i // len(glyphs)) % len(materials)],
                **twin_placement(geo, glyph, rng),
                "background": float(np.exp(rng.uniform(*np.log(TWIN_BACKGROUND)))),
                "seed": int(rng.integers(2**31))})
    return plan


def twin_placement(geo: TwinGeometry, pattern: str, rng: np.random.Generator) -> dict:
    """A random height (the geometry's x U[TWIN_ZOOM], the pattern's side at most
    TWIN_MAX_FILL of the scan) and centre offset (within TWIN_SHIFT of the scan width, the
    pattern inside the scan) of ``pattern`` in ``geo``."""
    side = CHART_SCALE if is_chart(pattern) else 1.0   # the pattern's side per height
    height = geo.height_m * float(rng.uniform(*TWIN_ZOOM))
    height = min(height, TWIN_MAX_FILL * geo.scan_width_m / side)
    room = max(0.0, min(TWIN_SHIFT * geo.scan_width_m, (geo.scan_width_m - side * height) / 2))
    return {"height_m": height, "offset_m": [float(v) for v in rng.uniform(-room, room, 2)]}


def render_twin(entry: dict, grid: TwinGrid = TwinGrid(), fractions=TWIN_FRACTIONS,
                device=None, keep_mips: bool = False) -> list[dict]:
    """The ladder of one twin (:func:`twin_plan` entry): per rung its fraction, photons,
    features (:func:`clnlos.study.judge.features.capture_features`) and label."""
    queue = get_queue(device)
    geo = next(g for g in TWIN_GEOMETRIES if g.name == entry["geometry"])
    scene = Scene.from_dict(twin_scene(geo, entry["glyph"], entry["material"],
                                       entry["height_m"], entry["offset_m"], grid,
                                       entry["seed"]))
    cap = ForwardModel(scene, queue=queue).capture()
    mu = np.asarray(cap.transient, np.float64)
    n_signal = TWIN_PHOTONS_PER_POINT * grid.points ** 2
    mu = mu * (n_signal / max(float(mu.sum()), 1e-300))
    mu += entry["background"] * n_signal / mu.size
    rng = np.random.default_rng(entry["seed"])
    top = rng.poisson(mu)
    cfg = ReconstructionConfig(max_path_m=window_path_m(geo.depth_m), slab=scene.slab,
                               method=JUDGE_METHOD, snr_rule=JUDGE_SNR_RULE).validate()
    centres = scene.scan_centres()
    height = entry["height_m"]
    stroke = geo.stroke_m * height / geo.height_m
    truth = glyph_coverage(entry["glyph"], height, stroke, entry["offset_m"], centres,
                           pattern_mask) >= 0.5
    fwhm = otoole_lateral_bound_m(geo.scan_width_m, geo.depth_m,
                                  math.hypot(TWIN_PULSE_S, grid.bin_width_s))
    templates = glyph_templates(height, stroke, entry["offset_m"], centres, fwhm,
                                TWIN_PATTERNS, pattern_mask)
    rows = []
    for f, counts in zip(fractions, thinned_series(top, fractions, entry["seed"] % 997),
                         strict=True):
        full, h1, h2 = judge_reconstructions(replace(cap, transient=counts), cfg, queue,
                                             seed=entry["seed"] % 991)
        mip = mip_of(full)
        row = {**{k: entry[k] for k in ("geometry", "family", "glyph", "material")},
               "fraction": float(f), "photons": float(counts.sum()),
               "features": capture_features(full, h1, h2),
               **twin_label(mip, entry["glyph"], templates, truth)}
        if keep_mips:
            row["mip"] = mip.astype(np.float32)
        rows.append(row)
        rng = np.random.default_rng(entry["seed"] + len(rows))
        for kind in GAIN_KINDS:
            gain = gain_field(full.shape[1:], rng, kind)
            rows.append({**{k: v for k, v in row.items() if k != "mip"}, "view": kind,
                         "features": capture_features(full * gain, h1 * gain, h2 * gain)})
    return rows


def gain_field(shape, rng: np.random.Generator, kind: str = "ramp") -> np.ndarray:
    """A lateral gain [y, x] up to TWIN_GAIN (what a real target's uneven brightness does to
    its MIP: a retroreflective part beside a diffuse one, parts at other depths): along a
    random direction s = a u + b v (u, v in [-1/2, 1/2] across the scan, |(a, b)| = 1), a
    ``"ramp"`` exp(k s) or a ``"step"`` of ratio r beyond a random cut."""
    a, b = rng.normal(size=2)
    n = max(float(np.hypot(a, b)), 1e-12)
    v = (np.arange(shape[0]) + 0.5) / shape[0] - 0.5
    u = (np.arange(shape[1]) + 0.5) / shape[1] - 0.5
    t = (a * u[None, :] + b * v[:, None]) / n
    ratio = float(np.exp(np.log(TWIN_GAIN) * rng.uniform(0.3, 1.0)))
    if kind == "ramp":
        return np.exp(np.log(ratio) * t)
    return np.where(t > rng.uniform(-0.25, 0.25), ratio, 1.0)


def render_twins(plan: list[dict], grid: TwinGrid = TwinGrid(), fractions=TWIN_FRACTIONS,
                 device=None, progress=None) -> list[dict]:
    """Every rung of every twin in ``plan``; ``progress(done, total)`` after each twin."""
    rows = []
    for k, entry in enumerate(plan):
        rows += render_twin(entry, grid, fractions, device)
        if progress is not None:
            progress(k + 1, len(plan))
    return rows


def twin_settings(grid: TwinGrid = TwinGrid(), fractions=TWIN_FRACTIONS) -> dict:
    """What the twins were made with (recorded beside the judge)."""
    return {"grid": asdict(grid), "fractions": list(fractions),
            "geometries": [asdict(g) for g in TWIN_GEOMETRIES],
            "materials": list(TWIN_MATERIALS), "patterns": list(TWIN_PATTERNS),
            "photons_per_point": TWIN_PHOTONS_PER_POINT, "background": list(TWIN_BACKGROUND),
            "zoom": list(TWIN_ZOOM), "max_fill": TWIN_MAX_FILL, "shift": TWIN_SHIFT,
            "gain": TWIN_GAIN, "method": JUDGE_METHOD, "snr_rule": JUDGE_SNR_RULE,
            "max_bins": JUDGE_MAX_BINS, "max_points": JUDGE_MAX_POINTS}
