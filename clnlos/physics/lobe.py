"""A voxel's reflectance lobe in the confocal light cone, as separable terms (pure numpy).

The light-cone transport (:mod:`clnlos.forward.transport`) sends a Lambertian voxel of
albedo-weighted coverage rho at depth z to the scan point at lateral offset d with

    w_L(d, z) = rho p^2 z^4 / (pi r^8),   r^2 = z^2 + |d|^2              (1/(m^2 sr))

(p the pitch; both cosines z / r). A voxel of BRDF f facing the scan plane sends
rho f(theta) z^4 / r^8 over its cell, theta the angle between its normal and the direction
to the scan point (the retro slice f(w, w) of the BRDF: the confocal scan sees only it).
Relative to the Lambertian weight,

    G(d, z) = pi < f_eff(theta(x)) z^4 / r(x)^8 >_cell / < z^4 / r(x)^8 >_cell     (1)

the lobe averaged over the voxel's cell (x over the cell at offset d; a lobe narrower than
the cell's angle p / z is integrated, not sampled at the centre), with f_eff the retro slice
seen through the slab: a slab diffuses the laser spot and the detector's view over a
footprint of rms radius s_fp on its hidden face, and a surface point reflects from an
entry point q1 to an exit point q2 of the footprint at its half vector, whose direction
deviates from the scan point's by the midpoint (q1 + q2) / 2: a 2D Gaussian of rms
angle sigma = s_fp / (sqrt(2) z). f_eff is f averaged over it (tangent plane, small
angles):

    f_eff(theta) = int f(theta') K_sigma(theta, theta') dtheta',
    K_sigma = theta' / s^2 exp(-(theta - theta')^2 / (2 s^2)) i0e(theta theta' / s^2),
    s = sigma / sqrt(2) per axis                                                     (2)

(i0e the scaled modified Bessel function: the azimuthal average of the Gaussian).
For a Lambertian f, G = 1.

A retroreflector (:mod:`clnlos.physics.retroreflector`) returns a cone that the scanned
spot collects in part: its f_eff depends on r as well as theta, f_eff(theta, r) = f(theta) +
f0(theta) S(c / r^2) (that module's Eq. 3: f its diffuse floor, f0 the cone's peak slice,
c its spot constant), and (1) averages it over the cell with r = r(x). Where the spot holds
the whole cone (S ~ r^2 / c) G grows as r^2: the voxel's falloff is 1/r^2, not 1/r^4.

G is not shift-invariant in z (the lobe is a function of |d| / z), so it does not fit the
light cone's convolution in (v, y, x) as one kernel; its K leading singular terms do,

    G(d, z) ~ sum_k a_k(z) b_k(d)                                                   (3)

each a light-cone convolution with a volume weight a_k and a lateral kernel weight b_k
(:func:`separable_terms`: the SVD of G weighted by the Lambertian response's importance
(z / r)^8, made separable as its best rank-one factor, so the truncation error is small where
the light cone carries light). K is the smallest rank whose weighted relative error is under
a tolerance; a Lambertian lobe needs K = 1 (exactly today's operator).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.sparse.linalg import ArpackError, ArpackNoConvergence, svds
from scipy.special import i0e

from clnlos.errors import ParameterError
from clnlos.physics.retroreflector import spot_factor

THETA_NODES = 4097        # retro slice samples over [0, pi/2] (0.022 deg apart)
LOBE_TOLERANCE = 1e-3     # weighted relative error of the separable terms (3)
# ... for a retroreflector's lobe: its entrance profile ends at the acceptance angle with a
# kink, which (3) converges to slowly (12 terms for 0.6%; 4 terms for 1%, docs/brdf.md)
RETRO_LOBE_TOLERANCE = 1e-2
# ... and for the iterative inversion's reconstructions ("auto" brdf_terms, at least the
# lobe's own): the terms past it change the reconstructions measured by less than half the
# photons do (docs/brdf.md, "Cost and reading against K"); the operator's default stays
# LOBE_TOLERANCE (its checks against the renderer, the lobe search's scores)
INVERSION_LOBE_TOLERANCE = 0.1
# ... and for the candidates the lobe search of brdf "auto" scores (clnlos.inverse.brdf_choice):
# between the two, their scores compare models, and with the inversion's one retroreflective
# term that lobe won a white plate's held-out score
SEARCH_LOBE_TOLERANCE = 0.03
MAX_TERMS = 12            # terms of (3) at most
CELL_SAMPLES_PER_WIDTH = 3.0  # sub-samples of a cell per lobe width (1): the lobe resolved
MAX_CELL_SAMPLES = 24     # per axis
NEAR_WIDTHS = 6.0         # cells within this many lobe widths are sub-sampled


@dataclass(frozen=True)
class RetroLobe:
    """A retro slice f(theta) (1/sr) on THETA_NODES angles uniform over [0, pi/2]; ``name``
    says where it came from (a preset, a texture file, "lambertian")."""

    f: np.ndarray
    name: str
    # a retroreflector's cone: its peak slice f0(theta) on the same angles (1/sr) and its
    # spot constant c (m^2) (module docstring); None and 0 for every other lobe
    cone: np.ndarray | None = None
    spot_constant_m2: float = 0.0
    # the weighted relative error of its separable terms (3) that "auto" terms stop at
    tolerance: float = LOBE_TOLERANCE

    def __post_init__(self) -> None:
        self.f.setflags(write=False)  # shared: lobes are built once per process
        if self.cone is not None:
            self.cone.setflags(write=False)

    @classmethod
    def retroreflector(cls, retro, name: str) -> RetroLobe:
        """The lobe of a :class:`clnlos.physics.retroreflector.Retroreflector`: its diffuse
        floor as f, its cone and spot constant beside it."""
        th = np.linspace(0.0, np.pi / 2, THETA_NODES)
        return cls(retro.diffuse_slice(th), name, retro.cone_slice(th),
                   float(retro.spot_constant_m2), RETRO_LOBE_TOLERANCE)

    def effective(self, theta, r2) -> np.ndarray:
        """f_eff(theta, r) (1/sr) at angles ``theta`` (rad) and squared distances ``r2``
        (m^2) from the scan point, from the slice ``f`` given on :attr:`theta` (for a
        retroreflector, ``f`` plus its cone times S; else ``f``)."""
        out = np.interp(theta, self.theta, self.f)
        if self.cone is not None:
            out = out + np.interp(theta, self.theta, self.cone) * spot_factor(
                self.spot_constant_m2 / np.maximum(r2, 1e-300))
        return out

    @property
    def theta(self) -> np.ndarray:
        return np.linspace(0.0, np.pi / 2, self.f.size)

    @property
    def lambertian(self) -> bool:
        return self.cone is None and bool(np.allclose(self.f, 1.0 / np.pi, rtol=1e-9,
                                                      atol=0.0))

    @property
    def flat(self) -> bool:
        """The same at every angle and distance: a Lambertian lobe of another albedo (G
        constant)."""
        return self.cone is None and bool(np.allclose(self.f, self.f[0], rtol=1e-9, atol=0.0))

    @classmethod
    def from_samples(cls, f, name: str) -> RetroLobe:
        """From a retro slice sampled uniformly over [0, pi/2] at any resolution (linear
        interpolation onto THETA_NODES)."""
        f = np.asarray(f, np.float64)
        if f.ndim != 1 or f.size < 2 or not np.all(np.isfinite(f)) or np.any(f < 0):
            raise ParameterError("brdf", name, "a retro slice of >= 2 finite values >= 0")
        if not f.max() > 0:
            raise ParameterError("brdf", name, "a retro slice that reflects some light")
        x = np.linspace(0.0, 1.0, THETA_NODES)
        return cls(np.interp(x, np.linspace(0.0, 1.0, f.size), f), name)

    @classmethod
    def lambert(cls) -> RetroLobe:
        return cls(np.full(THETA_NODES, 1.0 / np.pi), "lambertian")

    def halfwidth_rad(self) -> float:
        """Half width at half maximum of the lobe above its floor (its minimum), rad; pi/2
        for a flat slice."""
        f = self.f
        hi, lo = float(f.max()), float(f.min())
        if not hi > 1.0001 * lo:
            return math.pi / 2
        k0 = int(np.argmax(f))
        below = np.nonzero(f[k0:] <= 0.5 * (hi + lo))[0]
        return math.pi / 2 if below.size == 0 else float(self.theta[k0 + below[0]])



def footprint_average(f: np.ndarray, sigma_rad: float, extent_rad: float = np.pi / 2
                      ) -> np.ndarray:
    """Eq. (2) on the uniform [0, pi/2] grid of ``f``: the average of a radial function over
    a 2D Gaussian of rms angle ``sigma_rad`` (kernel cut at 7 s; computed at nodes s / 8
    apart and interpolated between them: the average is smooth on that scale), at angles up
    to ``extent_rad`` + 7 s (past a lobe's extent f is smooth on the scale of s and kept)."""
    f = np.asarray(f, np.float64)
    if not sigma_rad > 0:
        return f.copy()
    n = f.size
    th = np.linspace(0.0, np.pi / 2, n)
    h = th[1] - th[0]
    s = sigma_rad / math.sqrt(2.0)
    band = int(math.ceil(7.0 * s / h))
    stride = max(1, int(s / (8.0 * h)))
    last = min(n - 1, int(math.ceil((extent_rad + 7.0 * s) / h)))
    rows = np.unique(np.r_[np.arange(0, last, stride), last])
    j = rows[:, None] + np.arange(-band, band + 1)[None, :]
    ok = (j >= 0) & (j < n)
    jc = np.clip(j, 0, n - 1)
    ti, tj = th[rows][:, None], th[jc]
    kern = np.where(ok, tj * np.exp(-(ti - tj) ** 2 / (2 * s * s)) * i0e(ti * tj / (s * s)),
                    0.0)
    tot = kern.sum(axis=1)
    val = np.where(tot > 0, (kern * f[jc]).sum(axis=1) / np.where(tot > 0, tot, 1.0),
                   f[rows])
    out = f.copy()
    out[:last + 1] = np.interp(th[:last + 1], th[rows], val)
    return out


SPREAD_STEP = 1.1  # footprint averages on a geometric grid of spreads, interpolated between
LOBE_EXTENT_WIDTHS = 8.0  # a lobe varies out to this many half widths (GGX: 2e-4 of its peak)


def footprint_averages(lobe: RetroLobe, sigmas_rad) -> np.ndarray:
    """f_eff of (2) [len(sigmas), THETA_NODES] for each spread (rad; 0 = f itself), each
    interpolated in log spread between averages on a SPREAD_STEP grid."""
    sig = np.asarray(sigmas_rad, np.float64)
    out = np.empty((sig.size, lobe.f.size))
    pos = sig > 0
    out[~pos] = lobe.f
    if pos.any():
        lo, hi = float(sig[pos].min()), float(sig[pos].max())
        n = max(1, int(math.ceil(math.log(hi / lo) / math.log(SPREAD_STEP))) + 1)
        grid = lo * SPREAD_STEP ** np.arange(n)
        extent = min(np.pi / 2, LOBE_EXTENT_WIDTHS * lobe.halfwidth_rad())
        table = np.stack([footprint_average(lobe.f, g, extent) for g in grid])
        x = np.log(sig[pos] / lo) / math.log(SPREAD_STEP)
        i0 = np.clip(np.floor(x).astype(int), 0, max(n - 2, 0))
        w = np.clip(x - i0, 0.0, 1.0)[:, None]
        i1 = np.minimum(i0 + 1, n - 1)
        out[pos] = (1 - w) * table[i0] + w * table[i1]
    return out


def half_vector_spread_rad(footprint_rms_m: float, depth_m) -> np.ndarray:
    """rms angle of the half vector's deviation seen from ``depth_m`` (m) for a slab footprint
    of rms radius ``footprint_rms_m`` (m): the midpoint of two independent footprint points
    has rms radius s_fp / sqrt(2)."""
    return footprint_rms_m / (math.sqrt(2.0) * np.maximum(np.asarray(depth_m, float), 1e-9))


def cell_samples(pitch_m: float, depth_m: float, width_rad: float) -> int:
    """Sub-samples per axis of a cell of ``pitch_m`` at ``depth_m`` that resolve a lobe of
    half width ``width_rad``: CELL_SAMPLES_PER_WIDTH per width, 1 to MAX_CELL_SAMPLES."""
    cell = pitch_m / max(depth_m, 1e-9)
    return int(min(MAX_CELL_SAMPLES, max(1, math.ceil(CELL_SAMPLES_PER_WIDTH * cell
                                                         / max(width_rad, 1e-9)))))


def cell_average(theta, f, oy, ox, z: float, pitch_m: float, m: int, cone=None,
                 spot_constant_m2: float = 0.0) -> np.ndarray:
    """pi <f_eff(theta(x), r(x)) w(x)>_cell / <w(x)>_cell of (1), w = 1 / r^8, on m x m
    sub-samples of the cells centred at lateral offsets (oy, ox) (m) from the scan point at
    depth z (m); f_eff = f, plus a retroreflector's ``cone`` times S(c / r^2) where given
    (module docstring; f and cone on the angles ``theta``)."""
    u = ((np.arange(m) + 0.5) / m - 0.5) * pitch_m
    uy, ux = (a.ravel() for a in np.meshgrid(u, u, indexing="ij"))
    X = ox[:, None] + ux[None, :]
    Y = oy[:, None] + uy[None, :]
    rho2 = X * X + Y * Y
    w = 1.0 / (rho2 + z * z) ** 4
    th = np.arctan(np.sqrt(rho2) / z)
    lobe = np.interp(th, theta, f)
    if cone is not None:
        lobe = lobe + np.interp(th, theta, cone) * spot_factor(
            spot_constant_m2 / (rho2 + z * z))
    return np.pi * (lobe * w).sum(axis=1) / w.sum(axis=1)


def lobe_weight_table(lobe: RetroLobe, depths_m, pitch_m: float, n_offsets: tuple[int, int],
                      footprint_rms_m: float = 0.0) -> np.ndarray:
    """G of (1) [nz, ny_off, nx_off] (dimensionless) for a voxel facing the scan plane at each
    depth and each lateral offset (|dy|, |dx|) = 0 .. n_offsets - 1 cells; the slab's
    footprint (rms radius ``footprint_rms_m``, 0 = none) folded in by (2). 1 everywhere for
    a Lambertian lobe."""
    z_all = np.asarray(depths_m, np.float64)
    ny, nx = (int(v) for v in n_offsets)
    if lobe.lambertian:
        return np.ones((z_all.size, ny, nx))
    th = lobe.theta
    oy, ox = np.meshgrid(np.arange(ny) * pitch_m, np.arange(nx) * pitch_m, indexing="ij")
    oy, ox = oy.ravel(), ox.ravel()
    base_width = lobe.halfwidth_rad()
    G = np.empty((z_all.size, oy.size))
    sigmas = half_vector_spread_rad(footprint_rms_m, z_all) if footprint_rms_m > 0 else \
        np.zeros(z_all.size)
    f_eff = footprint_averages(lobe, sigmas)
    for k, z in enumerate(z_all):
        if not z > 0:
            G[k] = 0.0
            continue
        sig, f = float(sigmas[k]), f_eff[k]
        width = math.hypot(base_width, sig)
        # cells that reach into the lobe are sub-sampled, the rest sampled at the centre
        near = np.hypot(np.maximum(oy - pitch_m, 0), np.maximum(ox - pitch_m, 0)) \
            <= z * math.tan(min(NEAR_WIDTHS * width, 1.5))
        at = RetroLobe(f, lobe.name, lobe.cone, lobe.spot_constant_m2)
        G[k] = np.pi * at.effective(np.arctan(np.hypot(oy, ox) / z), oy * oy + ox * ox + z * z)
        m = cell_samples(pitch_m, z, width)
        if m > 1 and near.any():
            G[k, near] = cell_average(th, f, oy[near], ox[near], z, pitch_m, m, lobe.cone,
                                      lobe.spot_constant_m2)
    return G.reshape(z_all.size, ny, nx)


@dataclass(frozen=True)
class SeparableLobe:
    """Eq. (3): G[z, |dy|, |dx|] ~ sum_k a[k, z] b[k, |dy|, |dx|]; ``errors[K - 1]`` the
    weighted relative error with K terms (for every K up to MAX_TERMS)."""

    a: np.ndarray
    b: np.ndarray
    errors: tuple[float, ...]
    name: str

    @property
    def terms(self) -> int:
        return self.a.shape[0]


def leading_svd(A: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(U [m, k'], S [k'], Vt [k', n]): the k' = min(k, min(m, n)) leading singular triplets
    of A, largest first. A truncated Lanczos SVD (ARPACK, from a fixed start vector) where k
    is well below the smaller side (its cost is a few dozen products with A, where the full
    SVD of a 1024 x 1089 table took 0.5 s), the full SVD otherwise and where ARPACK fails
    (a table of zeros leaves it no Krylov space)."""
    m, n = A.shape
    if k < min(m, n) - 1:
        try:
            U, S, Vt = svds(A, k=k, v0=np.ones(min(m, n)), solver="arpack")
        except (ArpackError, ArpackNoConvergence):  # e.g. a table of zeros: no Krylov space
            pass
        else:
            order = np.argsort(S)[::-1]
            return U[:, order], S[order], Vt[order]
    U, S, Vt = np.linalg.svd(A, full_matrices=False)
    k = min(k, S.size)
    return U[:, :k], S[:k], Vt[:k]


def separable_terms(G: np.ndarray, depths_m, pitch_m: float, *, name: str = "",
                    tolerance: float = LOBE_TOLERANCE, terms: int | None = None,
                    depth_extent=None) -> SeparableLobe:
    """The fewest terms of (3) whose error on G is under ``tolerance`` (or exactly ``terms``),
    error weighted by the Lambertian response's importance (z / r)^8 through its best
    separable (rank-one) factor w1(z) w2(d): the SVD of w1 G w2, divided back. Each row
    (depth) counts in the error by its ``depth_extent`` (the depth its bin spans, any unit;
    default 1 each: equal depth bins), so rows sampled unevenly in depth (the light cone's
    u = z^2 grid) weigh as the depths they stand for."""
    nz, ny, nx = G.shape
    z = np.maximum(np.asarray(depths_m, np.float64), 1e-9)
    d2 = ((np.arange(ny)[:, None] * pitch_m) ** 2 + (np.arange(nx)[None, :] * pitch_m) ** 2)
    W = (z[:, None] ** 2 / (z[:, None] ** 2 + d2.ravel()[None, :])) ** 4
    if depth_extent is not None:
        W = W * np.sqrt(np.asarray(depth_extent, np.float64))[:, None]
    uw, sw, vw = leading_svd(W, 1)
    w1 = np.abs(uw[:, 0]) * math.sqrt(sw[0]) + 1e-300
    w2 = np.abs(vw[0]) * math.sqrt(sw[0]) + 1e-300
    A = G.reshape(nz, -1) * w1[:, None] * w2[None, :]
    U, S, Vt = leading_svd(A, MAX_TERMS)
    ref = np.linalg.norm(G.reshape(nz, -1) * W)
    kmax = S.size
    errors = []
    Gk = np.zeros_like(A)  # sum of the first k terms, in the weighted space
    back = W / (w1[:, None] * w2[None, :])  # from that space to the error's weight W
    for k in range(kmax):
        Gk += np.outer(U[:, k] * S[k], Vt[k])
        errors.append(float(np.linalg.norm((Gk - A) * back) / ref) if ref > 0 else 0.0)
    if terms is None:
        ok = [k for k, e in enumerate(errors, 1) if e <= tolerance]
        terms = ok[0] if ok else kmax
    terms = int(min(max(terms, 1), kmax))
    a = (U[:, :terms] * S[:terms]).T / w1[None, :]
    b = (Vt[:terms] / w2[None, :]).reshape(terms, ny, nx)
    # sign: each term's lateral weight positive at the centre (cosmetic, exact either way)
    sgn = np.where(b[:, 0, 0] < 0, -1.0, 1.0)
    return SeparableLobe(a * sgn[:, None], b * sgn[:, None, None], tuple(errors), name)
