"""Float64 numpy/scipy reference of the reconstruction pipeline (independent of the kernels).

Resampling uses the integral form: a histogram's cumulative sum is piecewise linear, so the
content of any destination bin is the difference of the interpolated cumulative sum at its
edges (the package builds explicit overlap matrices instead).
"""

import numpy as np

from .diffusion_ref import slab_transmittance_ref

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


def confocal_psf_ref(slab_kw, ze, shape, dt, pitch):
    nt, ny, nx = shape
    P = (2 * nt, 2 * ny, 2 * nx)
    yo, xo = wrap_offsets(P[1], pitch), wrap_offsets(P[2], pitch)
    rho = np.hypot(yo[:, None], xo[None, :])
    # bin-averaged lags: 4-node Gauss-Legendre over [(k - 1/2) dt, (k + 1/2) dt]
    u, w = np.polynomial.legendre.leggauss(4)
    phi = 0
    for uj, wj in zip(u / 2, w / 2, strict=True):
        t = (np.arange(P[0]) + uj) * dt
        phi = phi + wj * slab_transmittance_ref(rho[None], t[:, None, None], **slab_kw, ze_m=ze)
    phi = phi * dt * pitch**2
    phi[nt:] = 0
    phi2 = np.real(np.fft.ifftn(np.fft.fftn(phi) ** 2))
    phi2[nt:] = 0
    return phi2


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
