"""The study's check on real captures (results.json ``real_check``): for each ``[[real]]``
capture of the rig, the photons it needs to keep its image, measured on the capture and
predicted on its simulated twin by the same criterion, and their ratio.

Keeps its image (:mod:`clnlos.study.real.materials`): the NCC of a reconstruction's front-view
detail with the full-photon reconstruction's is at least KEEP_LEVEL (0.8). The variant is the
entry's method with the reflectance its material asks for (retroreflective: the (t/T)^2
falloff; else Lambertian).

Photons needed, finely enough to be checked: SEEDS series of nested thinnings, each refined at
its crossing until bracketed within 1.5x (:mod:`clnlos.study.real.ladder`); the median over
the series, its interval holding every bracket and the seeds' spread; a series that keeps the
image down to its last rung bounds the need from above ("at most"), and those bounds stay
bounds in every ratio.

The twin. ``target = "from-capture"``: the Otsu mask of the full-photon reconstruction's
front view, each pixel at the depth of its brightest voxel and with the front view's value as
its albedo (a mask object with a depth map and an albedo map,
:func:`clnlos.forward.geometry.sample_mask`); or the study's description of the target at its
depth. It is simulated in the entry's material with the capture's scan and time axis and its
slab, the system's pulse measured on the direct reflection (else the rig's), and reconstructed
on the capture's own time grid. Its expected counts (:func:`matched_expectation`): the
capture's background floor, the twin scaled by least squares to the counts above the floor,
and the counts the twin does not explain (a room's interreflections, a target's backing, what
the mask misses) smoothed to the system's temporal and lateral resolution; Poisson counts of
that are thinned like the capture.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter

from clnlos.config import ReconstructionConfig
from clnlos.forward.model import ForwardModel
from clnlos.forward.scene import Scene
from clnlos.inverse.pipeline import reconstruct
from clnlos.inverse.snr import estimate_noise, first_recorded_bin
from clnlos.io.capture import Capture, without_direct
from clnlos.io.files import read_capture
from clnlos.study.file.spec import RealEntry, Study
from clnlos.study.plan.entries import MaterialKeys, target_sample
from clnlos.study.plan.scenes import scene_objects
from clnlos.study.real.ladder import bounded_ratio, series_crossing, series_summary
from clnlos.study.real.materials import (
    KEEP_LEVEL,
    TWIN_DENSITY_PER_M2,
    binned_scan,
    counts_front,
    direct_reflection_fwhm,
    front_view,
    image_score,
)
from clnlos.study.samples.resolution import otoole_lateral_bound_m
from clnlos.study.score.legibility import FWHM_PER_SIGMA
from clnlos.study.score.metrics import otsu_threshold

SEEDS = 3
SERIES_SEED = 5600     # first seed of the series
TWIN_SEED = 5656


@dataclass(frozen=True)
class Variant:
    """How a real capture and its twin are reconstructed: the entry's config (a capture's
    own, or its ``config`` file) with the reflectance its material asks for."""

    config: ReconstructionConfig

    def front(self, cap: Capture, counts: np.ndarray, queue) -> np.ndarray:
        return counts_front(cap, counts, self.config, queue)


def variant_of(entry: RealEntry, mat: MaterialKeys, base: ReconstructionConfig) -> Variant:
    """The entry's method, its material's reflectance: LCT's and f-k's falloff 2 for a
    retroreflector, else the Lambertian falloff; the iterative method's lobe likewise."""
    brdf = "retroreflective" if mat.retroreflective else "lambertian"
    cfg = base.replace(method=entry.method, brdf=brdf, falloff=None).validate(
        {"brdf": "brdf"})
    return Variant(cfg)


def photons_needed(cap: Capture, variant: Variant, queue, seeds: int = SEEDS,
                   seed0: int = SERIES_SEED, progress=None) -> dict:
    """The photons a capture needs to keep its image (the module docstring): ``photons``,
    ``photons_needed`` (median over the series), ``interval`` [lo, hi], ``status``, the
    series, and the full-photon reference front view (``reference``)."""
    counts = np.rint(cap.transient).astype(np.float32)
    photons = float(counts.sum(dtype=np.float64))
    ref = variant.front(cap, counts, queue)

    def score(y):
        s = image_score(variant.front(cap, y, queue), ref)
        if progress:
            progress()
        return s

    series = [series_crossing(score, counts, seed0 + k, level=KEEP_LEVEL)
              for k in range(seeds)]
    return {"photons": photons, **series_summary(series, photons), "series": series,
            "reference": ref}


def from_capture_mask(volume: np.ndarray, voxel_depth_m: float
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mask, depth (m), albedo) [y, x] with row 0 the top of the scene, of a
    reconstruction: its front view Otsu-thresholded, each pixel at the depth of its
    brightest voxel with the front view's value (over its maximum) as its albedo."""
    front = front_view(volume)
    mask = front > otsu_threshold(front)
    depth = (np.argmax(volume, axis=0) + 0.5) * voxel_depth_m
    # volume rows run up the scene (y = scan centres, ascending); an image's row 0 is its top
    return mask[::-1].copy(), depth[::-1].copy(), np.where(mask, front, 0.0)[::-1].copy()


def twin_scene(cap: Capture, objects: list[dict], pulse_fwhm_s: float | None, slab: dict |
               None) -> Scene:
    """The twin's scene: the capture's scan and time axis, ``objects``, its pulse and slab."""
    nt, _, nx = cap.transient.shape
    d = {"seed": 0, "scan": {"width_m": cap.scan_width_m, "points": nx},
         "time": {"bin_width_s": cap.bin_width_s, "bins": nt,
                  "start_s": 0.0 if slab else cap.start_s},
         "objects": objects,
         "sampling": {"density_per_m2": TWIN_DENSITY_PER_M2, "splat_order": 1}}
    if pulse_fwhm_s:
        d["laser"] = {"pulse_width_s": pulse_fwhm_s}
    if slab:
        d["slab"] = slab
    return Scene.from_dict(d)


def twin_objects(entry: RealEntry, mat: MaterialKeys, study: Study, rec, out_dir: Path,
                 scan_width_m: float) -> tuple[list[dict], dict]:
    """The twin's [[objects]] and its description: the described target at its depth, or
    the capture's own mask (written as .npy beside the study's results) at its depths."""
    if entry.target is not None:
        t = entry.target
        s = target_sample(t, t.text or t.pattern, mat, exposure_s=1.0, seed=0,
                          method=entry.method, brdf={}, scan_width_m=scan_width_m)
        return scene_objects(s), {"kind": t.kind, "name": t.name, "depth_m": t.depth_m}
    mask, depth, albedo = from_capture_mask(rec.volume, rec.extents["voxel_depth_m"])
    d0 = float(np.median(depth[mask]))
    folder = out_dir / "real" / _safe(entry.label)
    folder.mkdir(parents=True, exist_ok=True)
    np.save(folder / "twin_mask.npy", mask.astype(np.uint8))
    np.save(folder / "twin_depth.npy", np.where(mask, depth - d0, 0.0))
    np.save(folder / "twin_albedo.npy", albedo)
    obj = {"shape": "mask", "path": str(folder / "twin_mask.npy"),
           "depth_path": str(folder / "twin_depth.npy"), "size_m": [scan_width_m] * 2,
           "albedo_path": str(folder / "twin_albedo.npy"),
           "translate_m": [0.0, 0.0, d0], "material": mat.sample["material"],
           "albedo": float(mat.sample.get("albedo", 1.0))}
    return [obj], {"kind": "from-capture", "pixels": int(mask.sum()), "depth_m": d0,
                   "depth_range_m": [float(depth[mask].min()), float(depth[mask].max())]}


def _safe(label: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in label)


def prepared_real(entry: RealEntry, study: Study) -> tuple[Capture, ReconstructionConfig,
                                                           list[str]]:
    """(the capture as the check reconstructs it: its direct reflection zeroed, its scan
    binned to the rig's points where it has more, its scan width given where the file has
    none; the base config: the entry's ``config`` file or the defaults; notes)."""
    raw = read_capture(entry.capture)
    cap, notes = without_direct(raw)
    if entry.config:
        base = ReconstructionConfig.from_toml(entry.config)
    else:
        base = ReconstructionConfig()
    width = cap.scan_width_m or base.scan_width_m or study.grid.scan_width_m
    pts = study.grid.points
    t = cap.transient
    if pts < t.shape[2] and t.shape[2] % pts == 0:
        t = binned_scan(t, pts)
        notes.append(f"scan binned {cap.transient.shape[2]} -> {pts} points per side (the "
                     "rig's [scan] points; photon counts add)")
    cap = Capture(t, cap.bin_width_s, cap.start_s, width, cap.source,
                  dict(cap.attrs))
    return cap, base.validate(), notes


def check_capture(entry: RealEntry, mat: MaterialKeys, study: Study, out_dir: Path, queue,
                  progress=None) -> dict:
    """One row of ``real_check``: the capture's photons needed (measured), its twin's
    (predicted), their ratio (a bound where either is), the twin's description and the
    numbers it was matched to."""
    cap, base, notes = prepared_real(entry, study)
    variant = variant_of(entry, mat, base)
    rec = reconstruct(cap, variant.config, device=queue)
    # the time grid the capture's format chose (the LCT release: 16 ps), for the twin too
    variant = Variant(variant.config.replace(bins=rec.params["bins"]).validate(
        {"brdf": "brdf", "bins": "bins"}))
    measured = photons_needed(cap, variant, queue, progress=progress)
    raw = read_capture(entry.capture)
    pulse = (direct_reflection_fwhm(raw.transient, raw.bin_width_s)
             if "direct_end_s" in raw.attrs else None) or study.grid.pulse_width_s
    slab = None if variant.config.slab is None else {
        "thickness_m": variant.config.slab.thickness_m, "mu_a": variant.config.slab.mu_a,
        "mu_s_prime": variant.config.slab.mu_s_prime, "n": variant.config.slab.n}
    objects, described = twin_objects(entry, mat, study, rec, out_dir, cap.scan_width_m)
    tau = ForwardModel(twin_scene(cap, objects, pulse, slab), queue=queue).run()
    fwhm_s = pulse or study.grid.pulse_width_s or cap.bin_width_s
    nx = cap.transient.shape[2]
    lateral = otoole_lateral_bound_m(cap.scan_width_m, described["depth_m"], fwhm_s)
    sigma = (fwhm_s / FWHM_PER_SIGMA / cap.bin_width_s,
             *[max(1.0, lateral / FWHM_PER_SIGMA / (cap.scan_width_m / nx))] * 2)
    expected, signal, floor = matched_expectation(cap, tau, sigma)
    twin = Capture(np.random.default_rng(TWIN_SEED).poisson(expected).astype(np.float32),
                   cap.bin_width_s, cap.start_s, cap.scan_width_m, "simulated twin", {})
    predicted = photons_needed(twin, variant, queue, progress=progress)
    ratio, bound = bounded_ratio(predicted, measured)
    return {"capture": entry.capture, "name": entry.label, "material": mat.name,
            "method": entry.method, "reflectance": variant.config.brdf,
            "photons": measured["photons"], "signal_photons": signal,
            "background_per_bin": floor, "pulse_fwhm_s": pulse, "twin": described,
            "photons_needed_measured": measured["photons_needed"],
            "photons_needed_measured_interval": measured["interval"],
            "measured_status": measured["status"],
            "photons_needed_predicted": predicted["photons_needed"],
            "photons_needed_predicted_interval": predicted["interval"],
            "predicted_status": predicted["status"], "ratio": ratio, "ratio_bound": bound,
            "series": {"measured": measured["series"], "predicted": predicted["series"]},
            "notes": notes,
            "arrays": {"reference": measured["reference"].astype(np.float32),
                       "twin_reference": predicted["reference"].astype(np.float32)}}


def matched_expectation(cap: Capture, tau: np.ndarray, sigma) -> tuple[np.ndarray, float,
                                                                         float]:
    """(the twin's expected counts [t, y, x], its signal photons, the floor per bin): the
    capture's background floor from its first recorded bin on, the noise-free twin ``tau``
    scaled by least squares to the counts above it, and the counts the twin does not explain
    (a room's interreflections, a target's backing, what its mask misses) smoothed by a
    Gaussian of ``sigma`` (bins, cells, cells: the system's resolution) to their expectation."""
    y = np.asarray(cap.transient, np.float64)
    nt = y.shape[0]
    first = first_recorded_bin(y.reshape(nt, -1).sum(axis=1))
    floor = estimate_noise(cap.transient, cap.bin_width_s, cap.start_s).background_per_bin
    t = np.asarray(tau, np.float64)[first:]
    above = y[first:] - floor
    a = float(np.sum(t * above) / max(float(np.sum(t * t)), 1e-300))
    lam = np.zeros_like(y)
    lam[first:] = a * t + floor + np.maximum(gaussian_filter(above - a * t, sigma), 0.0)
    return lam, a * float(t.sum()), floor


def real_check(study: Study, mats: dict, out_dir: Path, queue=None, progress=None) -> list:
    """Every ``[[real]]`` entry's row (:func:`check_capture`)."""
    return [check_capture(e, mats[e.material.name], study, out_dir, queue, progress)
            for e in study.real]


def summary(rows: list[dict]) -> dict:
    """The median ratio of the rows whose ratio is a value, and how many are bounds."""
    vals = [r["ratio"] for r in rows if r["ratio_bound"] is None]
    return {"median_ratio": float(np.median(vals)) if vals else None,
            "n": len(rows), "n_bounds": len(rows) - len(vals),
            "within_2x": sum(1 for v in vals if 0.5 <= v <= 2.0)}


def json_rows(rows: list[dict]) -> list[dict]:
    """The rows without their arrays (results.json)."""
    return [json.loads(json.dumps({k: v for k, v in r.items() if k != "arrays"}))
            for r in rows]
