"""Measured BRDF data: gonioreflectometer CSV, pbrt-v2 ``.brdf`` spectral files, MERL ``.binary``.

Angle convention (all readers return radians): (theta_i, phi_i) points towards the source and
(theta_s, phi_s) towards the detector, both away from the surface; the mirror direction is
(theta_i, phi_i + pi). BRDF values in 1/sr.

Every malformed file ends in :class:`~clnlos.errors.InputFileError` naming the file and what
is wrong (columns, NaN, negative BRDF, angles out of range).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from clnlos.checks import input_file
from clnlos.errors import InputFileError

CSV_COLUMNS = ["theta_i_deg", "phi_i_deg", "theta_s_deg", "phi_s_deg", "brdf"]
# Values below this (1/sr) are not used to judge a fit, whatever a file's precision: relative
# errors of near-zero values say nothing about the lobe.
MIN_SIGNIFICANT = 0.01
# A value printed with q as its last decimal place is known to about +-q/2; below 10 q its
# relative error exceeds 5%, so 10 q is taken as the file's precision.
PRECISION_QUANTA = 10
# Text data files are UTF-8, with or without the byte-order mark that Excel writes.
TEXT_ENCODING = "utf-8-sig"


def precision_from_text(values: list[str]) -> float:
    """Precision (1/sr) implied by how the values are printed: PRECISION_QUANTA x the finest
    last decimal place among them (0 when they are printed in exponent form)."""
    places = 0
    for v in values:
        if "e" in v or "E" in v:
            return 0.0
        if "." in v:
            places = max(places, len(v.split(".", 1)[1]))
    return PRECISION_QUANTA * 10.0 ** (-places)


def significance_floor(samples) -> float:
    """The value (1/sr) above which samples judge a fit: max(precision, MIN_SIGNIFICANT)."""
    return max(float(samples.meta.get("precision", 0.0)), MIN_SIGNIFICANT)




@dataclass
class BRDFSamples:
    """Measured samples: angles (radians) and BRDF (1/sr), with provenance."""

    theta_i: np.ndarray
    phi_i: np.ndarray
    theta_s: np.ndarray
    phi_s: np.ndarray
    brdf: np.ndarray
    meta: dict = field(default_factory=dict)

    def __len__(self):
        return len(self.brdf)

    @property
    def angles(self) -> np.ndarray:
        return np.column_stack([self.theta_i, self.phi_i, self.theta_s, self.phi_s])

    def subset(self, idx) -> BRDFSamples:
        return BRDFSamples(self.theta_i[idx], self.phi_i[idx], self.theta_s[idx],
                           self.phi_s[idx], self.brdf[idx], dict(self.meta))


def _validate(path, a: np.ndarray) -> None:
    if not np.all(np.isfinite(a)):
        row = int(np.nonzero(~np.isfinite(a).all(axis=1))[0][0])
        raise InputFileError(f"{path}: NaN or Inf in data row {row + 1}")
    th = a[:, [0, 2]]
    if np.any(th < 0) or np.any(th > 90):
        row = int(np.nonzero(((th < 0) | (th > 90)).any(axis=1))[0][0])
        raise InputFileError(f"{path}: zenith angle outside 0..90 deg in data row {row + 1}")
    ph = a[:, [1, 3]]
    if np.any(np.abs(ph) > 360):
        row = int(np.nonzero((np.abs(ph) > 360).any(axis=1))[0][0])
        raise InputFileError(f"{path}: azimuth outside -360..360 deg in data row {row + 1}")
    if np.any(a[:, 4] < 0):
        row = int(np.nonzero(a[:, 4] < 0)[0][0])
        raise InputFileError(f"{path}: negative BRDF {a[row, 4]} in data row {row + 1}")


def read_gonio_csv(path) -> BRDFSamples:
    """Read ``theta_i_deg,phi_i_deg,theta_s_deg,phi_s_deg,brdf`` with ``#`` header lines.

    ``meta["precision"]`` (1/sr) is a ``# precision:`` header when present, else derived from
    the printed decimals of the brdf column (:func:`precision_from_text`)."""
    p = input_file(path)
    meta, rows, header, printed = {}, [], None, []
    try:
        text = p.read_text(encoding=TEXT_ENCODING)
    except UnicodeDecodeError:
        raise InputFileError(f"{p}: not a text CSV file") from None
    for ln, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            body = s.lstrip("#").strip()
            if ":" in body:
                k, v = body.split(":", 1)
                meta.setdefault(k.strip(), v.strip())
            continue
        cells = [c.strip() for c in s.split(",")]
        if header is None:
            header = cells
            if header != CSV_COLUMNS:
                raise InputFileError(f"{p}: columns must be {','.join(CSV_COLUMNS)}, got "
                                     f"{','.join(header)}")
            continue
        if len(cells) != 5:
            raise InputFileError(f"{p}: line {ln}: 5 values expected, got {len(cells)}")
        printed.append(cells[4])
        try:
            rows.append([float(c) for c in cells])
        except ValueError:
            raise InputFileError(f"{p}: line {ln}: not a number in {s!r}") from None
    if header is None or not rows:
        raise InputFileError(f"{p}: no header row or no data")
    a = np.asarray(rows)
    _validate(p, a)
    r = np.radians(a[:, :4])
    meta["path"] = str(p)
    _set_precision(p, meta, printed)
    return BRDFSamples(r[:, 0], r[:, 1], r[:, 2], r[:, 3], a[:, 4], meta)


def _set_precision(path, meta: dict, printed: list[str]) -> None:
    if "precision" in meta:
        try:
            meta["precision"] = float(str(meta["precision"]).split()[0])
        except ValueError:
            raise InputFileError(f"{path}: '# precision:' must be a number in 1/sr, got "
                                 f"{meta['precision']!r}") from None
        if not (np.isfinite(meta["precision"]) and meta["precision"] >= 0):
            raise InputFileError(f"{path}: '# precision:' must be >= 0, got "
                                 f"{meta['precision']}")
        meta["precision_source"] = "file header"
    else:
        meta["precision"] = precision_from_text(printed)
        meta["precision_source"] = f"{PRECISION_QUANTA} x the last printed decimal place"


def read_pbrt_brdf(path, wavelength_nm: float = 550.0) -> BRDFSamples:
    """pbrt-v2 irregular spectral BRDF: counts, wavelengths, then rows of 4 angles (rad) and
    one value per wavelength; the value at ``wavelength_nm`` is linearly interpolated."""
    p = input_file(path)
    toks: list[str] = []
    for line in p.read_text(encoding=TEXT_ENCODING, errors="replace").splitlines():
        line = line.split("#", 1)[0]
        toks.extend(line.split())
    try:
        vals = np.asarray([float(t) for t in toks])
    except ValueError:
        raise InputFileError(f"{p}: non-numeric token in a pbrt .brdf file") from None
    if vals.size < 2 or vals[0] != int(vals[0]) or vals[0] < 1:
        raise InputFileError(f"{p}: missing wavelength count")
    nw = int(vals[0])
    wls = vals[1:1 + nw]
    body = vals[1 + nw:]
    if body.size == 0 or body.size % (4 + nw):
        raise InputFileError(f"{p}: data length {body.size} is not a multiple of 4 + {nw}")
    if not wls[0] <= wavelength_nm <= wls[-1]:
        raise InputFileError(f"{p}: wavelength {wavelength_nm} nm outside {wls[0]}..{wls[-1]}")
    rows = body.reshape(-1, 4 + nw)
    spec = rows[:, 4:]
    f = np.array([np.interp(wavelength_nm, wls, s) for s in spec])
    deg = np.degrees(rows[:, :4])
    a = np.column_stack([deg, f])
    _validate(p, a)
    meta = {"path": str(p), "channel": f"{wavelength_nm} nm", "format": "pbrt-v2"}
    value_tokens = np.asarray(toks[1 + nw:], dtype=object).reshape(-1, 4 + nw)[:, 4:]
    _set_precision(p, meta, list(value_tokens.ravel()))
    return BRDFSamples(rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], f, meta)


# ------------------------------------------------------------------ MERL
MERL_SHAPE = (90, 90, 180)  # theta_half, theta_diff, phi_diff
MERL_SCALE = (1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0)  # red, green, blue
# A MERL table sampled for ``brdf fit`` (:func:`merl_samples`): the training set as the
# gonioreflectometer sets of ../shared/data/brdf (incidence 30/45/60 deg, phi_i = 0, the
# detector every MERL_GONIO_STEP_DEG in theta_s and every 2 x that in phi_s over the half
# space an isotropic BRDF repeats), the held-out set at random directions (seeded)
MERL_GONIO_DEG = (30.0, 45.0, 60.0)
MERL_GONIO_STEP_DEG = 5.0
MERL_MAX_ZENITH_DEG = 85.0
MERL_HELD_OUT_SAMPLES = 2000
MERL_HELD_OUT_SEED = 0


def write_merl_binary(path, rgb: np.ndarray) -> None:
    """Write a MERL ``.binary`` (tests make small files with it; shape (3, 90, 90, 180))."""
    rgb = np.asarray(rgb, np.float64)
    if rgb.shape != (3, *MERL_SHAPE):
        raise ValueError(f"MERL data must have shape (3, 90, 90, 180), got {rgb.shape}")
    scaled = rgb / np.asarray(MERL_SCALE)[:, None, None, None]
    with open(path, "wb") as f:
        np.asarray(MERL_SHAPE, np.int32).tofile(f)
        scaled.astype("<f8").tofile(f)


class MerlBRDF:
    """A MERL isotropic BRDF in the half/difference parametrisation (Rusinkiewicz 1998).

    ``channel``: 0 red, 1 green, 2 blue. Evaluation uses the database's non-linear
    theta_half index sqrt(theta_h / (pi/2)) * 90 and nearest bins, as its reference code.
    """

    def __init__(self, path, channel: int = 1):
        p = input_file(path)
        raw = p.read_bytes()
        if len(raw) < 12:
            raise InputFileError(f"{p}: truncated MERL file")
        dims = tuple(np.frombuffer(raw[:12], "<i4"))
        n = int(np.prod(dims))
        if dims != MERL_SHAPE or len(raw) != 12 + 3 * n * 8:
            raise InputFileError(f"{p}: not a MERL .binary (dims {dims}, {len(raw)} bytes)")
        data = np.frombuffer(raw[12:], "<f8").reshape(3, *MERL_SHAPE)
        self.table = data[channel] * MERL_SCALE[channel]
        self.meta = {"path": str(p), "channel": "RGB"[channel], "format": "MERL",
                     "precision": 0.0, "precision_source": "float64 binary"}

    def __call__(self, ti, pi_, ts, ps) -> np.ndarray:
        th, td, pd = half_diff(ti, pi_, ts, ps)
        ih = np.clip((np.sqrt(np.clip(th, 0, None) / (np.pi / 2)) * 90).astype(int), 0, 89)
        idd = np.clip((td / (np.pi / 2) * 90).astype(int), 0, 89)
        pd = np.where(pd < 0, pd + np.pi, pd)
        ip = np.clip((pd / np.pi * 180).astype(int), 0, 179)
        return np.maximum(self.table[ih, idd, ip], 0)


def merl_samples(path, *, held_out: bool = False, channel: int = 1) -> BRDFSamples:
    """Samples of a MERL ``.binary`` (its ``channel``, default green) for a fit: the
    gonioreflectometer grid (MERL_GONIO_DEG), or, ``held_out``, MERL_HELD_OUT_SAMPLES random
    directions (zeniths uniform in cos theta up to MERL_MAX_ZENITH_DEG, azimuth difference
    uniform; seeded) -- the other directions a held-out set needs."""
    merl = MerlBRDF(path, channel)
    if held_out:
        rng = np.random.default_rng(MERL_HELD_OUT_SEED)
        cmin = np.cos(np.radians(MERL_MAX_ZENITH_DEG))
        ti, ts = (np.arccos(1 - rng.random((2, MERL_HELD_OUT_SAMPLES)) * (1 - cmin)))
        pi_ = np.zeros(MERL_HELD_OUT_SAMPLES)
        ps = rng.random(MERL_HELD_OUT_SAMPLES) * 2 * np.pi
    else:
        step = MERL_GONIO_STEP_DEG
        TI, TS, PS = np.meshgrid(np.radians(MERL_GONIO_DEG),
                                 np.radians(np.arange(0.0, MERL_MAX_ZENITH_DEG + 1e-9, step)),
                                 np.radians(np.arange(0.0, 180.0 + 1e-9, 2 * step)),
                                 indexing="ij")
        ti, ts, ps = TI.ravel(), TS.ravel(), PS.ravel()
        pi_ = np.zeros_like(ti)
    meta = {**merl.meta, "sampling": "random directions (held out)" if held_out else
            f"incidence {', '.join(f'{a:g}' for a in MERL_GONIO_DEG)} deg"}
    return BRDFSamples(ti, pi_, ts, ps, merl(ti, pi_, ts, ps), meta)


def half_diff(ti, pi_, ts, ps):
    """(theta_half, theta_diff, phi_diff) of two directions (Rusinkiewicz), radians."""
    def vec(t, p):
        return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)

    wi, wo = np.broadcast_arrays(vec(np.asarray(ti, float), np.asarray(pi_, float)),
                                 vec(np.asarray(ts, float), np.asarray(ps, float)))
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    th = np.arccos(np.clip(h[..., 2], -1, 1))
    ph = np.arctan2(h[..., 1], h[..., 0])

    def rot_z(v, a):
        c, s = np.cos(a), np.sin(a)
        return np.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1],
                         v[..., 2]], -1)

    def rot_y(v, a):
        c, s = np.cos(a), np.sin(a)
        return np.stack([c * v[..., 0] + s * v[..., 2], v[..., 1],
                         -s * v[..., 0] + c * v[..., 2]], -1)

    d = rot_y(rot_z(wi, -ph), -th)
    td = np.arccos(np.clip(d[..., 2], -1, 1))
    pd = np.arctan2(d[..., 1], d[..., 0])
    return th, td, pd


def agreement(pred, truth) -> float:
    """100% x (1 - mean min(1, |fhat - f| / f)) over samples with f > 0 (the seed's metric)."""
    pred, truth = np.asarray(pred, float), np.asarray(truth, float)
    m = truth > 0
    if not m.any():
        return math.nan
    return float(100.0 * (1 - np.mean(np.minimum(1, np.abs(pred[m] - truth[m]) / truth[m]))))


def relative_error(pred, truth) -> float:
    """Relative L2 error ||fhat - f|| / ||f||."""
    pred, truth = np.asarray(pred, float), np.asarray(truth, float)
    return float(np.linalg.norm(pred - truth) / max(np.linalg.norm(truth), 1e-300))
