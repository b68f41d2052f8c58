"""Bistatic BRDF transport through the slab: the seed's Eq. 8 in full (``kernels/bistatic.cl``).

    tau(r0, t) = sum_{r1, r2} Phi(r1 - r0) (x)_t Phi(r2 - r0) (x)_t I(r1, r2, t)
    I(r1, r2, t) = sum_x a f(x; w1, w2) cos(th_r1) cos(th_x1) cos(th_x2) cos(th_r2)
                   / (|x - r1|^2 |x - r2|^2) dA  delta(t - (|x - r1| + |x - r2|) / c)

Phi is the slab transmittance of the confocal model (:mod:`clnlos.diffusion`, physical
units: probability per face area and bin), f the full BRDF from the tabulated texture
(:mod:`clnlos.brdf.texture`, the grid every model exports), a the albedo. Units of I and tau:
1/(m^2 sr) per bin, as the confocal model (at r1 = r2 the term is its light-cone term).

Face quadrature (:class:`FaceQuadrature`): the face around each scan point r0 is cut into
``rings`` annuli of equal slab energy (quantiles of the window-integrated lateral mass of
Phi), each sampled at ``angles`` points at the annulus' rms radius (alternate rings rotated
by half a step). Each sample carries the exact mass of its share of the annulus at every
lag (the Gaussian lateral factor of T(rho, t) integrates in closed form over an annulus),
so the sum over the face is exact for an integrand constant over each annulus and, for the
window-integrated weighting, for one quadratic in the offset; its error is measured against
refined quadratures in ``clnlos bench`` (rows ``bistatic``) and against a float64 regular
grid in tests/test_bistatic.py. Samples of one ring share one time series, so the pairs of
rings (i <= j: rings (rings + 1) / 2 "classes") share one slab kernel m_i (x) m_j.

Cost: stage 1 (``bistatic_pairs``) evaluates (rings x angles)^2 face pairs per element and
scan point -- scan points x elements x (rings angles)^2 BRDF lookups (two for pairs of
different rings); stage 2 (``bistatic_convolve``) costs scan points x classes x bins x
min(bins, kernel lags) multiply-adds. The confocal light cone costs scan points x elements
(plus one FFT blur), so the bistatic stage is about (rings angles)^2 times dearer: 1024x at
the defaults (4 x 8 samples). Measured (PoCL, 2 shared CPU cores; 6 cm patch of 144
elements, 32 x 32 x 512 at 16 ps): confocal light cone + blur 0.16 s, bistatic 2 x 4
samples 3.4 s, 4 x 8 samples 31 s (16x the pairs, 9x the time: stage 2 is the same).
Memory: the class histograms, slices x scan points x classes x bins, processed in chunks
of scan points of at most HIST_BYTES.

Left out: occlusion, interreflections, the slab's own reflection; a retro-slice-only
material (``brdf_retro_csv``) has no bistatic BRDF and is refused.
"""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from clnlos.brdf.catalog import is_retroreflective
from clnlos.brdf.models import make_model
from clnlos.brdf.presets import ANALYTIC_PRESETS, preset_model, preset_table
from clnlos.brdf.texture import checked_texture, read_texture, tabulate
from clnlos.checks import integer
from clnlos.diffusion import SlabTransmittance, bin_time_nodes, support_of
from clnlos.errors import ParameterError
from clnlos.forward.sampling import material_retro
from clnlos.forward.scene import (  # noqa: F401 (the [transport] table: defaults and limits live there)
    FACE_ANGLES,
    FACE_RINGS,
    MAX_FACE_ANGLES,
    MAX_FACE_RINGS,
    TEXTURE_DPHI,
    TEXTURE_THETA,
    TRANSPORT_MODELS,
    TransportSettings,
)
from clnlos.runtime.buffers import fill_zero, kernel_int, round_up, zeros
from clnlos.runtime.caches import CACHES
from clnlos.runtime.device import get_queue, group_size, has_fp64, require_dtype, require_memory
from clnlos.runtime.programs import get_kernels, real_defines

HIST_BYTES = 64 << 20  # class histograms per chunk of scan points
MAX_SLICES = 16       # element slices per scan point on GPUs (more work-items)
# elements one work-item of stage 1 takes at most: on Mesa's rusticl (llvmpipe) work-items
# that loop over many elements lost light (a 1 m plate of 20,000 elements in one: 23x too
# little, its peak 0.29 m late; 4,000: 3.7% too little; 1,000: as on PoCL)
ELEMENTS_PER_ITEM = 2048
# "auto": bistatic where the lobe (half width at half maximum in the outgoing direction)
# is narrower than AUTO_FACTOR x the angular spread of the slab's footprint seen from the
# target (rms angle between w1 and w2). See :func:`auto_choice`. Calibrated on the ten
# presets at the study geometry (tools/results/confocal_error.csv, spread 4.08 deg at
# 0.5 m): the confocal model is off by more than 5% (relative L2) for lobes up to 14.1 deg
# (fuchsia lacquer, 6.3%) and by 3.5% at 21.1 deg (black anode), against a 0.9% floor for
# diffuse materials; 4 x 4.08 = 16.3 deg separates them.
AUTO_FACTOR = 4.0
LOBE_CONTRAST = 2.0   # a retro slice whose peak is under this x its floor has no lobe


# ------------------------------------------------------------------ face quadrature
@dataclass
class FaceQuadrature:
    """Face samples around a scan point and their slab time series (float64).

    ``offsets`` [rings * angles, 2] (m, ring-major); ``edges`` [rings + 1] annulus radii
    (m, last inf); ``radius`` [rings] sample radii; ``mass`` [rings, lags] per-sample
    probability per lag bin (lag k = bin centred on k dt, :func:`~clnlos.diffusion.
    bin_time_nodes`); ``classes`` [n_cls, 2] ring pairs i <= j; ``kernels`` [n_cls, n_lag]
    m_i (x) m_j cut at the window; ``rms_m`` the rms radius of the window-integrated Phi."""

    offsets: np.ndarray
    edges: np.ndarray
    radius: np.ndarray
    mass: np.ndarray
    classes: np.ndarray
    kernels: np.ndarray
    rms_m: float
    angles: int


def node_weights(slab, bins: int, bin_width_s: float, n_dipoles, queue):
    """(base [lag, node] = dt w_j T(0, t) pi a, a = 4 D v t [lag, node]) over the window's
    lags; dead nodes (t <= 0, T = 0) have base 0."""
    q = get_queue(queue)
    dt = np.float64 if has_fp64(q.device) else np.float32
    t, w = bin_time_nodes(bins, bin_width_s, 4)
    log_t0 = SlabTransmittance(slab, n_dipoles=n_dipoles, dtype=dt, queue=q).log_series(t)
    alive = np.isfinite(log_t0) & (t > 0)
    a = 4.0 * slab.D * slab.v * np.where(alive, t, 1.0)
    base = np.where(alive, bin_width_s * w[None, :] * np.exp(np.where(alive, log_t0, 0.0))
                    * np.pi * a, 0.0)
    return base, a


def _ring_mass(base, a, r_in: float, r_out: float) -> np.ndarray:
    """Probability per lag of leaving the face in the annulus [r_in, r_out) (sum over nodes)."""
    e_in = np.exp(-r_in * r_in / a)
    e_out = np.zeros_like(a) if math.isinf(r_out) else np.exp(-r_out * r_out / a)
    return (base * (e_in - e_out)).sum(axis=1)


def _ring_moment(base, a, r_in: float, r_out: float) -> float:
    """Window-integrated second moment sum_lags integral rho^2 dM over the annulus (m^2)."""
    e_in = np.exp(-r_in * r_in / a)
    tail = 0.0 if math.isinf(r_out) else (r_out * r_out + a) * np.exp(-r_out * r_out / a)
    return float((base * ((r_in * r_in + a) * e_in - tail)).sum())


def face_quadrature(slab, *, bins: int, bin_width_s: float, rings: int = FACE_RINGS,
                    angles: int = FACE_ANGLES, n_dipoles=None, queue=None) -> FaceQuadrature:
    """The face quadrature of the module docstring for a window of ``bins`` bins."""
    base, a = node_weights(slab, bins, bin_width_s, n_dipoles, queue)
    per_lag = base.sum(axis=1)
    lags = max(1, support_of(per_lag))
    base, a = base[:lags], a[:lags]
    total = float(base.sum())
    if not total > 0:
        raise ParameterError("slab", slab, "a slab that transmits light inside the time "
                             "window")
    # equal-mass annuli: M(R) = sum base (1 - exp(-R^2 / a)), monotone in R
    r_max = 10.0 * math.sqrt(float(a[base > 0].max()))
    grid = np.linspace(0.0, r_max, 4097)
    m_of = np.array([total - float((base * np.exp(-r * r / a)).sum()) for r in grid])
    edges = [0.0]
    for i in range(1, rings):
        edges.append(float(np.interp(i / rings * total, m_of, grid)))
    edges.append(math.inf)
    edges = np.asarray(edges)
    mass = np.empty((rings, lags))
    radius = np.empty(rings)
    for i in range(rings):
        m = _ring_mass(base, a, edges[i], edges[i + 1])
        mass[i] = m / angles
        radius[i] = math.sqrt(_ring_moment(base, a, edges[i], edges[i + 1]) / m.sum())
    phi = (np.arange(angles)[None, :] + 0.5 * (np.arange(rings)[:, None] % 2)) \
        * (2 * np.pi / angles)
    offsets = np.stack([radius[:, None] * np.cos(phi), radius[:, None] * np.sin(phi)],
                       axis=-1).reshape(-1, 2)
    classes = np.array([(i, j) for i in range(rings) for j in range(i, rings)], np.int32)
    n_lag = min(bins, 2 * lags - 1)
    kernels = np.stack([np.convolve(mass[i], mass[j])[:n_lag] for i, j in classes])
    rms = math.sqrt(_ring_moment(base, a, 0.0, math.inf) / total)
    return FaceQuadrature(offsets, edges, radius, mass, classes, kernels, rms, angles)


# ------------------------------------------------------------------ materials
def material_texture(obj, base_dir, n_theta: int, n_dphi: int) -> np.ndarray | None:
    """The object's BRDF texture [n_theta, n_theta, n_dphi] (1/sr, the grid of
    :func:`clnlos.brdf.texture.tabulate`), or None for Lambertian. A texture file is checked
    against its model (:func:`clnlos.brdf.texture.checked_texture`: one warning line where
    it was too coarse for its lobe and was tabulated again)."""
    if obj.brdf_retro_csv is not None:
        raise ParameterError("transport.model", "bistatic", "'confocal' for an object with "
                             f"brdf_retro_csv = {obj.brdf_retro_csv!r} (a confocal slice, no "
                             "bistatic BRDF)")
    if is_retroreflective(obj.material):
        raise ParameterError("transport.model", "bistatic", "'confocal' for a retroreflective "
                             "object (its return depends on the scanned spot it lands in: "
                             "the confocal light cone models it, clnlos.physics.retroreflector; "
                             "Eq. 8's bistatic paths have no spot)")
    tex, _, note = _material_texture(*_material_key(obj.material, base_dir), int(n_theta),
                                     int(n_dphi))
    if note:
        warnings.warn(note, UserWarning, stacklevel=2)
    return tex


def _material_key(m, base_dir) -> tuple[str, str]:
    """A hashable key of a material: its table as JSON, a texture file with its size and
    time (a file rewritten is read again), or its name."""
    if isinstance(m, dict):
        return "table", json.dumps(m, sort_keys=True)
    if str(m).endswith((".h5", ".hdf5")):
        path = Path(base_dir) / m
        st = path.stat() if path.is_file() else None
        return "file", json.dumps([str(path), st and st.st_size, st and st.st_mtime_ns])
    return "name", str(m).lower()


@lru_cache(maxsize=32)
def _material_texture(kind: str, key: str, n_theta: int, n_dphi: int
                      ) -> tuple[np.ndarray | None, str, str | None]:
    """(texture or None, the resolution it has, a note or None) of a material key
    (:func:`_material_key`); kept per process: tabulating a narrow lobe takes seconds."""
    grid = f"{n_theta}x{n_theta}x{n_dphi}"
    if kind == "table":
        return tabulate(make_model(json.loads(key)), n_theta, n_dphi, 2).texture, grid, None
    if kind == "file":
        path = json.loads(key)[0]
        return checked_texture(read_texture(path), path, n_theta, n_dphi)
    model = preset_model(key) if key in preset_table() else ANALYTIC_PRESETS.get(key)
    if model is None:
        return None, "lambertian", None
    return tabulate(model, n_theta, n_dphi, 2).texture, grid, None


CACHES.register("material textures", _material_texture.cache_clear)


def texture_label(scene, settings: TransportSettings) -> str:
    """The resolution of the textures the transport reads, per object where they differ
    ("16x16x16" for a texture file used as it is, the transport's grid for one tabulated
    from a model; "lambertian" without one)."""
    n, nd = settings.texture_theta, settings.texture_dphi
    labels = []
    for o in scene.objects:
        if o.brdf_retro_csv is None:
            labels.append(_material_texture(*_material_key(o.material, scene.base_dir), n,
                                            nd)[1])
    distinct = list(dict.fromkeys(labels))
    return distinct[0] if len(distinct) == 1 else "+".join(labels)


def scene_textures(scene, settings: TransportSettings) -> np.ndarray | None:
    """[objects, n_theta, n_theta, n_dphi] textures in object order (the material index of
    :func:`clnlos.forward.sampling.sample_scene`), or None when every object is Lambertian."""
    n, nd = settings.texture_theta, settings.texture_dphi
    texs = [material_texture(o, scene.base_dir, n, nd) for o in scene.objects]
    if all(t is None for t in texs):
        return None
    return np.stack([np.full((n, n, nd), 1 / np.pi) if t is None else t for t in texs])


# ------------------------------------------------------------------ the transport stage
class BistaticTransport:
    """Plan: Eq. 8 on one scan/time grid, slab, quadrature, texture stack, dtype and device.

    ``__call__(samples)`` returns tau [bins, points, points] on the device (slab included:
    no separate slab blur follows). ``textures`` None: Lambertian (f = 1/pi);
    ``texture_label``: the resolution the stage name gives them (:func:`texture_label`;
    default their shape)."""

    def __init__(self, *, slab, points: int, width_m: float, bins: int, bin_width_s: float,
                 start_s: float = 0.0, textures: np.ndarray | None = None,
                 rings: int = FACE_RINGS, angles: int = FACE_ANGLES, n_dipoles=None,
                 splat_order: int = 1, dtype=np.float32, queue=None,
                 texture_label: str | None = None):
        self.queue = get_queue(queue)
        self.dtype = require_dtype(self.queue.device, dtype)
        integer("transport.face_rings", rings, 1, MAX_FACE_RINGS)
        integer("transport.face_angles", angles, 1, MAX_FACE_ANGLES)
        self.points, self.width_m, self.bins = points, width_m, bins
        self.bin_width_s, self.start_s = bin_width_s, start_s
        self.shape = (bins, points, points)
        require_memory(self.queue.device, int(np.prod(self.shape)) * self.dtype.itemsize,
                       f"transient {self.shape}")
        self.quad = face_quadrature(slab, bins=bins, bin_width_s=bin_width_s, rings=rings,
                                    angles=angles, n_dipoles=n_dipoles, queue=self.queue)
        self.textures = textures
        defines = {**real_defines(self.dtype), "SPLAT_ORDER": int(splat_order),
                   "N_PHI": int(angles)}
        if textures is None:
            defines["LAMBERTIAN"] = True
        self._k = get_kernels(self.queue, "bistatic", defines)
        tex = texture_label or ("lambertian" if textures is None
                                else "x".join(str(s) for s in textures.shape[1:]))
        self.stage = f"lightcone:bistatic(rings={rings},angles={angles},texture={tex})"

    def _dev(self, a, dtype=None):
        return cla.to_device(self.queue, np.ascontiguousarray(a, dtype or self.dtype))

    def launch_plan(self, n_el: int) -> tuple[int, int, int]:
        """(local size of stage 1, element slices, scan points per chunk) from the device:
        on GPUs each scan point's elements are split into slices until there are about
        4 x compute units x local size work-items; on any device into at least enough
        slices that a work-item takes at most ELEMENTS_PER_ITEM elements; chunks keep the
        histograms under HIST_BYTES (and half the device's largest allocation)."""
        dev = self.queue.device
        lsz = group_size(self._k.bistatic_pairs, dev)
        n_cls, n_scan = len(self.quad.classes), self.points * self.points
        slices = 1
        if not dev.type & cl.device_type.CPU:
            want = 4 * dev.max_compute_units * lsz
            slices = int(np.clip(math.ceil(want / (n_cls * n_scan)), 1,
                                 min(MAX_SLICES, max(1, n_el // 64))))
        slices = max(slices, math.ceil(n_el / ELEMENTS_PER_ITEM))
        cap = min(HIST_BYTES, dev.max_mem_alloc_size // 2)
        per_point = slices * n_cls * self.bins * self.dtype.itemsize
        return lsz, slices, int(np.clip(cap // per_point, 1, n_scan))

    def __call__(self, samples) -> cla.Array:
        q, r = self.queue, self.dtype.type
        el = samples.elements
        out = zeros(q, self.shape, self.dtype)
        if len(el) == 0:
            return out
        tex = self.textures if self.textures is not None else np.zeros((1, 2, 2, 2))
        quad = self.quad
        n_cls, n_lag = quad.kernels.shape
        n_scan = self.points * self.points
        lsz, slices, chunk = self.launch_plan(len(el))
        pitch = self.width_m / self.points
        x0 = -self.width_m / 2 + pitch / 2
        mats = samples.material if self.textures is not None else np.zeros(len(el))
        bufs = [self._dev(el.pos), self._dev(el.normal), self._dev(el.area),
                self._dev(samples.albedo), self._dev(mats, np.int32), self._dev(tex)]
        face, cls_, kern = (self._dev(quad.offsets), self._dev(quad.classes, np.int32),
                            self._dev(quad.kernels))
        hist = cla.empty(q, (slices, chunk, n_cls, self.bins), self.dtype)
        for p0 in range(0, n_scan, chunk):
            n_p = min(chunk, n_scan - p0)
            fill_zero(q, hist)
            self._k.bistatic_pairs(
                q, (round_up(n_cls * n_p * slices, lsz),), (lsz,), *(b.data for b in bufs),
                *(kernel_int(s) for s in tex.shape[1:]), face.data, cls_.data,
                kernel_int(n_cls), kernel_int(len(el), "surface elements"), kernel_int(slices),
                kernel_int(self.points), r(x0), r(x0), r(pitch), kernel_int(p0),
                kernel_int(n_p), kernel_int(self.bins, "time bins"), r(self.start_s),
                r(self.bin_width_s), hist.data)
            self._k.bistatic_convolve(
                q, (round_up(self.bins, 8), round_up(n_p, 8)), None, hist.data, kern.data,
                kernel_int(n_cls), kernel_int(n_lag), kernel_int(slices), kernel_int(p0),
                kernel_int(n_p), kernel_int(n_scan), kernel_int(self.bins), out.data)
        return out


# ------------------------------------------------------------------ "auto"
def lobe_halfwidth_rad(retro: np.ndarray | None) -> float:
    """Half width at half maximum (rad) of a material's specular lobe in the outgoing
    direction: 2 theta_h, theta_h the first angle at which the retro slice f(theta, theta)
    (on [0, pi/2], theta = the half-vector angle there, which turns half as fast as the
    outgoing direction) falls to the middle between its peak and its floor. pi/2 (no lobe)
    for a Lambertian (None) or a slice whose peak is under LOBE_CONTRAST x its floor."""
    if retro is None:
        return math.pi / 2
    f = np.asarray(retro, float)
    lo, hi = float(f.min()), float(f.max())
    if not hi > LOBE_CONTRAST * max(lo, 0.0) or hi <= 0:
        return math.pi / 2
    th = np.linspace(0, np.pi / 2, len(f))
    half = 0.5 * (hi + lo)
    below = np.nonzero(f <= half)[0]
    below = below[below > int(np.argmax(f))]
    if not below.size:
        return math.pi / 2
    k = int(below[0])  # f[k - 1] > half >= f[k]: the crossing, interpolated linearly
    frac = (f[k - 1] - half) / (f[k - 1] - f[k])
    return float(min(math.pi / 2, 2 * (th[k - 1] + frac * (th[k] - th[k - 1]))))


def footprint_spread_rad(rms_m: float, depth_m: float) -> float:
    """rms angle between w1 and w2 seen from a target at ``depth_m``: r1 and r2 independent
    with rms radius ``rms_m`` each around the scan point, so |r1 - r2| has rms sqrt(2) rms."""
    return math.sqrt(2.0) * rms_m / max(depth_m, 1e-9)


def auto_choice(scene, samples, rms_m: float) -> tuple[str, str]:
    """("bistatic" or "confocal", the reason with its numbers) for ``model = "auto"``.

    Rule: bistatic when some object's lobe half width (:func:`lobe_halfwidth_rad`) is under
    AUTO_FACTOR x the footprint spread (:func:`footprint_spread_rad`) at the object's
    nearest element depth; confocal otherwise, and always without a slab. Numbers: the CDT
    slab's window-integrated footprint has an rms radius of 2.5 cm, a spread of 4.08 deg
    seen from 0.5 m, so bistatic for lobes under 16.3 deg there: quartz glass (0.75 deg),
    aluminium alloy (2.63), painted steel (3.49), gold-plated film (10.1), fuchsia lacquer
    (14.1), the analytic mirror-like (0.75), brushed metal (11.3) and glossy paint (12.3);
    confocal for black anode (21.1), the aluminium diffuse plate (34.7), glass fibre,
    standard white plate, cement board, matte-dark and Lambertian (no lobe)."""
    if scene.slab is None:
        return "confocal", "no slab"
    for i, obj in enumerate(scene.objects):
        if obj.brdf_retro_csv is not None:
            return "confocal", f"objects[{i}] has only a confocal slice (brdf_retro_csv)"
        if is_retroreflective(obj.material):
            return "confocal", f"objects[{i}] is retroreflective (confocal light cone only)"
    z_all = samples.elements.pos[:, 2]
    for i, obj in enumerate(scene.objects):
        retro = material_retro(obj, scene.base_dir)
        zs = z_all if samples.retro_tables is None else z_all[samples.material == i]
        zs = zs[zs > 0]
        if retro is None or zs.size == 0:
            continue
        lobe = lobe_halfwidth_rad(retro)
        spread = footprint_spread_rad(rms_m, float(zs.min()))
        if lobe < AUTO_FACTOR * spread:
            return "bistatic", (f"objects[{i}]: lobe half width {math.degrees(lobe):.2f} deg < "
                                f"{AUTO_FACTOR:g} x footprint spread "
                                f"{math.degrees(spread):.2f} deg")
    return "confocal", "every lobe is wider than the slab footprint's spread"










