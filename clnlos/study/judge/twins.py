"""Simulated twins of real NLOS captures: the legibility judge's training data.

Two rigs of real captures exist (:data:`RIGS`): behind a scattering slab (``slab``: Lindell &
Wetzstein 2020's confocal diffuse tomography, 0.5-0.8 m scans, targets 0.35-0.75 m behind
a 2.54 cm slab) and around a corner (``none``: O'Toole et al. 2018 and the f-k release, no
slab, 0.3-1.2 m scans, targets 0.3-1.6 m from the wall). A twin is one hidden target of a
kind (:data:`clnlos.study.judge.targets.TARGET_KINDS`: capitals and charts --
:mod:`clnlos.study.score.patterns` -- signs, figures, objects, extended 3-D shapes, several
at several depths; tilted or not) in one of the real rigs' kinds of material
(:data:`TWIN_MATERIALS`: two diffuse, a mixed and the retroreflective), on a scan of
TWIN_POINTS points a side with bins of TWIN_BIN_WIDTHS_S and a laser pulse in TWIN_PULSE_S.
It is simulated once noise free (the confocal light cone, the rig's slab) and then

    y ~ Poisson(N mu / sum(mu) + b N / (T P)),

N the signal photons (n per scan point, P points, T bins; the study's twins: n =
TWIN_PHOTONS_PER_POINT; the broad plan's: log-uniform in its rig's RIG_PHOTONS) and b a
uniform background floor over the signal, drawn log-uniformly in TWIN_BACKGROUND (what the
real captures' late floor shows), then binomially thinned (nested,
:func:`clnlos.study.real.thinning.thinned_series`) to the entry's ``fractions``
(TWIN_FRACTIONS, the broad plan's BROAD_FRACTIONS): a ladder from clear to noise per twin,
the real captures' thinning ladders' span of photons per scan point. Each rung is also seen
under a smooth lateral gain
(:func:`gain_field`, up to TWIN_GAIN across the scan; the label unchanged): real targets are
unevenly bright. Each rung and its two binomial halves are reconstructed with the judge's
recipe (:mod:`clnlos.study.judge.recipe`), as a real capture is.

The label of a rung (simulations only, ground truth). By the target (the study's twins,
:func:`twin_plan`):

* capitals and charts (``glyph``, ``chart``): the template rule identifies the pattern among
  all the twins' patterns (:func:`clnlos.study.score.legibility.identify`, templates blurred
  to O'Toole's lateral bound with the pulse and bin widths) *and* the IoU of the MIP's Otsu
  mask with the true mask beats the filled box's
  (:func:`clnlos.study.score.legibility.box_baseline_iou`): the study's label;
* every other kind: no template set names a figure, a sign or a statue, so the target is
  matched against the one other candidate a featureless image could be, its filled box:
  the ideal image of the target g = G_sigma * c (c the true front view's coverage of each
  scan cell, :func:`true_footprint`; sigma from O'Toole's lateral bound as for the
  templates) and that of its filled bounding box b = G_sigma * B. The image *shows the
  target* when its MIP m matches the target better than the box, r(m, g) > r(m, b), and
  at least FIDELITY_NCC, r(m, g) >= FIDELITY_NCC (r the normalised cross-correlation, best
  over shifts of up to one cell: :func:`clnlos.study.score.legibility.match_scores`). The
  floor is where the glyph twins' own label is best told by their match with their true
  template (``glyph_rule_agreement`` of tools/train_judge.py: the fidelity rule against the
  template rule on the glyph and chart twins).

By the reference (the shipped judge's twins, :func:`broad_plan`, entry ``"label":
"reference"``), as a real capture's rungs are labelled (:mod:`clnlos.study.judge.real`): the
top of the ladder (its photons those of the real captures: RIG_PHOTONS) is the reference,
as a real capture's full-photon reconstruction is. Where it does not show the target by
the rule above (a target the rig does not resolve at that exposure: too small, too far,
behind too much slab, too faint), the twin's rungs are *undecided* (``legible`` None,
``shows`` False): the judge is for targets the rig shows, as the published
reconstructions of real captures show theirs. Where it does, a rung is legible when its MIP
agrees with the reference by Pearson r >= REFERENCE_AGREEMENT (:data:`clnlos.study.judge.
real.REFERENCE_AGREEMENT`, the real rungs' bar): the photons still make the image the rig
makes. The label by the target alone is kept beside it (``legible_truth``). Each rung is
also reconstructed as ``clnlos reconstruct`` does by default (:func:`default_view`: a view
for the volume model only, labelled by its agreement with the top rung's default image).

Behind the slab the same image takes about ten times the photons it takes in a real CDT
capture (a twin of letter_s, an S of 0.4 m at 0.5 m on a 0.6 m scan of 32 points: the
halves' agreement 0.64 at 2e4 signal photons per point, where the real capture's 2e4
counts per point give 0.98): the slab rig's ladder starts about ten times above the real
CDT captures' 2e4-1.5e5 counts per point (RIG_PHOTONS), so that it, too, runs from clear
to noise. Around a corner it starts where the LCT release's captures are, 3e3-1.2e4 hidden
photons per point of the 32-point grid the judge sums them to, and goes down to a tenth of
a photon per point, below where their images are gone (the twins' images stay close to
their ideal down to 3-30 photons per point: a ladder that stops there holds no noise).
"""

from __future__ import annotations

import math
import tempfile
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter

from clnlos.forward.model import ForwardModel
from clnlos.forward.sampling import sample_object
from clnlos.forward.scene import Scene
from clnlos.physics.constants import C0
from clnlos.physics.slab import CDT_SLAB
from clnlos.runtime.device import get_queue
from clnlos.inverse.pipeline import reconstruct
from clnlos.inverse.preprocessing import setup_slab
from clnlos.study.judge.features import (
    capture_features,
    foreground,
    mip_features,
    mip_of,
    pearson_r,
    pooled,
)
from clnlos.study.judge.recipe import (
    JUDGE_SNR_RULE,
    capture_descriptors,
    judge_config,
    judge_reconstructions,
    recipe_settings,
)
from clnlos.study.judge.real import REFERENCE_AGREEMENT, default_config
from clnlos.study.judge.targets import TARGET_KINDS, draw_target
from clnlos.study.real.thinning import thinned_series
from clnlos.study.samples.resolution import otoole_lateral_bound_m
from clnlos.study.score.legibility import (
    FWHM_PER_SIGMA,
    box_baseline_iou,
    glyph_coverage,
    glyph_templates,
    identify,
    match_scores,
)
from clnlos.study.score.metrics import iou
from clnlos.study.score.patterns import (
    CHART_SCALE,
    TWIN_CHARTS,
    TWIN_LETTERS,
    TWIN_PATTERNS,
    is_chart,
    pattern_mask,
    pattern_objects,
)

@dataclass(frozen=True)
class TwinGeometry:
    """A fixed twin geometry of the study's plan (:func:`twin_plan`): family, scan width,
    target depth, letter height and stroke (m), slab thickness (m; 0: none)."""

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


@dataclass(frozen=True)
class Rig:
    """A rig of the broad plan: its family, the ranges its scans (width, m) and targets
    (depth, m) are drawn from, its slab, and the scan-width bands that group its twins in
    the held-out split by rig."""

    name: str
    family: str
    scan_width_m: tuple[float, float]
    depth_m: tuple[float, float]
    slab: bool
    bands_m: tuple[float, ...]


RIGS = (Rig("slab", "cdt", (0.5, 0.8), (0.35, 0.75), True, (0.65,)),
        Rig("none", "lct", (0.3, 2.0), (0.3, 2.0), False, (0.55, 1.0)))
# the broad plan's photons per scan point at the top of its ladder (log-uniform) per rig
RIG_PHOTONS = {"slab": (1e5, 3e6), "none": (1e3, 3e4)}
BROAD_FRACTIONS = (1.0, 1e-2, 1e-3, 1e-4)   # ... and its ladder
SLAB_SHARE = 0.4                  # of the broad plan's twins behind the slab
# the real rigs' targets: two diffuse presets, a mixed one and the retroreflective material
# (clnlos.physics.retroreflector: the LCT release's charts and letters); no specular one
# (a mirror-like target's confocal image is its glint: not what the judge is for)
TWIN_MATERIALS = ("standard white plate", "cement board", "fuchsia lacquer board",
                  "retroreflective")
TWIN_FRACTIONS = (0.1, 1e-3, 1e-4, 1e-5)   # of the photons: 1e5 ... 10 per point (the real
#                                             ladders' span; why these four: the docs)
TWIN_PHOTONS_PER_POINT = 1e6   # the study's twins: signal photons per scan point
TWIN_BACKGROUND = (0.03, 3.0)  # the floor's photons over the signal's, log-uniform (what
#                                the LCT release shows: docs/validation/legibility-judge.md)
TWIN_ZOOM = (0.75, 1.75)       # pattern height: the geometry's letter height x U[a, b] ...
TWIN_MAX_FILL = 0.9            # ... up to this share of the scan width for the pattern's side)
TWIN_SIDE = (0.6, 0.95)        # another target's side: this share of the scan width
TWIN_DEPTH_RATIO = (0.6, 1.3)  # a target's depth over the scan width (within the rig's)
TWIN_SHIFT = 0.1               # centre within +-this share of the scan width
TWIN_LETTER_HEIGHT = 0.52      # a capital's height in the broad plan: this x the scan width
TWIN_STROKE = 0.26             # ... its stroke over its height
TWIN_GAIN = 4.0                # each rung also seen under a lateral gain of up to this ratio
GAIN_KINDS = ("ramp",)        # ... smooth (a step, gain_field's "step", carves blobs into
#                                shapes: held out by material 0.61 balanced accuracy)
TWIN_PULSE_S = 35e-12          # the study plan's pulse; the broad plan's: U(TWIN_PULSES_S)
TWIN_PULSES_S = (30e-12, 90e-12)
TWIN_POINTS = (24, 32)
TWIN_BIN_WIDTHS_S = (16e-12, 32e-12, 48e-12, 64e-12)
TWIN_WINDOW_MARGIN_M = 0.3     # the window ends 2 (deepest point + this) of path ...
TWIN_WINDOW_SPARE = 1.3        # ... times this
CELL_SAMPLES = 4               # surface elements per scan cell side (at least) in a twin
FOOTPRINT_SAMPLES = 8          # ... and where its true front view is measured
FOOTPRINT_COVER = 0.5          # a cell is on the front view when covered this much
FIDELITY_NCC = 0.75            # a legible rung's match with its ideal image, at least


@dataclass(frozen=True)
class TwinGrid:
    """The study plan's scan points and time bins (small: what the quick study can pay for)."""

    points: int = 24
    bin_width_s: float = 48e-12


def window_path_m(depth_m: float, scan_width_m: float = 0.0) -> float:
    """The round-trip path (m) a twin's window must reach: from a corner of the scan to a
    point TWIN_WINDOW_MARGIN_M behind ``depth_m``, 2 sqrt((depth + margin)^2 + w^2 / 2), w
    the scan width."""
    return 2.0 * math.hypot(depth_m + TWIN_WINDOW_MARGIN_M, scan_width_m / math.sqrt(2))


# ------------------------------------------------------------------ plans
def twin_plan(geometries=TWIN_GEOMETRIES, glyphs=TWIN_PATTERNS, materials=TWIN_MATERIALS,
              seed: int = 0, per_geometry: int | None = None,
              grid: TwinGrid = TwinGrid()) -> list[dict]:
    """The study's twins: each geometry with each glyph (or ``per_geometry`` of them), the
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
                "kind": "chart" if is_chart(glyph) else "glyph", "geometry": geo.name,
                "rig": "slab" if geo.slab_thickness_m > 0 else "none", "rig_group": geo.name,
                "family": geo.family, "glyph": glyph,
                "material": materials[(i + i // len(glyphs)) % len(materials)],
                "scan_width_m": geo.scan_width_m, "depth_m": geo.depth_m,
                "points": grid.points, "bin_width_s": grid.bin_width_s,
                "pulse_s": TWIN_PULSE_S, "photons_per_point": TWIN_PHOTONS_PER_POINT,
                **twin_placement(geo, glyph, rng),
                "background": float(np.exp(rng.uniform(*np.log(TWIN_BACKGROUND)))),
                "seed": int(rng.integers(2**31))})
            plan[-1]["stroke_m"] = geo.stroke_m * plan[-1]["height_m"] / geo.height_m
    return plan


def twin_placement(geo: TwinGeometry, pattern: str, rng: np.random.Generator) -> dict:
    """A random height (the geometry's x U[TWIN_ZOOM], the pattern's side at most
    TWIN_MAX_FILL of the scan) and centre offset (within TWIN_SHIFT of the scan width, the
    pattern inside the scan) of ``pattern`` in ``geo``."""
    side = CHART_SCALE if is_chart(pattern) else 1.0   # the pattern's side per height
    height = geo.height_m * float(rng.uniform(*TWIN_ZOOM))
    height = min(height, TWIN_MAX_FILL * geo.scan_width_m / side)
    return {"height_m": height, "offset_m": centre_offset(geo.scan_width_m, side * height, rng)}


def centre_offset(scan_width_m: float, side_m: float, rng: np.random.Generator) -> list[float]:
    """A target's centre (x, y; m) within TWIN_SHIFT of the scan width, the target (of side
    ``side_m``) inside the scan."""
    room = max(0.0, min(TWIN_SHIFT * scan_width_m, (scan_width_m - side_m) / 2))
    return [float(v) for v in rng.uniform(-room, room, 2)]


def rig_group(rig: Rig, scan_width_m: float) -> str:
    """The rig's name and the band of its scan width (the held-out split by rig)."""
    band = int(np.searchsorted(rig.bands_m, scan_width_m))
    return f"{rig.name}-{band}"


def broad_plan(per_kind: int, seed: int = 0, kinds=TARGET_KINDS,
               materials=TWIN_MATERIALS) -> list[dict]:
    """The shipped judge's twins: ``per_kind`` of each kind, the kinds in turn (scene i: kind
    i mod K), the materials in turn shifted by one per round of the kinds (every kind meets
    every material: material (i mod K + i // K) mod M), a share SLAB_SHARE behind the slab
    (scenes with i // K mod 5 in {0, 2}), and at random: the scan (width in the rig's range,
    TWIN_POINTS, TWIN_BIN_WIDTHS_S), the depth (TWIN_DEPTH_RATIO of the width, within the
    rig's range), the pulse, the photons, the floor, the target's size and place and its
    seed."""
    rng = np.random.default_rng(seed)
    plan = []
    nk = len(kinds)
    for i in range(per_kind * nk):
        kind = kinds[i % nk]
        rig = RIGS[0] if (i // nk) % 5 in (0, 2) else RIGS[1]
        width = float(np.exp(rng.uniform(*np.log(rig.scan_width_m))))
        depth = float(np.clip(width * rng.uniform(*TWIN_DEPTH_RATIO), *rig.depth_m))
        e = {"kind": kind, "rig": rig.name, "rig_group": rig_group(rig, width),
             "family": rig.family,
             "material": materials[(i % nk + i // nk) % len(materials)],
             "scan_width_m": width, "depth_m": depth,
             "points": int(rng.choice(TWIN_POINTS)),
             "bin_width_s": float(rng.choice(TWIN_BIN_WIDTHS_S)),
             "pulse_s": float(rng.uniform(*TWIN_PULSES_S)),
             "photons_per_point": float(np.exp(rng.uniform(*np.log(RIG_PHOTONS[rig.name])))),
             "fractions": list(BROAD_FRACTIONS),
             "background": float(np.exp(rng.uniform(*np.log(TWIN_BACKGROUND))))}
        if kind in ("glyph", "chart"):
            names = TWIN_LETTERS if kind == "glyph" else TWIN_CHARTS
            glyph = names[(i // nk) % len(names)]
            per = CHART_SCALE if kind == "chart" else 1.0
            h = min(TWIN_LETTER_HEIGHT * width * float(rng.uniform(*TWIN_ZOOM)),
                    TWIN_MAX_FILL * width / per)
            e.update(glyph=glyph, height_m=h, stroke_m=TWIN_STROKE * h,
                     offset_m=centre_offset(width, per * h, rng))
        else:
            side = width * float(rng.uniform(*TWIN_SIDE))
            e.update(glyph=kind, side_m=side, offset_m=centre_offset(width, side, rng))
        e["seed"] = int(rng.integers(2**31))
        e["label"] = "reference"
        plan.append(e)
    return plan


# ------------------------------------------------------------------ scenes
def scene_objects(entry: dict) -> tuple[list[dict], list[bool], dict, str]:
    """(the [[objects]] tables at the entry's place and depth, which are its content, the
    files they name, the target's name) of a plan entry."""
    x, y = entry["offset_m"]
    z = entry["depth_m"]
    if entry["kind"] in ("glyph", "chart"):
        objs = pattern_objects(entry["glyph"], entry["height_m"], entry["stroke_m"],
                               (x, y, z), entry["material"])
        return objs, [True] * len(objs), {}, entry["glyph"]
    t = draw_target(entry["kind"], np.random.default_rng(entry["seed"]), entry["side_m"],
                    entry["material"])
    objs = []
    for o in t.objects:
        tx, ty, tz = o.get("translate_m", [0.0, 0.0, 0.0])
        objs.append({**o, "translate_m": [tx + x, ty + y, tz + z]})
    return objs, list(t.content), t.files, t.name


def write_files(files: dict, folder: Path) -> None:
    """The target's files in ``folder``: arrays as .npy, text (meshes) as it is."""
    for name, value in files.items():
        if isinstance(value, str):
            (folder / name).write_text(value)
        else:
            np.save(folder / name, np.asarray(value), allow_pickle=False)


def deepest_m(scene: Scene) -> float:
    """The largest depth (m) of any of the scene's objects: their surface elements' (coarsely
    sampled) and their origins'."""
    return max(max(float(o.translate_m[2]),
                   float(sample_object(o, 1e4, scene.base_dir).pos[:, 2].max(initial=0.0)))
               for o in scene.objects)


def twin_scene(entry: dict, folder: Path) -> tuple[Scene, list[bool], str]:
    """(the noise-free scene of a plan entry, its objects' content flags, the target's
    name), its files written to ``folder``; the window reaches TWIN_WINDOW_SPARE times
    :func:`window_path_m` of its deepest point, in bins of the entry's width."""
    objs, content, files, name = scene_objects(entry)
    write_files(files, folder)
    pitch = entry["scan_width_m"] / entry["points"]
    d = {"seed": int(entry["seed"]),
         "scan": {"width_m": entry["scan_width_m"], "points": int(entry["points"])},
         "time": {"bin_width_s": entry["bin_width_s"], "bins": 1, "start_s": 0.0},
         "objects": objs, "laser": {"pulse_width_s": entry["pulse_s"]},
         "sampling": {"density_per_m2": max(4e4, (CELL_SAMPLES / pitch) ** 2),
                      "splat_order": 1}}
    if entry["rig"] == "slab":
        d["slab"] = {"thickness_m": CDT_SLAB.thickness_m, "mu_a": CDT_SLAB.mu_a,
                     "mu_s_prime": CDT_SLAB.mu_s_prime, "n": CDT_SLAB.n}
    scene = Scene.from_dict(d, base_dir=folder)
    path = TWIN_WINDOW_SPARE * window_path_m(deepest_m(scene), entry["scan_width_m"])
    d["time"]["bins"] = int(math.ceil(path / (C0 * entry["bin_width_s"])))
    return Scene.from_dict(d, base_dir=folder), content, name


def true_footprint(scene: Scene, content) -> np.ndarray:
    """The target's true front view on the scan grid [y, x]: the share c of each cell's
    area that its content objects' front-facing surface covers,

        c(cell) = min(1, sum_e A_e max(0, -n_e . z) / p^2),

    over the surface elements e in the cell (sampled FOOTPRINT_SAMPLES per cell side), A_e
    their areas, n_e their normals and p the scan pitch (the projected area, facing the
    wall); the true mask is c >= FOOTPRINT_COVER."""
    p = scene.pitch_m
    n = scene.points
    cover = np.zeros((n, n))
    for obj, c in zip(scene.objects, content, strict=True):
        if not c:
            continue
        el = sample_object(obj, (FOOTPRINT_SAMPLES / p) ** 2, scene.base_dir)
        w = el.area * np.clip(-el.normal[:, 2], 0.0, None)
        ix = np.floor((el.pos[:, 0] + scene.width_m / 2) / p).astype(int)
        iy = np.floor((el.pos[:, 1] + scene.width_m / 2) / p).astype(int)
        ok = (ix >= 0) & (ix < n) & (iy >= 0) & (iy < n) & (w > 0)
        np.add.at(cover, (iy[ok], ix[ok]), w[ok])
    return np.minimum(cover / (p * p), 1.0)


def twin_label(mip: np.ndarray, glyph: str, templates: dict, truth: np.ndarray) -> dict:
    """The study's label of a glyph twin's MIP: identified and IoU above the box baseline."""
    best, margin, _ = identify(mip, templates)
    i = iou(foreground(mip), truth)
    base = box_baseline_iou(truth)
    return {"identified": bool(best == glyph), "iou": i, "iou_box_baseline": base,
            "legible": bool(best == glyph and i > base), "margin": margin}


def box_image(truth: np.ndarray) -> np.ndarray:
    """The filled bounding box [y, x] of a true mask (all zero for an empty one)."""
    box = np.zeros(truth.shape)
    if truth.any():
        ys, xs = np.nonzero(truth)
        box[ys.min():ys.max() + 1, xs.min():xs.max() + 1] = 1.0
    return box


def fidelity(mip: np.ndarray, ideal: np.ndarray, box_ideal: np.ndarray) -> dict:
    """``match``: r(m, g) of the MIP with the target's ideal image, ``match_box``: r(m, b)
    with its filled box's, and ``faithful``: r(m, g) >= FIDELITY_NCC and r(m, g) > r(m, b)
    (module docstring; for a glyph twin, beside the study's label)."""
    r = match_scores(mip, {"target": ideal, "box": box_ideal})
    return {"match": r["target"], "match_box": r["box"],
            "faithful": bool(r["target"] >= FIDELITY_NCC and r["target"] > r["box"])}


def shape_label(mip: np.ndarray, cover: np.ndarray, sigma_cells: float) -> dict:
    """The label of any other twin's MIP (module docstring): :func:`fidelity` with the
    target's ideal image and its filled box's; the IoU of its Otsu mask with the true mask
    (``cover`` >= FOOTPRINT_COVER) and the box's beside it."""
    truth = cover >= FOOTPRINT_COVER
    f = fidelity(mip, gaussian_filter(cover, sigma_cells, mode="constant"),
                 gaussian_filter(box_image(truth), sigma_cells, mode="constant"))
    return {"identified": None, "iou": iou(foreground(mip), truth),
            "iou_box_baseline": box_baseline_iou(truth), **f, "legible": f["faithful"],
            "margin": f["match"] - f["match_box"]}


def lateral_sigma_cells(entry: dict, pitch_m: float) -> float:
    """The Gaussian sigma (cells) of O'Toole's lateral bound for the entry's scan, depth,
    pulse and bin width: what a perfect reconstruction's blur is."""
    fwhm = otoole_lateral_bound_m(entry["scan_width_m"], entry["depth_m"],
                                  math.hypot(entry["pulse_s"], entry["bin_width_s"]))
    return fwhm / FWHM_PER_SIGMA / pitch_m


def glyph_truth(entry: dict, scene: Scene) -> tuple[np.ndarray, dict]:
    """(the true mask, the templates of every pattern) of a glyph or chart twin."""
    centres = scene.scan_centres()
    h, s = entry["height_m"], entry["stroke_m"]
    truth = glyph_coverage(entry["glyph"], h, s, entry["offset_m"], centres,
                           pattern_mask) >= FOOTPRINT_COVER
    fwhm = otoole_lateral_bound_m(entry["scan_width_m"], entry["depth_m"],
                                  math.hypot(entry["pulse_s"], entry["bin_width_s"]))
    return truth, glyph_templates(h, s, entry["offset_m"], centres, fwhm, TWIN_PATTERNS,
                                  pattern_mask)


# ------------------------------------------------------------------ rendering
ENTRY_KEYS = ("kind", "rig", "rig_group", "family", "glyph", "material", "geometry")


def top_counts(expected, entry: dict) -> np.ndarray:
    """The top rung's counts: Poisson of the noise-free ``expected`` scaled to the entry's
    signal photons per scan point, over its uniform floor (module docstring)."""
    mu = np.asarray(expected, np.float64)
    n_signal = entry["photons_per_point"] * mu.shape[1] * mu.shape[2]
    mu = mu * (n_signal / max(float(mu.sum()), 1e-300))
    mu += entry["background"] * n_signal / mu.size
    return np.random.default_rng(entry["seed"]).poisson(mu)


def labeller(entry: dict, scene: Scene, content):
    """The label by the target of the entry's MIPs (a function of a MIP): the study's for a
    glyph or chart with its fidelity beside it (:func:`twin_label`, :func:`fidelity`), the
    fidelity rule for any other target (:func:`shape_label`)."""
    sigma = lateral_sigma_cells(entry, scene.pitch_m)
    if entry["kind"] not in ("glyph", "chart"):
        cover = true_footprint(scene, content)
        return lambda mip: shape_label(mip, cover, sigma)
    truth, templates = glyph_truth(entry, scene)
    box = gaussian_filter(box_image(truth), sigma, mode="constant")
    return lambda mip: {**twin_label(mip, entry["glyph"], templates, truth),
                        **fidelity(mip, templates[entry["glyph"]], box)}


def render_twin(entry: dict, grid: TwinGrid | None = None, fractions=None,
                device=None, keep_mips: bool = False) -> list[dict]:
    """The ladder of one twin (a :func:`twin_plan` or :func:`broad_plan` entry; ``grid``,
    where given, replaces the entry's points and bin width; ``fractions`` its rungs,
    default the entry's, else TWIN_FRACTIONS): per rung its fraction, photons
    (and per scan point), features (:func:`clnlos.study.judge.features.capture_features`)
    and label, and the rung under a lateral gain (``"view"``); with ``keep_mips`` the MIPs
    of the rung and its halves (``mip``, ``mip_halves``)."""
    queue = get_queue(device)
    if grid is not None:
        entry = {**entry, "points": grid.points, "bin_width_s": grid.bin_width_s}
    fractions = fractions or entry.get("fractions") or TWIN_FRACTIONS
    with tempfile.TemporaryDirectory(prefix="clnlos-twin-") as folder:
        scene, content, name = twin_scene(entry, Path(folder))
        cap = ForwardModel(scene, queue=queue).capture()
        by_truth = labeller(entry, scene, content)
    top = top_counts(cap.transient, entry)
    cfg = judge_config(cap)
    by_reference = entry.get("label") == "reference"
    rows, reference = [], {}
    for f, counts in zip(fractions, thinned_series(top, fractions, entry["seed"] % 997),
                         strict=True):
        full, h1, h2 = judge_reconstructions(replace(cap, transient=counts), cfg, queue,
                                             seed=entry["seed"] % 991)
        mip = mip_of(full)
        label = by_truth(mip)
        if by_reference:  # the top rung: the reference, and whether it shows the target
            reference.setdefault("mip", mip)
            reference.setdefault("shows", bool(label["legible"]))
            agree = pearson_r(mip, reference["mip"])
            label = {**label, "legible_truth": label["legible"], "shows": reference["shows"],
                     "agreement": agree, "legible": bool(agree >= REFERENCE_AGREEMENT)
                     if reference["shows"] else None}
        row = {**{k: entry[k] for k in ENTRY_KEYS if k in entry}, "target": name,
               "fraction": float(f), "photons": float(counts.sum()),
               **capture_descriptors(replace(cap, transient=counts), cfg),
               "features": capture_features(full, h1, h2), **label}
        if keep_mips:
            row["mip"] = mip.astype(np.float32)
            row["mip_halves"] = np.stack([mip_of(h1), mip_of(h2)]).astype(np.float32)
        rows.append(row)
        if by_reference:
            rows.append(default_view(row, replace(cap, transient=counts), reference, queue,
                                     keep_mips))
        rng = np.random.default_rng(entry["seed"] + len(rows))
        for kind in GAIN_KINDS:
            gain = gain_field(full.shape[1:], rng, kind)
            view = {**row, "view": kind,
                    "features": capture_features(full * gain, h1 * gain, h2 * gain)}
            if keep_mips:
                view["mip"] = mip_of(full * gain).astype(np.float32)
                view["mip_halves"] = np.stack([mip_of(h1 * gain),
                                               mip_of(h2 * gain)]).astype(np.float32)
            rows.append(view)
    return rows


def default_view(row: dict, capture, reference: dict, queue, keep_mips: bool) -> dict:
    """The rung as ``clnlos reconstruct`` shows a real capture by default (LCT, its own bins
    and grid, the slab, SNRs by generalised cross-validation: what a real capture, which
    records no slab, gets; :func:`clnlos.study.judge.real.default_config`), for the volume
    model alone (``volume_only``): its MIP's features and its own label, its agreement with
    the top rung's default reconstruction (``reference["default"]``)."""
    cfg = setup_slab(default_config(None).replace(snr_rule=JUDGE_SNR_RULE), capture)[0]
    mip = pooled(mip_of(reconstruct(capture, cfg, device=queue).volume))
    reference.setdefault("default", mip)
    agree = pearson_r(mip, reference["default"])
    view = {k: v for k, v in row.items() if k not in ("mip", "mip_halves")}
    view.update(view="default", volume_only=True, features=mip_features(mip),
                agreement=agree, legible=bool(agree >= REFERENCE_AGREEMENT)
                if reference["shows"] else None)
    if keep_mips:
        view["mip"] = mip.astype(np.float32)
        view["mip_halves"] = np.stack([mip, mip]).astype(np.float32)
    return view


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


def render_twins(plan: list[dict], grid: TwinGrid | None = None, fractions=None,
                 device=None, progress=None) -> list[dict]:
    """Every rung of every twin in ``plan``; ``progress(done, total)`` after each twin."""
    rows = []
    for k, entry in enumerate(plan):
        rows += render_twin(entry, grid, fractions, device)
        if progress is not None:
            progress(k + 1, len(plan))
    return rows


def twin_settings(grid: TwinGrid | None = None, fractions=TWIN_FRACTIONS) -> dict:
    """What the twins were made with (recorded beside the judge)."""
    return {"grid": None if grid is None else asdict(grid), "fractions": list(fractions),
            "geometries": [asdict(g) for g in TWIN_GEOMETRIES],
            "rigs": [asdict(r) for r in RIGS], "slab_share": SLAB_SHARE,
            "kinds": list(TARGET_KINDS), "materials": list(TWIN_MATERIALS),
            "patterns": list(TWIN_PATTERNS), "points": list(TWIN_POINTS),
            "bin_widths_s": list(TWIN_BIN_WIDTHS_S), "pulses_s": list(TWIN_PULSES_S),
            "photons_per_point": TWIN_PHOTONS_PER_POINT, "fidelity_ncc": FIDELITY_NCC,
            "rig_photons": {k: list(v) for k, v in RIG_PHOTONS.items()},
            "broad_fractions": list(BROAD_FRACTIONS),
            "depth_ratio": list(TWIN_DEPTH_RATIO),
            "background": list(TWIN_BACKGROUND), "zoom": list(TWIN_ZOOM),
            "side": list(TWIN_SIDE), "max_fill": TWIN_MAX_FILL, "shift": TWIN_SHIFT,
            "gain": TWIN_GAIN, **recipe_settings()}
