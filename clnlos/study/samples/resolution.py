"""Measured resolution of the study's geometry, O'Toole's bound beside it, and the real chart.

A small square patch (point-like: ``patch_m`` = 1 cm, about one lateral voxel of the seed's
geometry) faces the scan plane at the geometry's depth, centred on the scan point nearest
the axis. It is simulated through the slab once noise-free and once at a photon budget,
and reconstructed by each method; for each reconstruction the profiles through its peak
along x, y and z give the lateral FWHM (mean of x and y) and the axial FWHM, each with the
half-maximum crossings interpolated between voxels (:func:`fwhm_1d`). A patch of side a
broadens a Gaussian PSF of FWHM F to about sqrt(F^2 + (0.68 a)^2): 1% for a = 1 cm, F = 5 cm.

O'Toole's bound for confocal scans (O'Toole, Lindell & Wetzstein, Nature 555, 2018):
lateral dx >= c gamma sqrt(w^2 + z^2) / (2 w) and axial dz >= c gamma / 2, with 2w the scan
width, z the depth and gamma the effective temporal FWHM, here MEASURED after the slab
deconvolution: the FWHM of the deconvolved transient at the scan point over the patch (it
holds the laser pulse, the bin width and what the Wiener filter leaves of the slab blur).
The bound is a two-point criterion for a linear inversion; a single point's FWHM can fall
below it: f-k migration returns |psi|^2 (:mod:`clnlos.inverse.fk`), whose FWHM is about 1/sqrt(2)
of the amplitude's, and the iterative method's non-negativity and L1 prior narrow it.

At the budget, a 1 cm^2 patch returns ~200x fewer photons than the study's 'UT' letters and
the auto-chosen Wiener SNRs (:mod:`clnlos.inverse.snr`) would smooth it far more than they smooth
the letters. ``budget_area_m2`` (default: the area of the geometry's letters) scales the
patch's albedo so that its capture holds the photons of a Lambertian target of that area at
the same depth: the resolution the letters' own photon count allows.

The real chart (``resolution_70.mat``, Supplementary Fig. 17 of Lindell & Wetzstein 2020,
0.7 m scan): the chart's design is not part of the shared data, so its features are found
in the reconstruction (:func:`chart_features`): the spots (local maxima of the chart plane)
and each pair of neighbouring spots with the dip of the image along the segment between
them. A pair is resolved when its contrast 1 - dip / min(peak1, peak2) is at least
CONTRAST_RESOLVED (0.2, about Rayleigh's 19% dip for two sinc^2 spots); patches closer than
the resolution merge into one spot, reported with its FWHM along x and y (a spot much wider
than the point response is a group none of whose members is resolved).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np
from scipy.ndimage import map_coordinates, maximum_filter
from scipy.optimize import brentq

from clnlos.physics.constants import C0
from clnlos.config import ReconstructionConfig, slab_table, snr_rule_applies
from clnlos.forward.geometry import sample_letters
from clnlos.forward.model import ForwardModel
from clnlos.forward.noise import photon_counts
from clnlos.forward.scene import Detector, Scene
from clnlos.inverse.methods import method_names
from clnlos.inverse.pipeline import reconstruct
from clnlos.io.capture import Capture
from clnlos.io.figures import new_figure
from clnlos.physics.slab import CDT_SLAB, Slab
from clnlos.runtime.device import get_queue
from clnlos.study.file.spec import StudyGrid
from clnlos.study.plan.scenes import window_m

CONTRAST_RESOLVED = 0.2   # dip between two maxima, as a fraction of the lower one
PEAK_FLOOR = 0.25         # chart maxima below this fraction of the image maximum are ignored
PEAK_PROMINENCE = 0.03    # ... and those that rise less than this above their surroundings
CHART_SLAB_M = 0.05       # the chart image: max over +-this depth around the chart plane
SEARCH_CELLS = 2          # the patch's peak is searched within +-this many scan cells of it


@dataclass(frozen=True)
class ResolutionGeometry:
    """Where the resolution is measured (defaults: the seed's Table 1, the study's default
    geometry): the patch at ``depth_m`` behind the ``slab`` (None: no slab), seen by a
    confocal scan of side ``scan_width_m``. ``text``, ``letter_height_m`` and ``stroke_m``
    are the letters read at this geometry: their area sets the budget's photon count
    (``budget_area_m2`` None) and their stroke the ratio stroke / resolution.

    Fields left None are the study grid's (:class:`clnlos.study.plan.scenes.StudyGrid`, filled
    by :meth:`resolve`): ``scan_width_m``, ``points``, ``bin_width_s``, ``pulse_width_s``,
    ``iterations``, ``snr_rule``, and ``max_path_m`` (the study's window for this depth,
    :func:`clnlos.study.plan.scenes.window_m`)."""

    depth_m: float = 0.5
    slab: Slab | None = CDT_SLAB
    scan_width_m: float | None = None
    points: int | None = None
    bin_width_s: float | None = None
    pulse_width_s: float | None = None
    max_path_m: float | None = None
    iterations: int | None = None
    snr_rule: str | None = None
    patch_m: float = 0.01
    density_per_m2: float = 4e6  # 400 surface elements on the 1 cm patch
    text: str = "UT"
    letter_height_m: float = 0.15
    stroke_m: float = 0.04
    budget_area_m2: float | None = None

    @classmethod
    def from_study(cls, d: dict, **kw) -> ResolutionGeometry:
        """From a study geometry or target dict: ``scan_width_m``, ``depth_m``,
        ``letter_height_m`` or ``height_m``, ``stroke_m``, ``text`` (those present);
        ``kw`` sets any other field."""
        keys = {"scan_width_m": "scan_width_m", "depth_m": "depth_m", "stroke_m": "stroke_m",
                "text": "text", "letter_height_m": "letter_height_m",
                "height_m": "letter_height_m"}
        return cls(**{keys[k]: v for k, v in d.items() if k in keys}, **kw)

    def resolve(self, grid) -> ResolutionGeometry:
        """A copy with every None field taken from the study ``grid``."""
        fill = {f: getattr(grid, f) for f in ("scan_width_m", "points", "bin_width_s",
                                              "pulse_width_s", "iterations", "snr_rule")
                if getattr(self, f) is None}
        if self.max_path_m is None:
            fill["max_path_m"] = window_m({"depth_m": self.depth_m}, grid)
        return replace(self, **fill)

    @property
    def pitch_m(self) -> float:
        return self.scan_width_m / self.points

    def patch_centre_m(self) -> float:
        """x = y of the patch: the centre of scan cell ``points // 2`` (m)."""
        return (self.points // 2 + 0.5) * self.pitch_m - self.scan_width_m / 2

    def bins(self) -> int:
        """Capture bins: 30% past the reconstruction window (the deconvolution's guard)."""
        return int(math.ceil(1.3 * self.max_path_m / (C0 * self.bin_width_s)))


def _crossing(p: np.ndarray, i: int, level: float) -> float:
    """Where the profile crosses ``level`` between samples i and i + 1 (one below it, one
    at or above): the root of the cubic through the four samples i-1..i+2 (fewer at the
    ends), fitted to their logarithms when all are positive (exact for a Gaussian, whose
    logarithm is a parabola), else to the values."""
    j = np.arange(max(0, i - 1), min(p.size, i + 3))
    v = p[j]
    if np.all(v > 0):
        v, level = np.log(v), math.log(level)
    poly = np.polynomial.Polynomial.fit(j, v, len(j) - 1)
    fa, fb = poly(i) - level, poly(i + 1) - level
    if fa * fb > 0:  # a sample on the level, moved off it by round-off
        return float(i if abs(fa) < abs(fb) else i + 1)
    return float(brentq(lambda x: poly(x) - level, i, i + 1))


def _peak_value(p: np.ndarray, k: int) -> float:
    """The profile's maximum near sample k: the vertex of the parabola through samples
    k-1..k+1, fitted to their logarithms when positive (exact for a Gaussian), else the
    sample itself when the vertex is not a maximum inside (k-1, k+1)."""
    if k < 1 or k > p.size - 2:
        return float(p[k])
    v = p[k - 1:k + 2]
    logs = bool(np.all(v > 0))
    f = np.log(v) if logs else v
    a, b = (f[0] + f[2]) / 2 - f[1], (f[2] - f[0]) / 2
    if not a < 0:
        return float(p[k])
    d = -b / (2 * a)
    if abs(d) >= 1:
        return float(p[k])
    top = f[1] - b * b / (4 * a)
    return float(math.exp(top) if logs else top)


def fwhm_1d(profile: np.ndarray, spacing: float = 1.0, peak: int | None = None
            ) -> float | None:
    """Full width at half maximum of a 1-D profile (units of ``spacing``) around its sample
    ``peak`` (default: the maximum sample). The maximum between samples is the vertex of
    the parabola through the three samples around ``peak`` (:func:`_peak_value`), and the
    half-maximum crossing on each side is interpolated between the last sample at or above
    half and the first below it (:func:`_crossing`): both exact for a Gaussian.
    None when the profile does not fall below half its peak on both sides (wider than the
    array) or the peak is not positive."""
    p = np.asarray(profile, np.float64)
    k = int(np.argmax(p)) if peak is None else int(peak)
    if not p[k] > 0 or p.size < 3:
        return None
    half = _peak_value(p, k) / 2
    below = np.nonzero(p < half)[0]
    left, right = below[below < k], below[below > k]
    if left.size == 0 or right.size == 0:
        return None
    x_lo = _crossing(p, int(left[-1]), half)
    x_hi = _crossing(p, int(right[0]) - 1, half)
    return float((x_hi - x_lo) * spacing)


def peak_index(volume: np.ndarray, near_yx: tuple[int, int] | None = None,
               cells: int = SEARCH_CELLS) -> tuple[int, int, int]:
    """(z, y, x) of the brightest voxel of a [z, y, x] volume, within ``cells`` scan cells
    of the column ``near_yx`` when given."""
    v = np.asarray(volume)
    if near_yx is None:
        return tuple(int(i) for i in np.unravel_index(np.argmax(v), v.shape))
    iy, ix = near_yx
    y0, x0 = max(0, iy - cells), max(0, ix - cells)
    sub = v[:, y0:iy + cells + 1, x0:ix + cells + 1]
    z, y, x = np.unravel_index(np.argmax(sub), sub.shape)
    return int(z), int(y + y0), int(x + x0)


def volume_fwhm(volume: np.ndarray, voxel_lateral_m: float, voxel_depth_m: float,
                near_yx: tuple[int, int] | None = None) -> dict:
    """FWHM (m) of the profiles through the peak of a [z, y, x] volume (:func:`peak_index`):
    ``lateral_fwhm_m`` (mean of x and y; None if either is wider than the volume), the two
    lateral ones, ``axial_fwhm_m``, the peak's depth (voxel centre) and index, and
    ``profiles`` (arrays, not JSON): the x and z profiles through the peak over its value."""
    z, y, x = peak_index(volume, near_yx)
    v = np.asarray(volume, np.float64)
    fx = fwhm_1d(v[z, y, :], voxel_lateral_m, x)
    fy = fwhm_1d(v[z, :, x], voxel_lateral_m, y)
    fz = fwhm_1d(v[:, y, x], voxel_depth_m, z)
    lat = None if fx is None or fy is None else (fx + fy) / 2
    top = v[z, y, x] if v[z, y, x] > 0 else 1.0
    return {"lateral_fwhm_m": lat, "lateral_fwhm_x_m": fx, "lateral_fwhm_y_m": fy,
            "axial_fwhm_m": fz, "peak_depth_m": (z + 0.5) * voxel_depth_m,
            "peak_index": [z, y, x],
            "profiles": {"x": (v[z, y, :] / top).astype(np.float32),
                         "z": (v[:, y, x] / top).astype(np.float32)}}


def otoole_lateral_bound_m(scan_width_m: float, depth_m: float, temporal_fwhm_s: float
                           ) -> float:
    """O'Toole's confocal lateral bound c gamma sqrt(w^2 + z^2) / (2 w), w = half the scan
    width (m), z the depth (m), gamma the effective temporal FWHM (s); m."""
    w = scan_width_m / 2
    return C0 * temporal_fwhm_s * math.sqrt(w * w + depth_m * depth_m) / (2 * w)


def otoole_axial_bound_m(temporal_fwhm_s: float) -> float:
    """O'Toole's confocal axial bound c gamma / 2 (m)."""
    return C0 * temporal_fwhm_s / 2


def stroke_over_resolution(stroke_m: float, lateral_fwhm_m: float | None) -> float | None:
    """Stroke width over the lateral FWHM (> 1: strokes wider than the resolution); None
    when the FWHM was not measured (wider than the scan)."""
    if lateral_fwhm_m is None or not lateral_fwhm_m > 0:
        return None
    return float(stroke_m / lateral_fwhm_m)


def letters_area_m2(text: str, height_m: float, stroke_m: float) -> float:
    """Area (m^2) of the stroked letters (:func:`clnlos.forward.geometry.sample_letters`)."""
    return float(sample_letters(text, height_m, stroke_m, 1e6).area.sum())


def patch_scene(geometry: ResolutionGeometry):
    """The noise-free scene of the patch (:class:`clnlos.forward.scene.Scene`) of a resolved
    geometry (:meth:`ResolutionGeometry.resolve`)."""
    g = geometry
    c = g.patch_centre_m()
    d = {"seed": 0, "scan": {"width_m": g.scan_width_m, "points": g.points},
         "time": {"bin_width_s": g.bin_width_s, "bins": g.bins(), "start_s": 0.0},
         "objects": [{"shape": "rectangle", "size_m": [g.patch_m, g.patch_m],
                      "translate_m": [c, c, g.depth_m], "material": "lambertian",
                      "albedo": 1.0}],
         "laser": {"pulse_width_s": g.pulse_width_s},
         "sampling": {"density_per_m2": g.density_per_m2, "splat_order": 1}}
    if g.slab is not None:
        d["slab"] = slab_table(g.slab)
    return Scene.from_dict(d)


def detector_table(grid, exposure_s: float) -> dict:
    """A scene's [detector] table from the study grid's photon budget
    (:class:`clnlos.study.plan.scenes.StudyGrid`) at ``exposure_s`` per scan point."""
    return {"power_w": grid.power_w, "rep_rate_hz": grid.rep_rate_hz, "exposure_s": exposure_s,
            "efficiency": grid.efficiency, "wavelength_m": grid.wavelength_m,
            "etendue_m2_sr": grid.etendue_m2_sr, "dark_count_rate_hz": grid.dark_count_rate_hz}


def budget_capture(noise_free, scene, geometry: ResolutionGeometry, grid, exposure_s: float,
                   seed: int = 0):
    """Photon counts of the patch at ``exposure_s``: the noise-free capture scaled by the
    albedo that gives the patch the photons of ``budget_area_m2`` (default: the letters'
    area), then Poisson noise and dark counts (:func:`clnlos.forward.noise.photon_counts`)."""
    g = geometry
    area = (g.budget_area_m2 if g.budget_area_m2 is not None
            else letters_area_m2(g.text, g.letter_height_m, g.stroke_m))
    albedo = area / (g.patch_m * g.patch_m)
    det_scene = replace(scene, detector=Detector(**detector_table(grid, exposure_s)))
    counts = photon_counts(noise_free.transient * albedo, det_scene,
                           np.random.default_rng(seed))
    cap = Capture(counts, noise_free.bin_width_s, noise_free.start_s, noise_free.scan_width_m,
                  "simulated", dict(noise_free.attrs))
    return cap, albedo


def _measure(capture, geometry: ResolutionGeometry, methods, queue) -> dict:
    """FWHMs of each method's reconstruction of one capture, the effective temporal FWHM
    of its deconvolved transient over the patch and the bounds from it."""
    g = geometry
    iy = ix = g.points // 2
    out: dict = {}
    gamma = None
    for m in methods:
        # the grid's SNR rule, for each method it is valid for (clnlos.config)
        rule = ({"snr_rule": g.snr_rule}
                if g.snr_rule is not None and snr_rule_applies(g.snr_rule, m) else {})
        cfg = ReconstructionConfig(max_path_m=g.max_path_m, slab=g.slab, method=m,
                                   iterations=g.iterations, **rule).validate()
        rec = reconstruct(capture, cfg, device=queue, keep_transient=gamma is None)
        e = rec.extents
        out[m] = volume_fwhm(rec.volume, e["voxel_lateral_m"], e["voxel_depth_m"], (iy, ix))
        out[m]["voxel_m"] = [e["voxel_depth_m"], e["voxel_lateral_m"]]
        if gamma is None:
            gamma = fwhm_1d(rec.transient[:, iy, ix], rec.bin_width_s)
    out["effective_temporal_fwhm_s"] = gamma
    out["bound_lateral_m"] = (None if gamma is None else
                              otoole_lateral_bound_m(g.scan_width_m, g.depth_m, gamma))
    out["bound_axial_m"] = None if gamma is None else otoole_axial_bound_m(gamma)
    out["photons"] = float(np.asarray(capture.transient, np.float64).sum())
    return out


def measure_resolution(geometry: ResolutionGeometry = ResolutionGeometry(), *,
                       exposure_s: float | None = None, methods=None, grid=None,
                       queue=None, seed: int = 0) -> dict:
    """Resolution of each method at ``geometry`` (results.json ``resolution``).

    Returns, noise-free: ``{method: {"lateral_fwhm_m", "axial_fwhm_m", ...}}``,
    ``bound_lateral_m``, ``bound_axial_m``, ``effective_temporal_fwhm_s``, ``photons`` (the
    capture's sum, 1/(m^2 sr) for noise-free), ``stroke_over_resolution`` {method: stroke /
    lateral FWHM}; and, when ``exposure_s`` is given (the study's budget, e.g. 0.1 s per
    scan point), ``budget``: the same keys at that exposure of the ``grid``'s photon budget
    (default :class:`clnlos.study.plan.scenes.StudyGrid`) with ``exposure_s`` and the patch's
    ``albedo``;
    ``geometry`` echoes the geometry resolved against the grid. A FWHM is None where the
    profile stays above half its peak across the volume. Each method's entry also holds
    ``profiles`` (arrays for :func:`resolution_figure`; :func:`json_ready` drops them)."""
    grid = StudyGrid() if grid is None else grid
    methods = method_names() if methods is None else methods
    queue = get_queue(queue)
    g = geometry.resolve(grid)
    scene = patch_scene(g)
    clean = ForwardModel(scene, queue=queue).capture()
    res = _measure(clean, g, methods, queue)
    cases = [res]
    if exposure_s is not None:
        cap, albedo = budget_capture(clean, scene, g, grid, exposure_s, seed)
        res["budget"] = {**_measure(cap, g, methods, queue), "exposure_s": exposure_s,
                         "albedo": albedo}
        cases.append(res["budget"])
    for case in cases:
        case["stroke_over_resolution"] = {
            m: stroke_over_resolution(g.stroke_m, case[m]["lateral_fwhm_m"]) for m in methods}
    geo = asdict(g)
    geo["slab"] = None if g.slab is None else asdict(g.slab)
    res["geometry"] = geo
    return res


def image_maxima(img: np.ndarray, floor: float = PEAK_FLOOR) -> list[tuple[int, int]]:
    """(row, column) of the local maxima of an image (3 x 3 neighbourhood) at least
    ``floor`` of its maximum, brightest first."""
    a = np.asarray(img, np.float64)
    top = a.max()
    if not top > 0:
        return []
    keep = (a == maximum_filter(a, size=3, mode="constant", cval=-np.inf)) & (a >= floor * top)
    idx = np.argwhere(keep)
    order = np.argsort(-a[keep])
    return [(int(r), int(c)) for r, c in idx[order]]


def neighbour_pairs(points: list[tuple[int, int]]) -> list[tuple[int, int]]:
    """Index pairs (i, j) of the Gabriel graph of ``points``: no third point lies inside the
    circle whose diameter is the segment i-j (the neighbours a dip can lie between)."""
    p = np.asarray(points, np.float64).reshape(-1, 2)
    out = []
    for i in range(len(p)):
        for j in range(i + 1, len(p)):
            mid, r2 = (p[i] + p[j]) / 2, np.sum((p[i] - p[j]) ** 2) / 4
            others = np.delete(p, [i, j], axis=0)
            if not np.any(np.sum((others - mid) ** 2, axis=1) < r2):
                out.append((i, j))
    return out


def dip_contrast(img: np.ndarray, a: tuple[int, int], b: tuple[int, int],
                 samples_per_pixel: int = 4) -> float:
    """1 - (minimum of the image along the segment a-b, bilinear) / min(img[a], img[b])."""
    n = max(2, int(math.ceil(math.dist(a, b) * samples_per_pixel)) + 1)
    rows, cols = np.linspace(a[0], b[0], n), np.linspace(a[1], b[1], n)
    line = map_coordinates(np.asarray(img, np.float64), [rows, cols], order=1)
    lower = min(float(img[a]), float(img[b]))
    return float(1.0 - line.min() / lower) if lower > 0 else 0.0


def chart_features(volume: np.ndarray, extents: dict, *,
                   contrast_min: float = CONTRAST_RESOLVED) -> dict:
    """Which features of a reconstructed planar chart are resolved.

    The chart image is the max over +-CHART_SLAB_M of depth around the chart plane (the
    depth of the volume's brightest slice). Its spots are the local maxima of at least
    PEAK_FLOOR of its maximum; each neighbouring pair (:func:`neighbour_pairs`) is a
    feature ``"pair (x1, y1)-(x2, y2)"`` with its spacing (m), its ``contrast``
    (:func:`dip_contrast`) and ``resolved`` = contrast >= ``contrast_min``. Each spot is also
    reported with its FWHM along x and y (m): a spot much wider than the point response is
    a group whose members are not resolved. Returns ``{"chart_depth_m", "criterion",
    "spots": [...], "features": {name: {"resolved", "contrast", "spacing_m"}}, "arrays":
    {"image": the chart image [y, x] / max}}`` (``arrays`` is not JSON: pop it)."""
    e = extents
    v = np.asarray(volume, np.float64)
    dz, dx = e["voxel_depth_m"], e["voxel_lateral_m"]
    z0 = int(np.argmax(v.max(axis=(1, 2))))
    k = int(round(CHART_SLAB_M / dz))
    img = v[max(0, z0 - k):z0 + k + 1].max(axis=0)
    img = img / img.max() if img.max() > 0 else img
    ny, nx = img.shape
    xs = e["x_min_m"] + (np.arange(nx) + 0.5) * dx
    ys = e["y_min_m"] + (np.arange(ny) + 0.5) * (e["y_max_m"] - e["y_min_m"]) / ny
    peaks = image_maxima(img)
    spots = [{"x_m": float(xs[c]), "y_m": float(ys[r]), "value": float(img[r, c]),
              "fwhm_x_m": fwhm_1d(img[r, :], dx, c), "fwhm_y_m": fwhm_1d(img[:, c], dx, r)}
             for r, c in peaks]
    features = {}
    for i, j in neighbour_pairs(peaks):
        (ra, ca), (rb, cb) = peaks[i], peaks[j]
        c = dip_contrast(img, peaks[i], peaks[j])
        name = (f"pair ({xs[ca]:+.2f}, {ys[ra]:+.2f})-({xs[cb]:+.2f}, {ys[rb]:+.2f}) m")
        features[name] = {"resolved": bool(c >= contrast_min), "contrast": c,
                          "spacing_m": float(math.hypot(xs[ca] - xs[cb], ys[ra] - ys[rb])),
                          "ends_m": [[float(xs[ca]), float(ys[ra])],
                                     [float(xs[cb]), float(ys[rb])]]}
    return {"chart_depth_m": (z0 + 0.5) * dz, "arrays": {"image": img.astype(np.float32)},
            "criterion": f"dip between neighbouring maxima >= {contrast_min:.0%} of the lower",
            "spots": spots, "features": features}


def json_ready(result: dict) -> dict:
    """A copy of a :func:`measure_resolution` / :func:`chart_features` result without its
    arrays (``profiles``, ``arrays``): what results.json holds."""
    if isinstance(result, dict):
        return {k: json_ready(v) for k, v in result.items() if k not in ("profiles", "arrays")}
    if isinstance(result, list):
        return [json_ready(v) for v in result]
    return result


def resolution_figure(result: dict, title: str = ""):
    """The profiles through the patch's peak (matplotlib Figure): lateral (x, m, centred on
    the peak) and axial (z, m) for every method, noise-free and at the budget, each with its
    FWHM in the legend and the lateral bound drawn as a bar at half maximum."""
    cases = [("noise-free", result)] + ([("budget", result["budget"])]
                                        if "budget" in result else [])
    fig, ax = new_figure(len(cases), 2, (12, 4 * len(cases)))
    ax = np.atleast_2d(ax)
    methods = [m for m in method_names() if m in result]
    for row, (label, case) in enumerate(cases):
        for m in methods:
            r = case[m]
            dz, dx = r["voxel_m"]
            z0, _, x0 = r["peak_index"]
            px, pz = np.asarray(r["profiles"]["x"]), np.asarray(r["profiles"]["z"])
            lat, axl = r["lateral_fwhm_m"], r["axial_fwhm_m"]
            ax[row, 0].plot((np.arange(px.size) - x0) * dx, px, "o-", ms=3,
                            label=f"{m}: FWHM {lat * 100:.1f} cm" if lat else f"{m}: > scan")
            ax[row, 1].plot((np.arange(pz.size) + 0.5) * dz, pz, "-",
                            label=f"{m}: FWHM {axl * 100:.2f} cm" if axl else f"{m}: -")
        b = case.get("bound_lateral_m")
        if b:
            ax[row, 0].plot([-b / 2, b / 2], [0.5, 0.5], "k-", lw=3,
                            label=f"O'Toole bound {b * 100:.1f} cm")
        gamma = case.get("effective_temporal_fwhm_s")
        g = f", gamma = {gamma * 1e12:.0f} ps" if gamma else ""
        ax[row, 0].set(xlabel="x - x_peak (m)", ylabel="value / peak",
                       title=f"{label}: lateral profile through the peak{g}")
        ax[row, 1].set(xlabel="depth z (m)", ylabel="value / peak",
                       title=f"{label}: axial profile through the peak")
        ax[row, 1].set_xlim(r["peak_depth_m"] - 0.15, r["peak_depth_m"] + 0.15)
        for a in ax[row]:
            a.legend(fontsize=8)
    if title:
        fig.suptitle(title)
    return fig


def chart_figure(result: dict, title: str = ""):
    """The chart image (x, y in m, colour bar) with its spots marked and each neighbouring
    pair joined: solid green where resolved, dashed red where not, labelled with its dip
    contrast (matplotlib Figure)."""
    e = result["arrays"]["extents"]
    fig, ax = new_figure(1, 1, (7, 6))
    im = ax.imshow(result["arrays"]["image"], origin="lower", cmap="gray",
                   extent=(e["x_min_m"], e["x_max_m"], e["y_min_m"], e["y_max_m"]))
    fig.colorbar(im, ax=ax, label="value / max")
    spots = result["spots"]
    ax.plot([s["x_m"] for s in spots], [s["y_m"] for s in spots], "c+", ms=12)
    for f in result["features"].values():
        (x1, y1), (x2, y2) = f["ends_m"]
        ax.plot([x1, x2], [y1, y2], "g-" if f["resolved"] else "r--", lw=1.5)
        ax.annotate(f"{f['contrast']:.2f}", ((x1 + x2) / 2, (y1 + y2) / 2), color="yellow",
                    fontsize=8, ha="center")
    ax.set(xlabel="x (m)", ylabel="y (m)",
           title=title or f"chart at {result['chart_depth_m']:.2f} m: {result['criterion']}")
    return fig
