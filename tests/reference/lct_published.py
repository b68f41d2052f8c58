"""An independent float64 NumPy port of the light-cone transform as published with the LCT
captures (O'Toole, Lindell & Wetzstein 2018, ``cnlos_reconstruction.m``): the test reference
for reading the released files. Written from the paper's description and the published
steps, not from clnlos: bins summed to 16 ps, the first 600 native bins zeroed, (t/T)^p
weighting (p = 4 diffuse, 2 retroreflective), the t -> v = t^2 resampling as the published
sparse operator (ceil(sqrt) binning, halved K times), a Wiener filter of the shell PSF, the
inverse resampling, clamped at zero.

Returns the volume in the published display orientation: ``vol[z, row, col]`` with the
front view ``vol.max(0)`` shown with row 0 at the top (as MATLAB's imagesc), x = col."""

from __future__ import annotations

import numpy as np

C_PUBLISHED = 3e8  # the published code's speed of light (m/s)


def _resampling(m: int) -> np.ndarray:
    """The published t -> v operator: row x of the m^2 fine rows holds 1/sqrt(x) at column
    ceil(sqrt(x)); pairs of rows averaged log2(m) times down to m rows."""
    x = np.arange(1, m * m + 1)
    cols = np.ceil(np.sqrt(x)).astype(int) - 1
    mtx = np.zeros((m, m))
    np.add.at(mtx, ((x - 1) // m, cols), 1.0 / np.sqrt(x) / m)  # m rows averaged per block
    return mtx  # (m, m); the inverse is its transpose


def _shell_psf(n: int, m: int, slope: float) -> np.ndarray:
    x = np.linspace(-1, 1, 2 * n)
    z = np.linspace(0, 2, 2 * m)
    gz, gy, gx = np.meshgrid(z, x, x, indexing="ij")
    psf = np.abs((4 * slope) ** 2 * (gx ** 2 + gy ** 2) - gz)
    psf = (psf == psf.min(axis=0, keepdims=True)).astype(np.float64)
    psf /= psf[:, n, n].sum()
    psf /= np.linalg.norm(psf)
    return np.roll(psf, (0, n, n), axis=(0, 1, 2))


def published_lct(rect_data: np.ndarray, width: float, *, diffuse: bool,
                  bin_width_s: float = 4e-12, downsample: int = 2, z_trim: int = 600,
                  snr: float | None = None, z_offset: int | None = None
                  ) -> tuple[np.ndarray, float]:
    """(vol[z, row, col], depth step (m), depth of vol[0] (m)) of the published LCT for
    ``rect_data`` (N, N, T); ``z_offset`` (native bins): the published display's crop."""
    data = np.asarray(rect_data, np.float64)
    n, m = data.shape[0], data.shape[2]
    rng = m * C_PUBLISHED * bin_width_s
    bw = bin_width_s
    for _ in range(downsample):
        m //= 2
        bw *= 2
        data = data[:, :, 0::2] + data[:, :, 1::2]
        z_trim = round(z_trim / 2)
    data[:, :, :z_trim] = 0
    if snr is None:
        snr = 0.08 if diffuse else 0.8
    fpsf = np.fft.fftn(_shell_psf(n, m, width / rng))
    inv = np.conj(fpsf) / (np.abs(fpsf) ** 2 + 1.0 / snr)
    mtx = _resampling(m)
    d = np.transpose(data, (2, 1, 0))  # (t, j, i), MATLAB's permute [3 2 1]
    gz = np.linspace(0, 1, m)[:, None, None]
    d = d * gz ** (4 if diffuse else 2)
    t = np.zeros((2 * m, 2 * n, 2 * n))
    t[:m, :n, :n] = (mtx @ d.reshape(m, -1)).reshape(m, n, n)
    tv = np.fft.ifftn(np.fft.fftn(t) * inv)[:m, :n, :n]
    vol = np.maximum(np.real((mtx.T @ tv.reshape(m, -1)).reshape(m, n, n)), 0)
    vol = vol[:, :, ::-1]  # the published display reverses the last index
    dz = rng / 2 / (m - 1)
    if z_offset is not None:  # the published display's depth crop (native 4 ps bins)
        z0 = round(z_offset / 2 ** downsample)
        vol = vol[z0:z0 + round(m * 2 * width / (rng / 2))]
        return vol, dz, z0 * dz
    return vol, dz, 0.0


# the published display's depth crop per released file (cnlos_reconstruction.m, 4 ps bins)
PUBLISHED_Z_OFFSET = {"data_resolution_chart_40cm": 350, "data_dot_chart_40cm": 350,
                      "data_s_u": 800, "data_outdoor_s": 700, "data_diffuse_s": 100}
