"""Float64 numpy reference of Eq. 8 for point scatterers (independent of the confocal model).

tau(r0, t) = sum_{r1, r2} Phi(r1 - r0) (x)_t Phi(r2 - r0) (x)_t I(r1, r2, t) with, for one
Lambertian point x of weight a (albedo / pi times its area),

    I(r1, r2, t) = a w(r1) w(r2) delta(t - (|x - r1| + |x - r2|) / c0),
    w(r) = cos(th_r) cos(th_x) / |x - r|^2          (face and target normal along +z)

The pair weight and delay separate into r1 and r2 factors, so per point
tau = a L(r0) (x)_t L(r0) with the one-leg transient L(r0, t) = sum_r Phi(r - r0, t) (x)_t
w(r) delta(t - |x - r| / c0): no far-field approximation (r1, r2 independent, the exact
bistatic path). The face is sampled on a fine grid (pitch ``face_pitch_m``); Phi is the
float64 slab PSF per face cell (``clnlos.diffusion.diffusion_psf``, physical units), the
delays are deposited into the 2 nearest bins (linear split).
"""

import numpy as np
from scipy.signal import fftconvolve

C0 = 299_792_458.0


def face_grid(n: int, pitch_m: float) -> np.ndarray:
    """Cell centres of an n-cell axis centred on 0 (m)."""
    return (np.arange(n) - (n - 1) / 2) * pitch_m


def _deposit(delay_bins: np.ndarray, weight: np.ndarray, nt: int) -> np.ndarray:
    """[t, y, x] deltas of ``weight`` at fractional bins ``delay_bins`` (linear split)."""
    out = np.zeros((nt,) + weight.shape)
    k = np.floor(delay_bins).astype(int)
    f = delay_bins - k
    jj, ii = np.indices(weight.shape)
    ok = k + 1 < nt
    np.add.at(out, (k[ok], jj[ok], ii[ok]), weight[ok] * (1 - f[ok]))
    np.add.at(out, (k[ok] + 1, jj[ok], ii[ok]), weight[ok] * f[ok])
    return out


def _leg(phi_c: np.ndarray, x: np.ndarray, fy: np.ndarray, fx: np.ndarray, nt: int,
         dt: float) -> np.ndarray:
    """L[t, y, x] on the face grid: Phi (centred, odd size) convolved with the deposited
    one-leg deltas of the point ``x``."""
    dy, dx = fy[:, None] - x[1], fx[None, :] - x[0]
    r = np.sqrt(dx * dx + dy * dy + x[2] ** 2)
    w = (x[2] / r) ** 2 / r**2
    q = _deposit(r / C0 / dt, w, nt)
    full = fftconvolve(q, phi_c, mode="full", axes=(0, 1, 2))
    cy, cx = phi_c.shape[1] // 2, phi_c.shape[2] // 2
    return full[:nt, cy:cy + fy.size, cx:cx + fx.size]


def eq8_capture(points, weights, *, phi_centred: np.ndarray, face_n: int,
                face_pitch_m: float, nt: int, bin_width_s: float) -> np.ndarray:
    """tau[t, y, x] of Eq. 8 on the face grid (scan points = face cells), float64.

    ``points`` (k, 3): scatterer positions (x, y, z) in m, z > 0 behind the face;
    ``weights``: a per point; ``phi_centred``: Phi per face cell [lag, y, x] with zero
    offset at the centre of odd lateral sizes."""
    f = face_grid(face_n, face_pitch_m)
    tau = np.zeros((nt, face_n, face_n))
    for x, a in zip(np.asarray(points, float), weights, strict=True):
        leg = _leg(phi_centred, x, f, f, nt, bin_width_s)
        tau += a * fftconvolve(leg, leg, mode="full", axes=0)[:nt]
    return tau


def confocal_transient(points, weights, *, face_n: int, face_pitch_m: float, nt: int,
                       bin_width_s: float) -> np.ndarray:
    """I_c[t, y, x]: the hidden-face confocal transient (r1 = r2 = m) on the face grid."""
    f = face_grid(face_n, face_pitch_m)
    out = np.zeros((nt, face_n, face_n))
    for x, a in zip(np.asarray(points, float), weights, strict=True):
        dy, dx = f[:, None] - x[1], f[None, :] - x[0]
        r = np.sqrt(dx * dx + dy * dy + x[2] ** 2)
        w = (x[2] / r) ** 2 / r**2
        out += a * _deposit(2 * r / C0 / bin_width_s, w * w, nt)
    return out


def centred(psf_wrap: np.ndarray, half: int) -> np.ndarray:
    """[lag, 2 half + 1, 2 half + 1] centred copy of a wrap-order lateral PSF."""
    idx = np.arange(-half, half + 1)
    return psf_wrap[:, idx[:, None] % psf_wrap.shape[1], idx[None, :] % psf_wrap.shape[2]]


def pair_sum_transient(x, r0, *, phi_centred: np.ndarray, pitch_m: float, bin_width_s: float,
                       hidden: str = "exact") -> np.ndarray:
    """tau(r0, t) of one Lambertian point ``x`` (weight 1) by the brute-force sum over all
    face pairs (r1, r2) within Phi's window around ``r0`` (no face border), float64:

    ``hidden="exact"``: I(r1, r2) of Eq. 8 (w(r1) w(r2), delay |x - r1| + |x - r2|);
    ``"midpoint"``: I_c((r1 + r2) / 2) (the far-target approximation);
    ``"cdt"``: I_c(r1 + r2 - r0) (what CDT's Phi * Phi assumes).
    Delays deposited by the linear 2-bin split (its exact DFT), lags 0..nt-1."""
    nt, ny, nx = phi_centred.shape
    hy, hx = ny // 2, nx // 2
    nf = 2 * nt
    spec = np.fft.rfft(phi_centred.reshape(nt, -1), n=nf, axis=0)
    om = 2 * np.pi * np.arange(spec.shape[0]) / nf
    oy, ox = np.meshgrid(np.arange(-hy, hy + 1) * pitch_m, np.arange(-hx, hx + 1) * pitch_m,
                         indexing="ij")
    y1, x1 = (r0[0] + oy.ravel())[:, None], (r0[1] + ox.ravel())[:, None]
    y2, x2 = y1.T, x1.T

    def leg(ry, rx):
        r = np.sqrt((rx - x[0]) ** 2 + (ry - x[1]) ** 2 + x[2] ** 2)
        return (x[2] / r) ** 2 / r ** 2, r

    if hidden == "exact":
        (w1, d1), (w2, d2) = leg(y1, x1), leg(y2, x2)
        weight, path = w1 * w2, d1 + d2
    else:
        my, mx = ((y1 + y2) / 2, (x1 + x2) / 2) if hidden == "midpoint" else \
            (y1 + y2 - r0[0], x1 + x2 - r0[1])
        wm, dm = leg(my, mx)
        weight, path = wm * wm, 2 * dm
    delay = (path / C0 / bin_width_s).ravel()
    k = np.floor(delay)
    f = delay - k
    dep = weight.ravel() * np.exp(-1j * om[:, None] * k) * ((1 - f) + f * np.exp(-1j * om[:, None]))
    pairs = (spec[:, :, None] * spec[:, None, :]).reshape(spec.shape[0], -1)
    return np.fft.irfft((pairs * dep).sum(axis=1), n=nf)[:nt]
