"""The slab diffusion model against measured time-resolved transmittance (real calibration data).

The CDT calibration captures (Lindell & Wetzstein 2020; the data's ``cdt/calibration`` folder)
are photon-count histograms of a pencil beam sent through 1.0 ... 8.0 inches of the same
foam, detected on axis on the far face, plus the system impulse response without the slab.
The model of a capture is the on-axis diffuse transmittance T(rho = 0, t) of
:mod:`clnlos.diffusion` (the OpenCL image-dipole series, float64 where the device has it)
convolved with the measured impulse response::

    h(s) = A sum_j irf[j] T(s - j dt - t0),     s = time since the light entered the slab

with A a free amplitude (closed-form least squares) and t0 a free per-capture offset (the
authors fitted one too: the hardware delay is known to a few bins only). Fitted: mu_s' and
mu_a per capture or jointly over all thicknesses, at a fixed relative index n (n and mu_s'
are nearly degenerate through D v = c0 / (3 n (mu_a + mu_s')); :func:`n_profile` sweeps n).

Preprocessing as the authors describe it: the recorded span (trailing empty bins dropped),
minus the median (dark level), clamped at 0; the impulse response starts at the first bin
above ``IRF_ONSET_COUNTS`` and is ``IRF_BINS`` long with unit sum; a capture's time axis is
aligned by that onset plus the propagation delay d / c0 and normalised to its maximum.

Pure numpy/scipy except the transmittance series (one kernel call per model evaluation).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import h5py
import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix

from clnlos.physics.constants import C0
from clnlos.diffusion import SlabTransmittance
from clnlos.errors import InputFileError, ParameterError
from clnlos.physics.slab import CDT_SLAB, Slab
from clnlos.runtime.device import get_queue, has_fp64

BIN_WIDTH_S = 8e-12  # histogram bin of the calibration captures (README of the data)
INCH_M = 0.0254
THICKNESSES_INCH = tuple(1.0 + 0.5 * k for k in range(15))  # 1.0, 1.5, ..., 8.0
DIRECT_NAME = "capture_direct.mat"
DATASET = "out"
IRF_ONSET_COUNTS = 100.0  # counts above the dark level that mark the impulse response onset
IRF_BINS = 129  # impulse response length kept, bins (1.03 ns: 98% of its counts)
WINDOW_S = (-0.25e-9, 35e-9)  # fitted span of s (time since entry), s
PUBLISHED = CDT_SLAB  # mu_a 0.53 1/m, mu_s' 262 1/m, n 1.12 (the authors' joint fit)
START_MU_S_PRIME = 150.0  # 1/m, the authors' initial guess
START_MU_A = 0.1  # 1/m
N_GRID = tuple(round(1.0 + 0.04 * k, 2) for k in range(16))  # 1.00 ... 1.60, n profile
T0_BOUND_S = 2e-9  # |t0| limit of the fits (the thick captures need up to ~0.5 ns)
# Departure measures: the rise is where the data climb from RISE_FROM to the peak, the tail
# where they fall below TAIL_BELOW of it (down to TAIL_FLOOR, above the dark noise).
RISE_FROM, TAIL_BELOW, TAIL_FLOOR = 0.05, 0.1, 0.003


def capture_name(thickness_inch: float) -> str:
    """File name of the capture through ``thickness_inch`` inches (e.g. capture_1_5_inch.mat)."""
    whole, half = divmod(round(float(thickness_inch) * 10), 10)
    return f"capture_{whole}_{half}_inch.mat"


def read_histogram(path) -> np.ndarray:
    """The photon-count histogram (float64, 1D) of a calibration capture (MATLAB v7.3)."""
    p = Path(path)
    if not p.is_file():
        raise InputFileError(f"calibration capture {p}: no such file")
    try:
        with h5py.File(p, "r") as f:
            if DATASET not in f:
                raise InputFileError(f"calibration capture {p}: no dataset {DATASET!r} "
                                     f"(has {sorted(f.keys())})")
            h = np.asarray(f[DATASET], dtype=np.float64).ravel()
    except OSError as exc:
        raise InputFileError(f"calibration capture {p}: not an HDF5/MATLAB v7.3 file "
                             f"({exc})") from None
    if h.size < IRF_BINS or not np.isfinite(h).all() or not (h > 0).any():
        raise InputFileError(f"calibration capture {p}: dataset {DATASET!r} holds "
                             f"{h.size} bins, needs >= {IRF_BINS} finite counts, not all 0")
    return h


def remove_dark(counts: np.ndarray) -> np.ndarray:
    """The recorded span (up to the last non-empty bin) minus its median, clamped at 0."""
    h = np.asarray(counts, np.float64)
    h = h[:np.nonzero(h > 0)[0][-1] + 1]
    return np.maximum(h - np.median(h), 0.0)


@dataclasses.dataclass(frozen=True)
class ImpulseResponse:
    """The system impulse response: ``kernel`` (IRF_BINS, unit sum) from bin ``onset`` of
    the direct capture on."""

    kernel: np.ndarray
    onset: int


def impulse_response(direct_counts: np.ndarray) -> ImpulseResponse:
    """:class:`ImpulseResponse` of the direct (no slab) histogram."""
    h = remove_dark(direct_counts)
    above = np.nonzero(h > IRF_ONSET_COUNTS)[0]
    if not above.size or above[0] + IRF_BINS > h.size:
        raise InputFileError(f"impulse response: no {IRF_BINS} bins after a count above "
                             f"{IRF_ONSET_COUNTS:g} (peak {h.max():g})")
    k = h[above[0]:above[0] + IRF_BINS]
    return ImpulseResponse(kernel=k / k.sum(), onset=int(above[0]))


@dataclasses.dataclass(frozen=True)
class Measurement:
    """One capture on its aligned axis: ``s_s`` (time since the light entered the slab, s,
    per bin of the window) and ``y`` (counts / max, dark removed)."""

    thickness_m: float
    s_s: np.ndarray
    y: np.ndarray


def align(counts: np.ndarray, irf: ImpulseResponse, thickness_m: float) -> Measurement:
    """Put a capture on the time axis s of the model: bin k is at
    s = (k - onset) dt + d / c0 (the direct light reached the detector at the onset; through
    the slab the entry face is d upstream of it) and keep the WINDOW_S span."""
    h = remove_dark(counts)
    s = (np.arange(h.size) - irf.onset) * BIN_WIDTH_S + float(thickness_m) / C0
    keep = (s >= WINDOW_S[0]) & (s <= WINDOW_S[1])
    y = h[keep]
    if y.size < IRF_BINS or y.max() <= 0:
        raise InputFileError(f"calibration capture of {thickness_m} m: {y.size} bins with "
                             f"signal in the window {WINDOW_S} s, needs >= {IRF_BINS}")
    return Measurement(thickness_m=float(thickness_m), s_s=s[keep], y=y / y.max())


def load_captures(directory, thicknesses_inch=THICKNESSES_INCH
                  ) -> tuple[ImpulseResponse, list[Measurement]]:
    """(impulse response, aligned captures) of a calibration directory."""
    d = Path(directory)
    irf = impulse_response(read_histogram(d / DIRECT_NAME))
    meas = [align(read_histogram(d / capture_name(th)), irf, th * INCH_M)
            for th in thicknesses_inch]
    return irf, meas


def model_curve(slab: Slab, s_s: np.ndarray, irf_kernel: np.ndarray, t0_s: float = 0.0,
                queue=None) -> np.ndarray:
    """sum_j irf[j] T(0, s - j dt - t0) at the equally spaced times ``s_s`` (1/(m^2 s),
    per unit injected energy): T on the window extended by the kernel's length, convolved."""
    q = get_queue(queue)
    dt = np.float64 if has_fp64(q.device) else np.float32
    nk = len(irf_kernel)
    ds = float(s_s[1] - s_s[0])
    t = s_s[0] - float(t0_s) + (np.arange(len(s_s) + nk - 1) - (nk - 1)) * ds
    tr = np.zeros(t.size)
    pos = t > 0
    if pos.any():
        tr[pos] = np.exp(SlabTransmittance(slab, dtype=dt, queue=q).log_series(t[pos]))
    return np.convolve(tr, irf_kernel, mode="valid")


def scaled_residual(y: np.ndarray, m: np.ndarray) -> tuple[np.ndarray, float]:
    """(A m - y, A) with the amplitude A >= 0 minimising the squared residual."""
    mm = float(m @ m)
    a = max(float(m @ y) / mm, 0.0) if mm > 0 else 0.0
    return a * m - y, a


def relative_residual(y: np.ndarray, m: np.ndarray) -> float:
    """||A m - y|| / ||y|| at the best amplitude A."""
    r, _ = scaled_residual(y, m)
    return float(np.linalg.norm(r) / np.linalg.norm(y))


@dataclasses.dataclass(frozen=True)
class SlabFit:
    """A fit: the slab coefficients (1/m), n, per-capture offsets t0 (s) and amplitudes,
    the relative residual per capture and over all, evaluations used."""

    mu_s_prime: float
    mu_a: float
    n: float
    thickness_m: tuple
    t0_s: tuple
    amplitude: tuple
    residual: tuple
    residual_all: float
    nfev: int
    success: bool

    def slab(self, i: int = 0) -> Slab:
        return Slab(thickness_m=self.thickness_m[i], mu_a=self.mu_a,
                    mu_s_prime=self.mu_s_prime, n=self.n)


def _curves(mu_s, mu_a, n, t0, meas, irf, queue):
    return [model_curve(Slab(thickness_m=m.thickness_m, mu_a=mu_a, mu_s_prime=mu_s, n=n),
                        m.s_s, irf.kernel, t0_i, queue) for m, t0_i in zip(meas, t0, strict=True)]


def fit_slab(meas: list[Measurement], irf: ImpulseResponse, *, n: float = PUBLISHED.n,
             fit_mu: bool = True, mu_s_prime: float = START_MU_S_PRIME,
             mu_a: float = START_MU_A, queue=None) -> SlabFit:
    """Least-squares fit of the model to the captures ``meas`` jointly: mu_s' and mu_a shared
    (held at the given values when ``fit_mu`` is False), one t0 per capture, n fixed.

    Starts at the given mu_s', mu_a and t0 = 0; bounds mu_s' in [10, 1e4] 1/m, mu_a in
    [0, 50] 1/m, |t0| <= T0_BOUND_S. The residual per capture is ||A m - y|| / ||y||.
    """
    if not meas:
        raise ParameterError("meas", "[]", "at least one capture")
    k = len(meas)
    n_mu = 2 if fit_mu else 0
    sizes = [m.y.size for m in meas]
    offs = np.concatenate([[0], np.cumsum(sizes)])

    def unpack(x):
        mus, mua = (x[0] * 100.0, x[1]) if fit_mu else (mu_s_prime, mu_a)
        return mus, mua, x[n_mu:] * 1e-9

    def res(x):
        mus, mua, t0 = unpack(x)
        curves = _curves(mus, mua, n, t0, meas, irf, queue)
        return np.concatenate([scaled_residual(m.y, c)[0]
                               for m, c in zip(meas, curves, strict=True)])

    sparsity = lil_matrix((offs[-1], n_mu + k), dtype=int)
    for i in range(k):
        sparsity[offs[i]:offs[i + 1], :n_mu] = 1
        sparsity[offs[i]:offs[i + 1], n_mu + i] = 1
    x0 = np.array(([mu_s_prime / 100.0, mu_a] if fit_mu else []) + [0.0] * k)
    lo = np.array(([0.1, 0.0] if fit_mu else []) + [-T0_BOUND_S * 1e9] * k)
    hi = np.array(([100.0, 50.0] if fit_mu else []) + [T0_BOUND_S * 1e9] * k)
    sol = least_squares(res, x0, bounds=(lo, hi), diff_step=1e-4,
                        jac_sparsity=sparsity if k > 1 else None,
                        x_scale=np.array(([1.0, 0.5] if fit_mu else []) + [0.05] * k),
                        xtol=1e-10, ftol=1e-10, max_nfev=200)
    mus, mua, t0 = unpack(sol.x)
    curves = _curves(mus, mua, n, t0, meas, irf, queue)
    amps = [scaled_residual(m.y, c)[1] for m, c in zip(meas, curves, strict=True)]
    rel = [relative_residual(m.y, c) for m, c in zip(meas, curves, strict=True)]
    y_all = np.concatenate([m.y for m in meas])
    return SlabFit(mu_s_prime=float(mus), mu_a=float(mua), n=float(n),
                   thickness_m=tuple(m.thickness_m for m in meas),
                   t0_s=tuple(float(v) for v in t0), amplitude=tuple(amps),
                   residual=tuple(rel),
                   residual_all=float(np.linalg.norm(sol.fun) / np.linalg.norm(y_all)),
                   nfev=int(sol.nfev), success=bool(sol.success))


def n_profile(meas, irf, n_grid=N_GRID, queue=None) -> list[SlabFit]:
    """:func:`fit_slab` at each n of ``n_grid`` (mu_s', mu_a, t0 refitted at each)."""
    return [fit_slab(meas, irf, n=float(n), queue=queue) for n in n_grid]


def departures(m: Measurement, fitted: np.ndarray) -> dict:
    """Where a fitted curve (same axis as ``m``, any scale) departs from the data.

    Returns (times in ps, ratios model/data at the best amplitude):
    ``rise_residual`` / ``tail_residual``: relative L2 over the rise (data from RISE_FROM of
    the peak up to it) and the tail (after the peak, from TAIL_BELOW down to TAIL_FLOOR);
    ``half_rise_ps``: model minus data time of the half-maximum on the rise;
    ``peak_ps``: model minus data peak time;
    ``ratio_at_rise_10``: model / data where the data first reach 10% of the peak;
    ``tail_rate_ratio``: model / data decay rate of the tail (log-linear slopes).
    """
    r, a = scaled_residual(m.y, fitted)
    mod = a * fitted
    y, s = m.y, m.s_s * 1e12
    ip = int(np.argmax(y))
    rise = np.arange(ip + 1)
    rise = rise[y[rise] >= RISE_FROM]
    tail = np.arange(ip, y.size)
    tail = tail[(y[tail] <= TAIL_BELOW) & (y[tail] >= TAIL_FLOOR)
                & (np.cumsum(y[tail] < TAIL_FLOOR) == 0)]

    def crossing(curve, level):
        j = int(np.nonzero(curve[:int(np.argmax(curve)) + 1] >= level * curve.max())[0][0])
        if j == 0:
            return s[0]
        f = (level * curve.max() - curve[j - 1]) / (curve[j] - curve[j - 1])
        return s[j - 1] + f * (s[j] - s[j - 1])

    def slope(idx, curve):
        pos = curve[idx] > 0
        return np.polyfit(s[idx][pos], np.log(curve[idx][pos]), 1)[0] if pos.sum() > 2 else 0.0

    i10 = int(np.nonzero(y >= 0.1)[0][0])
    tail_ratio = (slope(tail, mod) / slope(tail, y)) if tail.size > 2 else float("nan")
    return {
        "rise_residual": float(np.linalg.norm(r[rise]) / np.linalg.norm(y[rise])),
        "tail_residual": (float(np.linalg.norm(r[tail]) / np.linalg.norm(y[tail]))
                          if tail.size else float("nan")),
        "half_rise_ps": float(crossing(mod, 0.5) - crossing(y, 0.5)),
        "peak_ps": float(s[int(np.argmax(mod))] - s[ip]),
        "ratio_at_rise_10": float(mod[i10] / y[i10]),
        "tail_rate_ratio": float(tail_ratio),
    }


__all__ = ["BIN_WIDTH_S", "INCH_M", "THICKNESSES_INCH", "PUBLISHED", "ImpulseResponse",
           "Measurement", "SlabFit", "capture_name", "read_histogram", "remove_dark",
           "impulse_response", "align", "load_captures", "model_curve", "scaled_residual",
           "relative_residual", "fit_slab", "n_profile", "departures"]
