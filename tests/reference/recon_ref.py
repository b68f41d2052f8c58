"""Float64 numpy/scipy reference of the reconstruction pipeline (independent of the kernels).

Resampling uses the integral form: a histogram's cumulative sum is piecewise linear, so the
content of any destination bin is the difference of the interpolated cumulative sum at its
edges (the package builds explicit overlap matrices instead).
"""

import numpy as np
from scipy.special import erf

from .diffusion_ref import params, slab_transmittance_ref

C0 = 299_792_458.0


def resample_cumsum(x, src_edges, dst_edges, weights=None):
    """Mass-conserving resampling of x[k, ...] from src to dst bins along axis 0."""
    x = np.asarray(x, np.float64)
    if weights is not None:
        x = x * np.asarray(weights)[:, None, None]
    cs = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0)])
    flat = cs.reshape(cs.shape[0], -1)
    out = np.empty((len(dst_edges), flat.shape[1]))
    for j in range(flat.shape[1]):
        out[:, j] = np.interp(dst_edges, src_edges, flat[:, j])
    return np.diff(out, axis=0).reshape((len(dst_edges) - 1,) + x.shape[1:])


def wrap_offsets(n, pitch):
    j = np.arange(n)
    return np.where(j < (n + 1) // 2, j, j - n) * pitch


def _bin_nodes():
    """4-node Gauss-Legendre nodes (in bins) and weights over [(k - 1/2) dt, (k + 1/2) dt]."""
    u, w = np.polynomial.legendre.leggauss(4)
    return u / 2, w / 2


def _cells(offsets, a, pitch):
    """The unit Gaussian exp(-u^2 / a) / sqrt(pi a) integrated over cells at ``offsets``."""
    s = np.sqrt(a)
    return 0.5 * (erf((offsets + pitch / 2) / s) - erf((offsets - pitch / 2) / s))


def _closed_form(slab_kw, ze, shape, dt, pitch, pad, square):
    nt = shape[0]
    P = (2 * nt, 2 * shape[1], 2 * shape[2]) if pad is None else tuple(pad)
    D, v, _, _ = params(**slab_kw, ze_m=ze)
    u, w = _bin_nodes()
    t = (np.arange(P[0])[:, None] + u[None, :]) * dt
    t0 = slab_transmittance_ref(0.0, t, **slab_kw, ze_m=ze)
    mass = t0 * 4 * np.pi * D * v * np.where(t > 0, t, 0) * w[None, :] * dt  # [lag, node]
    yo, xo = wrap_offsets(P[1], pitch), wrap_offsets(P[2], pitch)
    out = np.zeros(P)
    if square:
        terms = [(np.convolve(mass[:, i], mass[:, j])[:nt], u[i] + u[j])
                 for i in range(4) for j in range(4)]
    else:
        terms = [(mass[:nt, i], u[i]) for i in range(4)]
    for q, shift in terms:
        tt = (np.arange(nt) + shift) * dt
        for k in np.nonzero(q > 0)[0]:
            a = 4 * D * v * tt[k]
            out[k] += q[k] * _cells(yo, a, pitch)[:, None] * _cells(xo, a, pitch)[None, :]
    return out


def confocal_psf_ref(slab_kw, ze, shape, dt, pitch, pad=None):
    """Phi * Phi on the padded grid ``pad`` (default (2 nt, 2 ny, 2 nx)), lags < nt, written
    from the closed form: the laterally integrated P * P per pair of time nodes
    (np.convolve) times the unit Gaussian of variance 2 D v t per axis integrated over each
    scan cell (erf differences), at the nearest-image offsets of the wrap-order grid."""
    return _closed_form(slab_kw, ze, shape, dt, pitch, pad, square=True)


def phi_ref(slab_kw, ze, shape, dt, pitch, pad=None):
    """Phi alone on the grid of :func:`confocal_psf_ref`, lags < nt: per time node the
    laterally integrated response times the cell-integrated Gaussian of variance 2 D v t."""
    return _closed_form(slab_kw, ze, shape, dt, pitch, pad, square=False)


def _phi_fine(slab_kw, ze, shape, dt, pitch, sub):
    """Phi point-sampled (times the fine cell's area) on the (2 nt, 2 ny, 2 nx) grid made
    ``sub`` times finer laterally, lags < nt."""
    nt, ny, nx = shape
    P = (2 * nt, 2 * ny * sub, 2 * nx * sub)
    f = pitch / sub
    yo, xo = wrap_offsets(P[1], f), wrap_offsets(P[2], f)
    rho, where = np.unique(np.hypot(yo[:, None], xo[None, :]), return_inverse=True)
    u, w = _bin_nodes()
    phi = 0
    for uj, wj in zip(u, w, strict=True):
        tj = (np.arange(nt) + uj) * dt  # lags past nt are cut
        phi = phi + wj * slab_transmittance_ref(rho[None], tj[:, None], **slab_kw, ze_m=ze,
                                                M=20)
    phi = np.concatenate([phi[:, where.reshape(P[1:])] * dt * f**2,
                          np.zeros((P[0] - nt,) + P[1:])])
    return phi


def phi_binned_ref(slab_kw, ze, shape, dt, pitch, sub):
    """Phi by another route: point-sampled on a grid ``sub`` (odd) times finer and summed
    over the fine cells of each scan cell (converges to the cell integral as sub grows)."""
    return bin_fine_cells(_phi_fine(slab_kw, ze, shape, dt, pitch, sub), sub)


def confocal_psf_binned_ref(slab_kw, ze, shape, dt, pitch, sub):
    """Phi * Phi by another route: the fine point-sampled Phi of :func:`phi_binned_ref`
    self-convolved by FFT in 3D, cut to lags < nt and summed per scan cell."""
    phi = _phi_fine(slab_kw, ze, shape, dt, pitch, sub)
    phi2 = np.fft.irfftn(np.fft.rfftn(phi) ** 2, s=phi.shape, axes=(0, 1, 2))
    phi2[shape[0]:] = 0
    return bin_fine_cells(phi2, sub)


def bin_fine_cells(fine, sub):
    """Sum a wrap-order table [t, Y, X] over the ``sub`` x ``sub`` (odd) fine cells of each
    coarse cell (coarse index j holds fine offsets j sub - sub // 2 .. j sub + sub // 2)."""
    n0, n1, n2 = fine.shape
    h = sub // 2  # fine cells -h..h around each coarse centre, in wrap order
    rolled = np.roll(fine, (h, h), axis=(1, 2))
    return rolled.reshape(n0, n1 // sub, sub, n2 // sub, sub).sum(axis=(2, 4))


def pad_filter(x, psf, mode, snr=None):
    P = psf.shape
    xp = np.zeros(P)
    xp[: x.shape[0], : x.shape[1], : x.shape[2]] = x
    H = np.fft.fftn(psf)
    H = H / H[0, 0, 0].real
    if mode == "wiener":
        G = np.conj(H) / (np.abs(H) ** 2 + 1.0 / snr)
    else:
        G = H
    y = np.real(np.fft.ifftn(G * np.fft.fftn(xp)))
    return y[: x.shape[0], : x.shape[1], : x.shape[2]]


def lightcone_psf_ref(nt, ny, nx, dt, pitch):
    R = nt * C0 * dt / 2
    psf = np.zeros((2 * nt, 2 * ny, 2 * nx))
    for iy, oy in enumerate(wrap_offsets(2 * ny, 1)):
        for ix, ox in enumerate(wrap_offsets(2 * nx, 1)):
            s = ((oy * pitch) ** 2 + (ox * pitch) ** 2) / R**2 * nt
            k = int(np.floor(s))
            f = s - k
            if k < 2 * nt:
                psf[k, iy, ix] += 1 - f
            if k + 1 < 2 * nt:
                psf[k + 1, iy, ix] += f
    return psf


def lct_ref(tau, dt, width, snr, falloff=4.0):
    nt, ny, nx = tau.shape
    e = np.linspace(0, 1, nt + 1)
    w = ((np.arange(nt) + 0.5) / nt) ** falloff
    tv = resample_cumsum(tau, e, np.sqrt(e), weights=w)
    psf = lightcone_psf_ref(nt, ny, nx, dt, width / nx)
    u = pad_filter(tv, psf, "wiener", snr)
    z = resample_cumsum(u, np.sqrt(e), e)
    return np.maximum(z, 0)


def fk_ref(tau, dt, width, falloff=2.0):
    nt, ny, nx = tau.shape
    w = ((np.arange(nt) + 0.5) / nt) ** falloff
    psi = np.zeros((2 * nt, 2 * ny, 2 * nx), complex)
    psi[:nt, :ny, :nx] = np.sqrt(np.maximum(tau * w[:, None, None], 0))
    S = np.fft.fftn(psi)
    dz = C0 * dt / 2
    pitch = width / nx
    ay = (nt * dz / (ny * pitch)) ** 2
    ax = (nt * dz / (nx * pitch)) ** 2
    fz = np.fft.fftfreq(2 * nt, 1 / (2 * nt))
    fy = np.fft.fftfreq(2 * ny, 1 / (2 * ny))
    fx = np.fft.fftfreq(2 * nx, 1 / (2 * nx))
    FZ, FY, FX = np.meshgrid(fz, fy, fx, indexing="ij")
    k = np.sqrt(FZ**2 + ay * FY**2 + ax * FX**2)
    kmax = nt - 1
    valid = (FZ > 0) & (k <= kmax)
    i0 = np.clip(np.floor(k).astype(int), 0, 2 * nt - 2)
    f = k - i0
    iy, ix = np.indices((2 * ny, 2 * nx))
    iy = np.broadcast_to(iy, k.shape)
    ix = np.broadcast_to(ix, k.shape)
    v = S[i0, iy, ix] * (1 - f) + S[np.minimum(i0 + 1, 2 * nt - 1), iy, ix] * f
    out = np.where(valid, v * FZ / np.maximum(k, 1e-6), 0)
    vol = np.abs(np.fft.ifftn(out)) ** 2
    return vol[:nt, :ny, :nx]
