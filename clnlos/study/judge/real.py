"""The legibility judge on real captures: the family split (trained on simulations only,
tested on every real capture's thinning ladder) and the judge applied to any capture file.

A real capture is reconstructed with the judge's recipe (:func:`judge_config`: the
published scan width, window and slab of a shared CDT capture, the capture's own geometry and
recorded slab otherwise, its time axis rebinned to at most JUDGE_MAX_BINS, its scan
points summed to at most JUDGE_MAX_POINTS a side (:func:`binned_laterally`); the recipe's
method and SNR rule) together with two binomial halves
of its photons, at each rung of a nested binomial thinning (:data:`REAL_FRACTIONS`, down to
where the image is noise).

The reference label (testing only, never training). A real capture has no template; its
published reconstruction shows its content plainly at full photons, so the full-photon
reconstruction stands in for the truth: a thinned rung is *legible (reference)* when its MIP
agrees with the full-photon MIP at least REFERENCE_AGREEMENT in Pearson correlation over the
scan cells, and *gone* below REFERENCE_GONE (between the two: undecided, not scored). The
full-photon rung is legible by this definition; the rule checks the judge's fall with
photons, not whether the capture itself is legible.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from clnlos.config import ReconstructionConfig
from clnlos.inverse.preprocessing import setup_slab
from clnlos.io.files import read_capture
from clnlos.runtime.device import get_queue
from clnlos.study.judge.heldout import balanced_accuracy, roc_auc
from clnlos.study.judge.features import capture_features, feature_matrix, mip_of, pearson_r
from clnlos.study.real.capture import PUBLISHED_SCAN_WIDTH_M, capture_config
from clnlos.study.real.thinning import thinned_series
from clnlos.study.judge.twins import JUDGE_MAX_BINS, JUDGE_MAX_POINTS, judge_reconstructions

REAL_FRACTIONS = (1.0, 0.3, 0.1, 0.03, 0.01, 3e-3, 1e-3, 1e-4)
REAL_SEED = 48
REFERENCE_AGREEMENT = 0.8   # r(thinned MIP, full MIP) at least this: legible (reference)
REFERENCE_GONE = 0.3        # below this: the image is gone (reference)
FAMILIES = ("cdt", "lct")


def judge_config(capture, path, recipe: dict) -> ReconstructionConfig:
    """How the judge reconstructs ``capture`` (read from ``path``): a shared CDT capture
    with its published settings, any other with its own geometry and recorded slab."""
    name = Path(path).stem if path is not None else ""
    if name in PUBLISHED_SCAN_WIDTH_M:
        return capture_config(name, recipe["method"], snr_rule=recipe["snr_rule"])
    nt = np.asarray(capture.transient).shape[0]
    most = int(recipe.get("max_bins", JUDGE_MAX_BINS))
    cfg = ReconstructionConfig(method=recipe["method"], snr_rule=recipe["snr_rule"],
                               bins=most if nt > most else None).validate()
    return setup_slab(cfg, capture)[0]


def binned_laterally(capture, most: int = JUDGE_MAX_POINTS):
    """The capture with its scan points summed in k x k blocks (photon counts kept), k the
    smallest integer that leaves at most ``most`` points per side (unchanged for k = 1 or
    a capture whose columns were shifted by its reader)."""
    t = np.asarray(capture.transient)
    k = -(-max(t.shape[1:]) // most)
    if k <= 1 or capture.time_shift_bins is not None:
        return capture
    ny, nx = (t.shape[1] // k) * k, (t.shape[2] // k) * k
    b = t[:, :ny, :nx].reshape(t.shape[0], ny // k, k, nx // k, k).sum(axis=(2, 4))
    w = None if capture.scan_width_m is None else capture.scan_width_m * nx / t.shape[2]
    h = None if capture.scan_height_m is None else capture.scan_height_m * ny / t.shape[1]
    return replace(capture, transient=b.astype(t.dtype), scan_width_m=w, scan_height_m=h)


def real_capture_paths(root) -> list[tuple[str, Path]]:
    """(family, path) of every real capture under ``root`` (its cdt/ and lct/ .mat files)."""
    out = []
    if root is None:
        return out
    for fam in FAMILIES:
        d = Path(root) / fam
        if d.is_dir():
            out += [(fam, p) for p in sorted(d.glob("*.mat"))
                    if fam != "cdt" or p.stem in PUBLISHED_SCAN_WIDTH_M]
    return out


def reference_label(agreement: float) -> str:
    """The reference label of a rung from its agreement with the full-photon MIP."""
    if agreement >= REFERENCE_AGREEMENT:
        return "legible"
    return "gone" if agreement < REFERENCE_GONE else "undecided"


def judge_ladder(path, judge, fractions=REAL_FRACTIONS, seed: int = REAL_SEED,
                 device=None, family: str = "") -> list[dict]:
    """Rows ``{"capture", "family", "fraction", "photons", "features", "p_legible",
    "p_volume", "agreement", "reference", "mip"}`` of the capture at ``path`` thinned to ``fractions``."""
    queue = get_queue(device)
    cap = binned_laterally(read_capture(path), judge.recipe.get("max_points",
                                                              JUDGE_MAX_POINTS))
    cfg = judge_config(cap, path, judge.recipe)
    rows, full_mip = [], None
    for f, counts in zip(fractions, thinned_series(cap.transient, fractions, seed),
                         strict=True):
        full, h1, h2 = judge_reconstructions(replace(cap, transient=counts), cfg, queue)
        mip = mip_of(full)
        full_mip = mip if full_mip is None else full_mip
        agree = pearson_r(mip, full_mip)
        feats = capture_features(full, h1, h2)
        rows.append({"capture": Path(path).stem, "family": family, "fraction": float(f),
                     "photons": float(counts.sum()), "features": feats,
                     "p_legible": float(judge.capture.predict_proba(
                         feature_matrix([feats], judge.capture.features))[0]),
                     "p_volume": float(judge.volume_proba([full])[0]),
                     "agreement": agree, "reference": reference_label(agree),
                     "mip": mip.astype(np.float32)})
    return rows


def family_split(root, judge, fractions=REAL_FRACTIONS, device=None,
                 progress=None) -> list[dict]:
    """:func:`judge_ladder` of every real capture under ``root``; ``progress(done, total)``
    after each capture. A capture clnlos cannot read is skipped with its reason."""
    paths = real_capture_paths(root)
    rows = []
    for k, (fam, p) in enumerate(paths):
        try:
            rows += judge_ladder(p, judge, fractions, device=device, family=fam)
        except Exception as exc:  # noqa: BLE001 - an unreadable capture is reported, not fatal
            rows.append({"capture": p.stem, "family": fam, "error": str(exc).splitlines()[0]})
        if progress is not None:
            progress(k + 1, len(paths))
    return rows


def family_scores(rows: list[dict], tolerance: float = 0.05) -> dict:
    """Per capture: P at full photons, the largest rise of P as photons fall, P at the first
    'gone' rung, and whether the issue's bar holds (P >= 0.8 at full photons, no rise above
    ``tolerance``, P < 0.5 wherever the reference says gone); and the balanced accuracy of
    P >= 1/2 against the reference label over the decided rungs."""
    out, ys, ps = {}, [], []
    for cap in dict.fromkeys(r["capture"] for r in rows):
        rs = [r for r in rows if r["capture"] == cap]
        if "error" in rs[0]:
            out[cap] = {"error": rs[0]["error"]}
            continue
        p = [r["p_legible"] for r in rs]
        rise = max((b - a for a, b in zip(p, p[1:], strict=False)), default=0.0)
        gone = [r for r in rs if r["reference"] == "gone"]
        out[cap] = {"family": rs[0]["family"], "p_full": p[0], "largest_rise": max(rise, 0.0),
                    "p_first_gone": gone[0]["p_legible"] if gone else None,
                    "fraction_first_gone": gone[0]["fraction"] if gone else None,
                    "passes": bool(p[0] >= 0.8 and rise <= tolerance
                                   and all(r["p_legible"] < 0.5 for r in gone))}
        for r in rs:
            if r["reference"] != "undecided":
                ys.append(r["reference"] == "legible")
                ps.append(r["p_legible"])
    y, pr = np.array(ys, bool), np.array(ps)
    return {"captures": out,
            "balanced_accuracy": balanced_accuracy(y, pr >= 0.5) if len(y) else None,
            "auc": roc_auc(y, pr) if len(y) else None, "n_decided": int(len(y)),
            "reference": {"legible_at_least": REFERENCE_AGREEMENT,
                          "gone_below": REFERENCE_GONE}}
