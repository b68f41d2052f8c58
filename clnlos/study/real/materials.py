"""The material question on real captures: how many photons a real target needs, per inversion
and assumed reflectance, for its reconstruction to keep its image (results.json
``real_materials``).

The captures: the light-cone transform release (``lct/``: O'Toole, Lindell & Wetzstein 2018,
a diffuse S and retroreflective letters and charts, the same rig) and the CDT set (``cdt/``:
letters and a chart behind a slab), each as its reader gives it (the LCT release with its
direct reflection zeroed, :func:`clnlos.io.capture.without_direct`). Each is reconstructed with
every inversion x assumed reflectance of :func:`variants` (LCT and f-k: the Lambertian
falloff (t/T)^4 or the retroreflective (t/T)^2; the iterative method with the matching lobe
where the study asks for it).

The score. The reference image of a capture is the front view (max over depth, normalised)
of its full-photon reconstruction by the variant whose two binomial halves of the photons
agree best (normalised cross-correlation of their front views): chosen from the data, not
from what the target is. A reconstruction keeps its image where the NCC of its front view
with the reference is at least KEEP_LEVEL. A blob does not: the reference blurred by a
Gaussian of BLOB_SIGMA_FRACTION of the scan is scored too (``blob_ncc``, below KEEP_LEVEL on
every shared capture; a capture where it is not is flagged). Noise scores about 0.

Photons needed. Each capture is thinned binomially down the plan's ladder (nested: every
photon of a fainter capture is one of the brighter one's, the exact model of a shorter
exposure), its ``seeds`` series each refined at the crossing of KEEP_LEVEL until bracketed
within 1.5x (:mod:`clnlos.study.real.ladder`); the median over the series and the range
that holds every bracket; "at most" where a series keeps the image to its last rung (an
upper bound, kept as one in every ratio), "not kept" where the full capture already scores
below. Photons are the counts the reconstruction sees (after the direct reflection).

The question on real data: photons a diffuse S needs over those a retroreflective S needs
(``data_diffuse_s`` and the S of ``data_s_u``, same rig), per inversion, each with the
variant that reads it best. How the numbers were measured is in docs/real_materials.md.
"""

from __future__ import annotations

import html
import math
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
from clnlos.io.figures import new_figure
from clnlos.io.files import read_capture
from clnlos.study.score.legibility import detail as detail_image
from clnlos.study.real.ladder import AT_MOST, bounded_ratio, series_crossing, series_summary
from clnlos.study.real.capture import capture_config, estimate_letters, measurement_summary
from clnlos.study.samples.resolution import chart_features, json_ready, otoole_lateral_bound_m
from clnlos.study.real.thinning import thinned_series

KEEP_LEVEL = 0.8            # NCC with the reference front view: the image is kept
BLOB_SIGMA_FRACTION = 0.08  # the blob control: the reference blurred by this x the scan (rms)
DETAIL_SIGMA_FRACTION = 3 / 64  # the detail: an image less its blur of this x the scan (rms)
HALVES_SEED = 47            # the binomial halves that choose the reference variant
SERIES_SEED = 4700          # first seed of the thinning series

# what the shared captures are (their READMEs): family, material, target
CATALOG = {
    "data_diffuse_s": ("lct", "diffuse", "S"),
    "data_s_u": ("lct", "retroreflective", "S and U"),
    "data_outdoor_s": ("lct", "retroreflective", "S outdoors (sunlight)"),
    "data_resolution_chart_40cm": ("lct", "retroreflective", "resolution chart at 40 cm"),
    "data_dot_chart_40cm": ("lct", "retroreflective", "dot chart at 40 cm"),
    "letters_ut": ("cdt", "as captured (not stated)", "UT behind the slab"),
    "letter_s": ("cdt", "as captured (not stated)", "S behind the slab"),
    "resolution_70": ("cdt", "as captured (not stated)", "resolution chart behind the slab"),
}
REFLECTANCES = ("lambertian", "retroreflective")  # LCT's and f-k's brdf (their falloff)
HEADLINE = ("data_diffuse_s", "data_s_u")  # the diffuse S against the retroreflective S
TWIN_MATERIALS = {"data_diffuse_s": "lambertian", "data_s_u": "retroreflective"}
TWIN_SLAB_M = 0.15       # the twin's letter: the reconstruction within this depth of its peak
TWIN_PULSE_S = 70e-12    # the twin's pulse FWHM where the capture shows no direct reflection
TWIN_DENSITY_PER_M2 = 4e5  # surface elements per m^2 of the twin's letter
TWIN_SEED = 4748


@dataclass(frozen=True)
class RealPlan:
    """How much of the question a run asks: the thinning ladder (fractions of the photons),
    series per capture, the inversions, the scan points and time bin the LCT release is
    reconstructed on (its scan binned 2 x 2 where ``points`` is half; photon counts add)."""

    ladder: tuple[float, ...] = (1.0, 0.3, 0.1, 0.03, 0.01, 0.003, 0.001)
    seeds: int = 3
    inversions: tuple[str, ...] = ("lct", "fk")
    points: int | None = None         # None: the capture's own scan
    bin_width_s: float | None = None  # None: the release's published 16 ps
    twins: bool = True                # the simulated twins of the diffuse and retroreflective S

    @classmethod
    def quick(cls) -> RealPlan:
        return cls(ladder=(1.0, 0.1, 0.03, 0.01, 0.003, 0.001, 0.0003), seeds=2,
                   points=32, bin_width_s=32e-12)


def variants(inversions) -> list[tuple[str, str]]:
    """(inversion, assumed reflectance) pairs a capture is reconstructed with."""
    return [(inv, r) for inv in inversions for r in REFLECTANCES]


def real_capture_paths(data_dir: Path) -> list[Path]:
    """The catalogued captures present under ``data_dir`` (``lct/``, ``cdt/``)."""
    out = []
    for name, (family, _, _) in CATALOG.items():
        p = Path(data_dir) / family / f"{name}.mat"
        if p.is_file():
            out.append(p)
    return out


def binned_scan(transient: np.ndarray, points: int) -> np.ndarray:
    """[t, y, x] counts summed over blocks of the scan to ``points`` x ``points`` (the same
    photons on a coarser scan: still Poisson counts)."""
    nt, ny, nx = transient.shape
    if points >= nx or nx % points or ny % points:
        return transient
    b = nx // points
    return transient.reshape(nt, ny // b, b, nx // b, b).sum(axis=(2, 4))


def prepared_capture(path: Path, plan: RealPlan) -> tuple[Capture, ReconstructionConfig]:
    """(capture with its direct reflection removed and its scan binned, base config)."""
    name = Path(path).stem
    cap, _ = without_direct(read_capture(path))
    if CATALOG[name][0] == "cdt":
        return cap, capture_config(name, "lct", published_snr=True)
    if plan.points is not None:
        cap = Capture(binned_scan(cap.transient, plan.points), cap.bin_width_s, cap.start_s,
                      cap.scan_width_m, cap.source, {k: v for k, v in cap.attrs.items()
                                                     if k != "direct_end_s"})
    kw = {}
    target = plan.bin_width_s or cap.attrs.get("bin_width_default_s")
    if target and target > cap.bin_width_s:
        kw["bins"] = max(1, int(round(cap.transient.shape[0] * cap.bin_width_s / target)))
    return cap, ReconstructionConfig(**kw).validate()


def variant_config(base: ReconstructionConfig, inversion: str, reflectance: str
                   ) -> ReconstructionConfig:
    """The base config with the inversion and the assumed reflectance (its ``brdf``: LCT's
    falloff 4 or 2; f-k's 2 for both, its own default being the retroreflective one)."""
    return base.replace(method=inversion, brdf=reflectance, falloff=None).validate(
        {"brdf": "brdf"})  # named: the capture format's default reflectance stays out


def front_view(volume: np.ndarray) -> np.ndarray:
    """Max over depth [y, x], normalised to its maximum (zeros stay zeros)."""
    img = np.asarray(volume, np.float64).max(axis=0)
    top = img.max()
    return img / top if top > 0 else img


def ncc(a: np.ndarray, b: np.ndarray) -> float:
    """Normalised cross-correlation of two images (0 where either is flat)."""
    a = np.asarray(a, np.float64) - np.mean(a)
    b = np.asarray(b, np.float64) - np.mean(b)
    den = math.sqrt(float((a * a).sum() * (b * b).sum()))
    return float((a * b).sum() / den) if den > 0 else 0.0


def detail(img: np.ndarray) -> np.ndarray:
    """The image minus its Gaussian blur of DETAIL_SIGMA_FRACTION of the scan (rms): the
    strokes and edges a blob lacks."""
    return detail_image(img, DETAIL_SIGMA_FRACTION * np.shape(img)[1])


def image_score(image: np.ndarray, reference: np.ndarray) -> float:
    """The score of an image against the reference: the NCC of their details
    (:func:`detail`)."""
    return ncc(detail(image), detail(reference))


def blob_control(reference: np.ndarray) -> float:
    """The score of the reference blurred to a blob (BLOB_SIGMA_FRACTION of the scan)."""
    return image_score(gaussian_filter(reference, BLOB_SIGMA_FRACTION * reference.shape[1]),
                       reference)


def counts_front(cap: Capture, counts: np.ndarray, cfg: ReconstructionConfig,
                 queue) -> np.ndarray:
    """The front view of ``counts`` (a thinning of ``cap``'s, its direct cut left to the
    config) reconstructed by ``cfg``."""
    c = Capture(counts, cap.bin_width_s, cap.start_s, cap.scan_width_m, cap.source,
                {k: v for k, v in cap.attrs.items() if k != "direct_end_s"})
    return front_view(reconstruct(c, cfg, device=queue).volume)


def capture_rows(path: Path, plan: RealPlan, queue, progress=None) -> dict:
    """One capture's entry (:func:`ladder_rows` of the capture as read, with its name,
    family, material and target)."""
    name = Path(path).stem
    family, material, target = CATALOG[name]
    cap, base = prepared_capture(path, plan)
    invs = plan.inversions if family == "lct" else ("lct",)
    rows = ladder_rows(cap, base, plan, invs, queue, progress)
    return {"name": name, "family": family, "material": material, "target": target, **rows}


def ladder_rows(cap: Capture, base: ReconstructionConfig, plan: RealPlan, inversions, queue,
                progress=None) -> dict:
    """Photons, the reference variant and each variant's half agreement, the blob control,
    and per variant the scores along the ladder and the photons needed (median and range
    over the series) of a capture of photon counts."""
    counts = np.rint(cap.transient).astype(np.float32)
    photons = float(counts.sum(dtype=np.float64))
    signal = signal_photons(counts, cap.bin_width_s, cap.start_s)
    var = variants(inversions)
    cfgs = {v: variant_config(base, *v) for v in var}
    half = thinned_series(counts, (1.0, 0.5), seed=HALVES_SEED)[1]
    other = counts - half
    agree, full = {}, {}
    for v in var:
        agree[v] = image_score(counts_front(cap, half, cfgs[v], queue),
                               counts_front(cap, other, cfgs[v], queue))
        full[v] = counts_front(cap, counts, cfgs[v], queue)
        if progress:
            progress()
    best = max(var, key=lambda v: agree[v])
    ref = full[best]
    rows = []
    for v in var:
        def score(y, v=v):
            s = image_score(counts_front(cap, y, cfgs[v], queue), ref)
            if progress:
                progress()
            return s

        full_score = image_score(full[v], ref)
        series = [series_crossing(score, counts, SERIES_SEED + k, level=KEEP_LEVEL,
                                  ladder=plan.ladder, full_score=full_score)
                  for k in range(plan.seeds)]
        need = series_summary(series, photons)
        n = need["photons_needed"]
        rows.append({"inversion": v[0], "reflectance": v[1], "half_agreement": agree[v],
                     "full_score": full_score, "series": series, "status": need["status"],
                     "photons_needed": n, "photons_needed_range": need["interval"],
                     "fraction_needed": None if n is None else n / photons,
                     "signal_photons_needed": None if n is None else n * signal / photons,
                     "at_most": need["status"] == AT_MOST})
    blob = blob_control(ref)
    return {"photons": photons, "signal_photons": signal, "ladder": list(plan.ladder),
            "reference": {"inversion": best[0], "reflectance": best[1]}, "blob_ncc": blob,
            "blob_fails": bool(blob < KEEP_LEVEL), "rows": rows,
            "arrays": {"reference": ref.astype(np.float32)}}


def twin_scene(cap: Capture, letters: dict, material: str, pulse_fwhm_s: float) -> Scene:
    """The simulated twin of a real capture: its scan and time axis, the ``letters``
    (:func:`clnlos.study.real.capture.estimate_letters`) in ``material`` (no slab), a laser
    pulse of the FWHM measured on the real capture."""
    nt, _, nx = cap.transient.shape
    objects = [{"shape": "letters", "text": L["text"], "height_m": L["height_m"],
                "stroke_m": L["stroke_m"], "translate_m": [*L["centre_m"], L["depth_m"]],
                "rotate_deg": [0.0, L["tilt_deg"], 0.0], "material": material,
                "albedo": 1.0} for L in letters["letters"]]
    return Scene.from_dict({
        "seed": 0, "scan": {"width_m": cap.scan_width_m, "points": nx},
        "time": {"bin_width_s": cap.bin_width_s, "bins": nt, "start_s": cap.start_s},
        "objects": objects, "laser": {"pulse_width_s": pulse_fwhm_s},
        "sampling": {"density_per_m2": TWIN_DENSITY_PER_M2, "splat_order": 1}})


def twin_counts(tau: np.ndarray, signal_photons: float, background_per_bin: float,
                first_bin: int, seed: int) -> np.ndarray:
    """Poisson counts of a noise-free transient scaled to ``signal_photons``, over a floor of
    ``background_per_bin`` per bin and scan point from ``first_bin`` on (the real capture's)."""
    lam = np.asarray(tau, np.float64) * (signal_photons / max(float(tau.sum()), 1e-300))
    lam[first_bin:] += background_per_bin
    return np.random.default_rng(seed).poisson(lam).astype(np.float32)


def letter_twin(path: Path, plan: RealPlan, material: str, queue, progress=None) -> dict:
    """A real capture of an S beside its simulated twin in ``material``: the S estimated from
    the real reference reconstruction (its depth slab: the brightest voxel's +-TWIN_SLAB_M,
    so the U behind the retroreflective S stays out), simulated at the same scan, bins,
    signal photons and background, measured (photons, peak time, temporal FWHM of the
    scan-summed profile) and thinned like the real capture (:func:`ladder_rows`)."""
    name = Path(path).stem
    cap, base = prepared_capture(path, plan)
    noise = estimate_noise(cap.transient, cap.bin_width_s, cap.start_s)
    rec = reconstruct(cap, variant_config(base, "lct", "retroreflective"), device=queue)
    v = rec.volume
    kz = int(np.unravel_index(np.argmax(v), v.shape)[0])
    k = max(1, int(round(TWIN_SLAB_M / rec.extents["voxel_depth_m"])))
    sub = np.zeros_like(v)
    sub[max(0, kz - k):kz + k + 1] = v[max(0, kz - k):kz + k + 1]
    letters = estimate_letters(sub, rec.extents, "S")
    raw = read_capture(path)
    pulse = (direct_reflection_fwhm(raw.transient, raw.bin_width_s)
             if "direct_end_s" in raw.attrs else None) or TWIN_PULSE_S
    tau = ForwardModel(twin_scene(cap, letters, material, pulse), queue=queue).run()
    first = first_recorded_bin(cap.transient.reshape(cap.transient.shape[0], -1).sum(axis=1))
    n_scan = cap.transient.shape[1] * cap.transient.shape[2]
    floor = noise.background_per_bin
    signal = max(float(cap.transient.sum()) - floor * n_scan * (cap.transient.shape[0] - first),
                 1.0)
    twin = Capture(twin_counts(tau, signal, floor, first, TWIN_SEED), cap.bin_width_s,
                   cap.start_s, cap.scan_width_m, "simulated twin", {})
    keys = ("photons", "peak_time_s", "temporal_fwhm_s")
    real_m = measurement_summary(cap.transient, cap.bin_width_s, name)
    twin_m = measurement_summary(twin.transient, cap.bin_width_s, f"{name} twin")
    rows = ladder_rows(twin, base, plan, ("lct",), queue, progress)
    return {"name": name, "material": material, "letters": letters,
            "pulse_fwhm_s": pulse, "background_per_bin": floor,
            "real": {k: real_m[k] for k in keys}, "twin": {k: twin_m[k] for k in keys},
            **rows}


def signal_photons(counts: np.ndarray, bin_width_s: float, start_s: float) -> float:
    """The photons above the floor of dark counts and ambient light (the noise estimate's
    background per bin and scan point, over the recorded bins): thinning scales them with
    the total, so a photons-needed count converts by their share."""
    noise = estimate_noise(counts, bin_width_s, start_s)
    nt = counts.shape[0]
    first = first_recorded_bin(counts.reshape(nt, -1).sum(axis=1, dtype=np.float64))
    n_scan = counts.shape[1] * counts.shape[2]
    return max(0.0, float(counts.sum(dtype=np.float64))
               - noise.background_per_bin * n_scan * (nt - first))


def ratio_text(h: dict, fmt: str = ".3g") -> str:
    """A headline ratio in words: "26x (21-33x)", "at most 26x (-33x)": a bound said as one,
    an open end of its range as "-"."""
    lo, hi = h["ratio_range"]
    bound = {"<=": "at most ", ">=": "at least ", "unknown": "(two bounds) "}.get(
        h.get("ratio_bound"), "")
    end = "-" if lo is None else format(lo, fmt)
    top = "-" if hi is None else format(hi, fmt)
    return f"{bound}{format(h['ratio'], fmt)}x ({end} to {top}x)"


def headline_ratios(captures: list[dict]) -> list[dict]:
    """Per inversion: photons the diffuse S needs over those the retroreflective S needs,
    each with its best-reading reflectance (the fewest photons needed), with the range
    from the series' extremes."""
    by = {c["name"]: c for c in captures}
    if not all(n in by for n in HEADLINE):
        return []
    out = []
    for inv in sorted({r["inversion"] for r in by[HEADLINE[0]]["rows"]}):
        best = {}
        for n in HEADLINE:
            cand = [r for r in by[n]["rows"] if r["inversion"] == inv
                    and r["photons_needed"] is not None]
            best[n] = min(cand, key=lambda r: r["photons_needed"]) if cand else None
        d, r = best[HEADLINE[0]], best[HEADLINE[1]]
        row = {"inversion": inv, "diffuse": None if d is None else
               {"reflectance": d["reflectance"], "photons": d["photons_needed"],
                "signal_photons": d["signal_photons_needed"], "status": d["status"]},
               "retroreflective": None if r is None else
               {"reflectance": r["reflectance"], "photons": r["photons_needed"],
                "signal_photons": r["signal_photons_needed"], "status": r["status"]}}
        if d is not None and r is not None:
            row["ratio"], row["ratio_bound"] = bounded_ratio(d, r)
            row["signal_ratio"] = d["signal_photons_needed"] / r["signal_photons_needed"]
            (dlo, dhi), (rlo, rhi) = d["photons_needed_range"], r["photons_needed_range"]
            row["ratio_range"] = [None if dlo is None else dlo / rhi,
                                  None if rlo is None else dhi / rlo]
        elif d is None and r is not None:
            row["ratio"], row["ratio_bound"] = None, None
            row["note"] = ("the diffuse S does not keep its image even with all its photons: "
                           "the ratio exceeds its photons over the retroreflective S's need")
        out.append(row)
    return out


def direct_reflection_fwhm(transient: np.ndarray, bin_width_s: float) -> float | None:
    """The system's response as the direct reflection off the wall shows it (a window that
    starts at its peak, as the LCT release's): twice the time from the scan-summed peak to
    half of it (s); None where it does not fall to half within the window."""
    p = np.asarray(transient, np.float64).reshape(transient.shape[0], -1).sum(axis=1)
    k = int(np.argmax(p))
    below = np.flatnonzero(p[k:] < p[k] / 2)
    if not below.size:
        return None
    j = k + int(below[0])
    frac = (p[j - 1] - p[k] / 2) / (p[j - 1] - p[j]) if p[j - 1] > p[j] else 0.0
    return float(2 * (j - 1 - k + frac + 0.5) * bin_width_s)


def chart_resolution(path: Path, queue) -> dict:
    """A real chart's resolved features (:func:`chart_features` on its default
    reconstruction at full photons), the smallest resolved and unresolved spacings, and
    O'Toole's lateral bound at its depth with the system's temporal FWHM measured on the
    direct reflection (:func:`direct_reflection_fwhm`)."""
    raw = read_capture(path)
    cap, _ = without_direct(raw)
    rec = reconstruct(raw, ReconstructionConfig().validate(), device=queue)
    feats = chart_features(rec.volume, rec.extents)
    res = [f["spacing_m"] for f in feats["features"].values() if f["resolved"]]
    unres = [f["spacing_m"] for f in feats["features"].values() if not f["resolved"]]
    fwhm = direct_reflection_fwhm(raw.transient, raw.bin_width_s)
    bound = (otoole_lateral_bound_m(cap.scan_width_m, feats["chart_depth_m"], fwhm)
             if fwhm else None)
    return {"name": Path(path).stem, "chart_depth_m": feats["chart_depth_m"],
            "spots": len(feats["spots"]), "criterion": feats["criterion"],
            "smallest_resolved_m": min(res) if res else None,
            "smallest_unresolved_m": min(unres) if unres else None,
            "temporal_fwhm_s": fwhm, "lateral_bound_m": bound,
            "features": json_ready(feats["features"]),
            "arrays": {"image": feats["arrays"]["image"], "extents": dict(rec.extents)}}


def real_materials(data_dir: Path, plan: RealPlan, queue=None, progress=None) -> dict:
    """The section: ``captures`` (:func:`capture_rows` each), ``headline``
    (:func:`headline_ratios`), ``charts`` (:func:`chart_resolution` of the LCT charts),
    the score's definition; arrays under ``arrays`` keys (pop with json_ready)."""
    paths = real_capture_paths(data_dir)
    captures = [capture_rows(p, plan, queue, progress) for p in paths]
    charts = [chart_resolution(p, queue) for p in paths
              if p.stem in ("data_resolution_chart_40cm", "data_dot_chart_40cm")]
    section = {"score": f"NCC of the front view's detail with the reference's >= "
                        f"{KEEP_LEVEL:g} (reference: the full-photon reconstruction of the "
                        "variant whose binomial halves agree best)", "keep_level": KEEP_LEVEL,
            "plan": {"ladder": list(plan.ladder), "seeds": plan.seeds,
                     "inversions": list(plan.inversions), "points": plan.points,
                     "bin_width_s": plan.bin_width_s},
            "captures": captures, "headline": headline_ratios(captures), "charts": charts}
    section["headline_rows"] = headline_rows(section)
    if plan.twins:
        by = {p.stem: p for p in paths}
        twins = [letter_twin(by[n], plan, m, queue, progress)
                 for n, m in TWIN_MATERIALS.items() if n in by]
        section["twins"] = twins
        section["twin_headline"] = headline_ratios(
            [{**t, "name": t["name"]} for t in twins])
    return section


def _best_row(capture: dict, inversion: str = "lct") -> dict | None:
    """The variant of ``inversion`` that keeps the capture's image with the fewest photons."""
    rows = [r for r in capture["rows"] if r["inversion"] == inversion
            and r["photons_needed"] is not None]
    return min(rows, key=lambda r: r["photons_needed"]) if rows else None


def headline_rows(section: dict) -> list[list]:
    """The report's headline rows (:mod:`clnlos.study.report.headline`'s format): per capture, the
    photons its best LCT variant needs, with the series' range; an open upper end where the
    image is kept down to the smallest fraction tried."""
    out = []
    for c in section["captures"]:
        r = _best_row(c)
        if r is None:
            out.append([f"{c['target'].split(',')[0]}, {c['material'].split(' (')[0]}", None,
                        [c["photons"], None]])
            continue
        lo, hi = r["photons_needed_range"]
        out.append([f"{c['target'].split(',')[0]}, {c['material'].split(' (')[0]}",
                    r["photons_needed"], [lo, hi]])
    return out


def section_figure(section: dict):
    """Per capture: its reference front view and the score of each variant against photons
    along each refined series (dashed: the keep level) (matplotlib Figure)."""
    caps = section["captures"]
    fig, ax = new_figure(2, max(1, len(caps)), (2.3 * max(1, len(caps)), 4.8))
    ax = np.asarray(ax).reshape(2, -1)
    for k, c in enumerate(caps):
        ref = c.get("arrays", {}).get("reference")
        if ref is not None:
            ax[0, k].imshow(ref, cmap="gray", origin="lower")
        ax[0, k].set_title(f"{c['target']}\n{c['material']}", fontsize=7)
        ax[0, k].set_axis_off()
        for j, r in enumerate(c["rows"]):
            for i, s in enumerate(r["series"]):
                f, v = zip(*sorted(s["tried"]), strict=True)
                ax[1, k].plot(np.asarray(f) * c["photons"], v, marker="o", ms=2.5, lw=0.8,
                              color=f"C{j}", label=None if i else
                              f"{r['inversion']} {r['reflectance'][:5]}.")
        ax[1, k].axhline(section["keep_level"], color="gray", ls="--", lw=0.8)
        ax[1, k].set_xscale("log")
        ax[1, k].set(ylim=(-0.2, 1.05), xlabel="photons")
        ax[1, k].xaxis.label.set_fontsize(7)
        ax[1, k].tick_params(labelsize=6)
        if k == 0:
            ax[1, k].set_ylabel("score (detail NCC)", fontsize=7)
            ax[1, k].legend(fontsize=5.5)
    return fig


def _blob_sentence(section: dict) -> str:
    """Where the blob control reaches the keep level (the score cannot tell the image from
    a blob there), said; else that it stays below on every capture."""
    bad = [c["name"] for c in section["captures"] if not c["blob_fails"]]
    if not bad:
        return ", below the keep level on every capture."
    return (", below the keep level except on " + ", ".join(bad) + " (there the score "
            "cannot tell the image from a blob: read their rows as upper bounds).")


def _twin_pairs(section: dict) -> list[str]:
    """Per twin, the photons its best LCT variant needs, as text."""
    out = []
    for t in section.get("twins", ()):
        r = _best_row(t)
        out.append("not kept at full photons" if r is None else
                   f"{r['photons_needed']:.3g} photons ({r['reflectance']})")
    return out


def section_html(section: dict, out_dir, png=None) -> str:
    """The report's real-materials section: the headline ratio, the photons-needed table,
    the chart resolutions, the figure (``png(fig)``: base64 PNG, when given)."""
    esc = html.escape
    out = ["<details open><summary>Real materials: photons a real target needs "
           "(light-cone transform release and CDT captures)</summary>",
           f"<p>Score: {esc(section['score'])}; photons needed = where the score first "
           "falls below the keep level along nested binomial thinnings (median and range "
           f"over {section['plan']['seeds']} series). The blob column: the score of the "
           "reference blurred to a blob" + _blob_sentence(section) + "</p>"]
    for h in section["headline"]:
        if h.get("ratio") is not None:
            out.append(f"<p><b>{esc(h['inversion'].upper())}: the diffuse S needs "
                       f"{esc(ratio_text(h))} the photons of the retroreflective S</b> "
                       f"({h['diffuse']['photons']:.3g} against "
                       f"{h['retroreflective']['photons']:.3g}); counted above the floor of "
                       f"dark counts and ambient light, {h['signal_ratio']:.3g}x "
                       f"({h['diffuse']['signal_photons']:.3g} against "
                       f"{h['retroreflective']['signal_photons']:.3g}): the rest is the "
                       "diffuse capture's larger floor.</p>")
        elif h.get("note"):
            out.append(f"<p><b>{esc(h['inversion'].upper())}:</b> {esc(h['note'])}</p>")
    head = ["capture", "material", "photons", "reference", "blob", "inversion", "reflectance",
            "half agreement", "photons needed", "range", "fraction"]
    rows = []
    for c in section["captures"]:
        for r in c["rows"]:
            need, rng = r["photons_needed"], r["photons_needed_range"]
            rows.append([c["name"], c["material"], f"{c['photons']:.3g}",
                         f"{c['reference']['inversion']} {c['reference']['reflectance']}",
                         f"{c['blob_ncc']:.2f}", r["inversion"], r["reflectance"],
                         f"{r['half_agreement']:.2f}",
                         "not kept at full photons" if need is None else
                         f"{'at most ' if r['at_most'] else ''}{need:.3g}",
                         "" if rng is None else
                         f"{'-' if rng[0] is None else format(rng[0], '.3g')} to "
                         f"{rng[1]:.3g}",
                         "" if r["fraction_needed"] is None else f"{r['fraction_needed']:.3g}"])
    out.append("<div class='tab'><table><tr>" + "".join(f"<th>{esc(h)}</th>" for h in head)
               + "</tr>" + "".join("<tr>" + "".join(f"<td>{esc(str(v))}</td>" for v in r)
                                   + "</tr>" for r in rows) + "</table></div>")
    for t, h in zip(section.get("twins", ()), _twin_pairs(section), strict=False):
        out.append(f"<p>Simulated twin of {esc(t['name'])} ({esc(t['material'])}): "
                   f"{t['twin']['photons']:.3g} photons (real {t['real']['photons']:.3g}), peak "
                   f"{t['twin']['peak_time_s'] * 1e9:.2f} ns (real "
                   f"{t['real']['peak_time_s'] * 1e9:.2f} ns), FWHM "
                   f"{t['twin']['temporal_fwhm_s'] * 1e9:.2f} ns (real "
                   f"{t['real']['temporal_fwhm_s'] * 1e9:.2f} ns); needs {h}.</p>")
    for h in section.get("twin_headline", ()):
        if h.get("ratio") is not None:
            out.append(f"<p><b>The twins predict {esc(ratio_text(h))}</b>.</p>")
    for ch in section["charts"]:
        def cm(v):
            return "-" if v is None else f"{100 * v:.1f} cm"
        out.append(f"<p>{esc(ch['name'])} at {ch['chart_depth_m']:.3f} m: smallest resolved "
                   f"spacing {cm(ch['smallest_resolved_m'])}, smallest unresolved "
                   f"{cm(ch['smallest_unresolved_m'])}; O'Toole's lateral bound "
                   f"{cm(ch['lateral_bound_m'])} (the system's temporal FWHM "
                   f"{0 if ch['temporal_fwhm_s'] is None else ch['temporal_fwhm_s'] * 1e12:.0f}"
                   f" ps, measured on the direct reflection; {esc(ch['criterion'])}).</p>")
    if png is not None and section["captures"]:
        out.append("<img alt='real captures: reference front views and score against photons'"
                   f" src='data:image/png;base64,{png(section_figure(section))}'/>")
    out.append("</details>")
    return "\n".join(out)
