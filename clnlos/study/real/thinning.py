"""Real captures degraded on purpose: the shared CDT captures thinned to a fraction of their
photons, reconstructed with the study's method and defaults, and judged by the legibility
classifier (results.json ``classifier.real_thinning``).

Binomial thinning keeps each recorded photon independently with probability f: from counts
y (Poisson of mean mu per bin) it gives counts Binomial(y, f), Poisson of mean f mu, the
capture the same scene would have given with f times the exposure (photon noise only; the
dark and background counts are thinned with the signal). The fractions are nested: each
capture is thinned from the one before it,

    y_k ~ Binomial(y_{k-1}, f_k / f_{k-1}),    y_0 = y, f_0 = 1,

so y_k is Binomial(y, f_k) and every photon of a fainter capture is one of the brighter
capture's (a series, not independent draws); seeded (THINNING_SEED). Each capture is
reconstructed as the study reconstructs the real captures
(:func:`clnlos.study.real.capture.capture_config` with the study grid's method, iterations and
SNR rule) and its maximum-intensity projection, resampled to the study grid's points and
normalised to its maximum, is what the classifier sees. Reconstructions are cached in the
study's sample cache, keyed by the capture file's SHA-256, the fraction, the seed, the grid
and :func:`clnlos.study.samples.render.code_version`.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
from scipy.ndimage import zoom

from clnlos.inverse.pipeline import reconstruct
from clnlos.io.files import atomic_path, file_sha256, read_capture
from clnlos.io.figures import new_figure
from clnlos.study.file.spec import StudyGrid
from clnlos.study.samples.render import NPZ_ERRORS, code_version
from clnlos.study.real.capture import PUBLISHED_SCAN_WIDTH_M, capture_config

THINNING_FRACTIONS = (1.0, 0.3, 0.1, 0.03, 0.01, 0.003)
THINNING_SEED = 40


def thinned_series(counts: np.ndarray, fractions=THINNING_FRACTIONS,
                   seed: int = THINNING_SEED) -> list[np.ndarray]:
    """Nested binomial thinnings of integer ``counts`` to each of ``fractions`` (decreasing,
    in (0, 1]): float32 arrays of counts, the first of a fraction 1 the counts themselves."""
    f = [float(v) for v in fractions]
    if any(not 0 < v <= 1 for v in f) or any(b > a for a, b in zip(f, f[1:], strict=False)):
        raise ValueError(f"thinning fractions must decrease within (0, 1]: {fractions}")
    y = np.rint(np.asarray(counts, np.float64))
    if y.size and y.min() < 0:
        raise ValueError("thinning needs counts >= 0")
    rng = np.random.default_rng(seed)
    out, prev, cur = [], 1.0, y.astype(np.int64)
    for v in f:
        if v < prev:
            cur = rng.binomial(cur, v / prev)
        prev = v
        out.append(cur.astype(np.float32))
    return out


def study_mip(volume: np.ndarray, points: int) -> np.ndarray:
    """A reconstruction's MIP [y, x] as the classifier sees it: resampled (linear) to
    ``points`` x ``points`` and normalised to its maximum (float32)."""
    mip = np.asarray(volume, np.float64).max(axis=0)
    if mip.shape != (points, points):
        mip = zoom(mip, (points / mip.shape[0], points / mip.shape[1]), order=1)
    m = mip.max()
    return (mip / m if m > 0 else mip).astype(np.float32)



def _cache_path(cache: Path, digest: str, fraction: float, seed: int, grid: StudyGrid,
                version: str) -> Path:
    blob = json.dumps({"capture": digest, "fraction": fraction, "seed": seed,
                       "grid": asdict(grid), "code": version, "kind": "real_thinning"},
                      sort_keys=True)
    return cache / f"real-{hashlib.sha1(blob.encode()).hexdigest()}.npz"


def _load(path: Path, points: int) -> np.ndarray | None:
    """The cached MIP at ``path`` when it is there and has the grid's shape (a bad entry is
    deleted and recomputed)."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            mip = np.asarray(z["mip"])
    except NPZ_ERRORS:
        mip = None
    if mip is None or mip.shape != (points, points) or mip.dtype != np.float32:
        path.unlink(missing_ok=True)
        return None
    return mip


def thinned_mips(path, grid: StudyGrid, *, fractions=THINNING_FRACTIONS,
                 seed: int = THINNING_SEED, cache: Path | None = None, device=None,
                 progress=None) -> list[dict]:
    """``[{"capture", "fraction", "photons", "mip"}]``: the real capture at ``path`` (one of
    the shared CDT captures) thinned to each fraction and reconstructed with the study's
    method and defaults. ``progress(done, total)`` is called after each reconstruction."""
    path = Path(path)
    name = path.stem
    cap = read_capture(path)
    cfg = capture_config(name, grid.method, iterations=grid.iterations,
                         snr_rule=grid.snr_rule)
    digest = file_sha256(path) if cache is not None else ""
    version = code_version() if cache is not None else ""
    out = []
    for f, counts in zip(fractions, thinned_series(cap.transient, fractions, seed),
                         strict=True):
        entry = None if cache is None else _cache_path(cache, digest, f, seed, grid, version)
        mip = None if entry is None else _load(entry, grid.points)
        if mip is None:
            rec = reconstruct(replace(cap, transient=counts), cfg, device=device)
            mip = study_mip(rec.volume, grid.points)
            if entry is not None:
                entry.parent.mkdir(parents=True, exist_ok=True)
                with atomic_path(entry) as tmp:
                    with open(tmp, "wb") as fh:
                        np.savez(fh, mip=mip)
        out.append({"capture": name, "fraction": float(f), "photons": float(counts.sum()),
                    "mip": mip})
        if progress is not None:
            progress(len(out), len(fractions))
    return out


def real_thinning(cdt: Path, grid: StudyGrid, predict_proba, *,
                  fractions=THINNING_FRACTIONS, progress=None, **kw) -> list[dict]:
    """:func:`thinned_mips` of every shared capture in ``cdt`` (``kw``: its seed, cache and
    device), each row with ``p_legible``: the classifier's ``predict_proba`` of its MIP.
    ``progress(done, total)`` counts the reconstructions of all the captures."""
    paths = [Path(cdt) / f"{n}.mat" for n in PUBLISHED_SCAN_WIDTH_M]
    paths = [p for p in paths if p.is_file()]
    total = len(paths) * len(fractions)
    rows = []
    for k, path in enumerate(paths):
        step = None if progress is None else (
            lambda done, _n, k=k: progress(k * len(fractions) + done, total))
        rows += thinned_mips(path, grid, fractions=fractions, progress=step, **kw)
    if rows:
        p = predict_proba(np.stack([r["mip"] for r in rows]))
        for r, v in zip(rows, p, strict=True):
            r["p_legible"] = float(v)
    return rows


def thinning_figure(rows: list[dict], scan_width_m: dict | None = None):
    """Per capture a row of its thinned reconstructions' MIPs (axes in m over the published
    scan, a colour bar), P(legible) and the photons under each; beside them P(legible)
    against photons per capture (log axis)."""
    widths = scan_width_m or PUBLISHED_SCAN_WIDTH_M
    names = list(dict.fromkeys(r["capture"] for r in rows))
    ncol = max(sum(r["capture"] == n for r in rows) for n in names)
    fig, ax = new_figure(len(names), ncol + 1, (2.3 * (ncol + 1) + 1.5, 2.6 * len(names)))
    ax = np.asarray(ax).reshape(len(names), ncol + 1)
    for i, n in enumerate(names):
        rs = [r for r in rows if r["capture"] == n]
        w = widths.get(n, 1.0)
        for j in range(ncol):
            a = ax[i, j]
            if j >= len(rs):
                a.axis("off")
                continue
            r = rs[j]
            im = a.imshow(r["mip"], origin="lower", cmap="gray", vmin=0, vmax=1,
                          extent=(-w / 2, w / 2, -w / 2, w / 2))
            a.set_title(f"{n} {r['fraction']:.3g}\n{r['photons']:.2g} photons", fontsize=8)
            a.set_xlabel(f"x (m)\nP(legible) = {r['p_legible']:.2f}", fontsize=9,
                         color="tab:green" if r["p_legible"] >= 0.5 else "tab:red")
            if j == 0:
                a.set_ylabel("y (m)")
            a.tick_params(labelsize=7)
        fig.colorbar(im, ax=ax[i, len(rs) - 1], label="MIP / max", shrink=0.8)
    gs = ax[0, ncol].get_gridspec()
    for a in ax[:, ncol]:
        a.remove()
    curve = fig.add_subplot(gs[:, ncol])
    for n in names:
        rs = [r for r in rows if r["capture"] == n]
        curve.semilogx([r["photons"] for r in rs], [r["p_legible"] for r in rs], "o-",
                       label=n)
    curve.axhline(0.5, color="gray", ls=":", label="P = 0.5")
    curve.set(xlabel="photons per capture", ylabel="P(legible)", ylim=(0, 1),
              title="P(legible) against photons")
    curve.legend(fontsize=8)
    return fig
