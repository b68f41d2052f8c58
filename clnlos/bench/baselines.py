"""Host baselines the benchmarks compare the OpenCL kernels with: vectorised numpy float64
(slab transmittance, light cone, reconstruction) and torch CPU float32 (reconstruction), built
from the same matrices and PSFs as the OpenCL plans so only the execution engine differs.
"""

from __future__ import annotations

import warnings

import numpy as np
import scipy.sparse as sp

from clnlos.physics.constants import C0
from clnlos.forward.blur import confocal_psf
from clnlos.forward.scene import Scene
from clnlos.inverse.lct import lightcone_psf, t_to_v_matrix, u_to_z_matrix
from clnlos.physics.slab import Slab


def numpy_transmittance(slab: Slab, rho, t, n_dipoles: int) -> np.ndarray:
    """Vectorised float64 numpy image sum (the baseline)."""
    D, v, d, z0, ze = slab.D, slab.v, slab.thickness_m, slab.z0, slab.ze
    t = np.maximum(t, 1e-300)  # T(t=0) = 0: the exp underflows to exactly 0 here
    a = 4 * D * v * t
    s = np.zeros_like(a)
    for m in range(-n_dipoles, n_dipoles + 1):
        z1 = (1 - 2 * m) * d - 4 * m * ze - z0
        z2 = (1 - 2 * m) * d - (4 * m - 2) * ze + z0
        s += z1 * np.exp(-z1 * z1 / a) - z2 * np.exp(-z2 * z2 / a)
    with np.errstate(over="ignore", invalid="ignore"):
        out = ((4 * np.pi * D * v) ** -1.5 * t**-2.5 * np.exp(-slab.mu_a * v * t - rho**2 / a)
               * 0.5 * s)
    return np.nan_to_num(out, nan=0.0, posinf=0.0)


def ut_scene(points: int, bins: int, density: float, material: str = "lambertian") -> Scene:
    """Letters "UT" (0.3 m high, 6 cm strokes) 0.5 m behind a 0.6 m scan, no slab."""
    return Scene.from_dict({
        "scan": {"width_m": 0.6, "points": points},
        "time": {"bin_width_s": 4.0 / (C0 * bins), "bins": bins, "start_s": 0.0},
        "objects": [{"shape": "letters", "text": "UT", "height_m": 0.3, "stroke_m": 0.06,
                     "translate_m": [0.0, 0.0, 0.5], "material": material}],
        "sampling": {"density_per_m2": density}})


def numpy_lightcone(s: Scene, samples) -> np.ndarray:
    el = samples.elements
    c = s.scan_centres()
    out = np.zeros((s.bins, s.points, s.points))
    for iy, sy in enumerate(c):
        d = el.pos[None, :, :] - np.stack([c, np.full_like(c, sy), np.zeros_like(c)], 1)[:, None]
        r = np.linalg.norm(d, axis=2)
        cr = d[..., 2] / r
        co = -(d * el.normal[None]).sum(2) / r
        w = samples.albedo * cr**2 * co**2 / r**4 * el.area / np.pi
        w[(cr <= 0) | (co <= 0)] = 0
        b = (2 * r / C0 - s.start_s) / s.bin_width_s - 0.5
        k = np.floor(b).astype(int)
        f = b - k
        for ix in range(len(c)):
            for kk, ww in ((k[ix], w[ix] * (1 - f[ix])), (k[ix] + 1, w[ix] * f[ix])):
                ok = (kk >= 0) & (kk < s.bins)
                out[:, iy, ix] += np.bincount(kk[ok], ww[ok], minlength=s.bins)
    return out


class _Setup:
    def __init__(self, shape, *, bin_width_s, scan_width_m, slab, snr, lct_snr, queue):
        nt, ny, nx = shape
        self.shape = shape
        self.pad = (2 * nt, 2 * ny, 2 * nx)
        psf = confocal_psf(slab, shape, bin_width_s=bin_width_s, pitch_m=scan_width_m / nx,
                           dtype=np.float32, queue=queue).get().astype(np.float64)
        Hb = np.fft.rfftn(psf)
        self.Hb = Hb / Hb[0, 0, 0].real
        Hl = np.fft.rfftn(lightcone_psf(nt, ny, nx, bin_width_s=bin_width_s,
                                        pitch_m=scan_width_m / nx))
        self.Hl = Hl / Hl[0, 0, 0].real
        self.snr, self.lct_snr = snr, lct_snr
        self.A = t_to_v_matrix(nt, 4.0)
        self.B = u_to_z_matrix(nt)
        dz = C0 * bin_width_s / 2
        pitch = scan_width_m / nx
        self.alpha_y = (nt * dz / (ny * pitch)) ** 2
        self.alpha_x = (nt * dz / (nx * pitch)) ** 2
        self.w_fk = ((np.arange(nt) + 0.5) / nt) ** 2


def _stolt_indices(pad, alpha_y, alpha_x):
    """Source index i0, weight f and scale s of the Stolt interpolation on the padded grid."""
    nt2, ny2, nx2 = pad
    fz = np.fft.fftfreq(nt2, 1 / nt2)
    fy = np.fft.fftfreq(ny2, 1 / ny2)
    fx = np.fft.fftfreq(nx2, 1 / nx2)
    k = np.sqrt(fz[:, None, None] ** 2 + alpha_y * fy[None, :, None] ** 2
                + alpha_x * fx[None, None, :] ** 2)
    valid = (fz[:, None, None] > 0) & (k <= nt2 // 2 - 1)
    i0 = np.clip(np.floor(k).astype(np.int64), 0, nt2 - 2)
    f = k - i0
    scale = np.where(valid, fz[:, None, None] / np.maximum(k, 1e-6), 0.0)
    return i0, f, scale


class NumpyReconstruction(_Setup):
    """float64 numpy/scipy execution."""

    def _filter(self, x, H, snr):
        xp = np.zeros(self.pad)
        xp[: x.shape[0], : x.shape[1], : x.shape[2]] = x
        S = np.fft.rfftn(xp)
        S *= np.conj(H) / (np.abs(H) ** 2 + 1.0 / snr)
        y = np.fft.irfftn(S, s=self.pad, axes=(0, 1, 2))
        return y[: x.shape[0], : x.shape[1], : x.shape[2]]

    def deconvolve(self, x):
        return self._filter(x, self.Hb, self.snr)

    def lct(self, x):
        nt = x.shape[0]
        v = (self.A @ x.reshape(nt, -1)).reshape(x.shape)
        u = self._filter(v, self.Hl, self.lct_snr)
        return np.maximum((self.B @ u.reshape(nt, -1)).reshape(x.shape), 0)

    def fk(self, x):
        nt, ny, nx = x.shape
        psi = np.zeros(self.pad, complex)
        psi[:nt, :ny, :nx] = np.sqrt(np.maximum(x * self.w_fk[:, None, None], 0))
        S = np.fft.fftn(psi)
        if not hasattr(self, "_st"):
            self._st = _stolt_indices(self.pad, self.alpha_y, self.alpha_x)
        i0, f, scale = self._st
        g = np.take_along_axis(S, i0, axis=0) * (1 - f) + np.take_along_axis(S, i0 + 1, 0) * f
        out = np.fft.ifftn(g * scale)
        return np.abs(out[:nt, :ny, :nx]) ** 2


class TorchReconstruction(_Setup):
    """torch CPU float32 execution of the same math (torch.fft, sparse CSR matmul)."""

    def __init__(self, *a, **kw):
        import torch

        super().__init__(*a, **kw)
        self.torch = torch
        self.tHb = torch.from_numpy(self.Hb.astype(np.complex64))
        self.tHl = torch.from_numpy(self.Hl.astype(np.complex64))

        def csr(m):
            m = sp.csr_matrix(m, dtype=np.float32)
            # the matrices are built here from a valid scipy CSR: skip torch's invariant
            # checks (and their beta-feature warnings)
            with torch.sparse.check_sparse_tensor_invariants(enable=False), \
                    warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)
                return torch.sparse_csr_tensor(torch.from_numpy(m.indptr.astype(np.int64)),
                                               torch.from_numpy(m.indices.astype(np.int64)),
                                               torch.from_numpy(m.data), size=m.shape)

        self.tA, self.tB = csr(self.A), csr(self.B)
        self.tw = torch.from_numpy(self.w_fk.astype(np.float32))
        self._st = None

    def _filter(self, x, H, snr):
        t = self.torch
        xp = t.zeros(self.pad, dtype=t.float32)
        xp[: x.shape[0], : x.shape[1], : x.shape[2]] = x
        S = t.fft.rfftn(xp)
        S *= t.conj(H) / (H.abs() ** 2 + 1.0 / snr)
        y = t.fft.irfftn(S, s=self.pad)
        return y[: x.shape[0], : x.shape[1], : x.shape[2]]

    def deconvolve(self, x):
        return self._filter(x, self.tHb, self.snr)

    def lct(self, x):
        nt = x.shape[0]
        v = (self.tA @ x.reshape(nt, -1)).reshape(x.shape)
        u = self._filter(v, self.tHl, self.lct_snr).contiguous()
        return (self.tB @ u.reshape(nt, -1)).reshape(x.shape).clamp_min(0)

    def fk(self, x):
        t = self.torch
        nt, ny, nx = x.shape
        psi = t.zeros(self.pad, dtype=t.complex64)
        psi[:nt, :ny, :nx] = t.sqrt((x * self.tw[:, None, None]).clamp_min(0))
        S = t.fft.fftn(psi)
        if self._st is None:
            i0, f, scale = _stolt_indices(self.pad, self.alpha_y, self.alpha_x)
            self._st = (t.from_numpy(i0), t.from_numpy(f.astype(np.float32)),
                        t.from_numpy(scale.astype(np.float32)))
        i0, f, scale = self._st
        g = t.gather(S, 0, i0) * (1 - f) + t.gather(S, 0, i0 + 1) * f
        out = t.fft.ifftn(g * scale)
        return out[:nt, :ny, :nx].abs() ** 2
