"""The legibility judge on real captures: the family split (trained on simulations only,
tested on every real capture's thinning ladder) and the judge applied to any capture file.

A real capture is reconstructed with the judge's recipe
(:func:`clnlos.study.judge.recipe.judge_config`: the capture's own geometry and recorded
slab, and what a user would give for a shared CDT capture, whose files store neither its
scan width nor its slab: :func:`real_options`) together with two binomial halves of its
photons, at each rung of a nested binomial thinning (:data:`REAL_FRACTIONS`, down to where
the image is noise); optionally also with ``clnlos reconstruct``'s defaults, the volume a
user would judge.

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
from clnlos.inverse.pipeline import reconstruct
from clnlos.io.files import read_capture
from clnlos.runtime.device import get_queue
from clnlos.study.judge.heldout import balanced_accuracy, roc_auc
from clnlos.study.judge.features import (
    capture_features,
    mip_features,
    mip_of,
    pearson_r,
    pooled,
)
from clnlos.study.real.capture import PUBLISHED_SCAN_WIDTH_M, capture_config
from clnlos.study.judge.recipe import (
    JUDGE_MAX_POINTS,
    JUDGE_METHOD,
    USER_FIELDS,
    binned_laterally,
    capture_descriptors,
    judge_config,
    judge_reconstructions,
)
from clnlos.study.real.thinning import thinned_series

REAL_FRACTIONS = (1.0, 0.3, 0.1, 0.03, 0.01, 3e-3, 1e-3, 1e-4)
REAL_SEED = 48
REFERENCE_AGREEMENT = 0.8   # r(thinned MIP, full MIP) at least this: legible (reference)
REFERENCE_GONE = 0.3        # below this: the image is gone (reference)
FAMILIES = ("cdt", "lct")


def real_options(family: str, path) -> ReconstructionConfig | None:
    """What a user would give the judge for a shared capture (the study knows which one it
    reads): a CDT capture's published scan width, window and slab (its data README's
    table, :func:`clnlos.study.real.capture.capture_config`: the file stores none of them);
    nothing for the LCT release (its files store their geometry)."""
    return capture_config(Path(path).stem, JUDGE_METHOD) if family == "cdt" else None


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
                 device=None, family: str = "", options: ReconstructionConfig | None = None,
                 default_volumes: bool = False) -> list[dict]:
    """Rows ``{"capture", "family", "fraction", "photons", "features", "descriptors",
    "p_legible", "interval", "notes", "p_volume", "agreement", "reference", "mip"}`` of the
    capture at ``path`` thinned to ``fractions`` (:func:`ladder_views` judged by
    :func:`judged_rows`)."""
    return judged_rows(ladder_views(path, fractions, seed, device, family, options,
                                    default_volumes,
                                    judge.recipe.get("max_points", JUDGE_MAX_POINTS),
                                    judge.recipe), judge)


def ladder_views(path, fractions=REAL_FRACTIONS, seed: int = REAL_SEED, device=None,
                 family: str = "", options: ReconstructionConfig | None = None,
                 default_volumes: bool = False, most: int = JUDGE_MAX_POINTS,
                 recipe: dict | None = None) -> list[dict]:
    """What any judge reads of the capture at ``path`` thinned to ``fractions`` (its scan
    points thinned, then summed as the recipe sums them; ``options``: what a user would
    give, by default :func:`real_options`): per rung its features, descriptors, the
    reconstruction's MIP (``mip``), its agreement with the full-photon one's and the
    reference label; with ``default_volumes`` also each rung's default LCT reconstruction
    (``clnlos reconstruct`` with the options alone: ``mip_default``, ``features_default``,
    ``agreement_default`` with the full-photon one's)."""
    queue = get_queue(device)
    raw = read_capture(path)
    options = real_options(family, path) if options is None else options
    cfg = judge_config(binned_laterally(raw, most), options, recipe)
    default = default_config(options)
    rows, first = [], {}
    for f, counts in zip(fractions, thinned_series(raw.transient, fractions, seed),
                         strict=True):
        cap = binned_laterally(replace(raw, transient=counts), most)
        full, h1, h2 = judge_reconstructions(cap, cfg, queue)
        mip = mip_of(full)
        first.setdefault("mip", mip)
        agree = pearson_r(mip, first["mip"])
        row = {"capture": Path(path).stem, "family": family, "fraction": float(f),
               "photons": float(counts.sum()), "features": capture_features(full, h1, h2),
               "descriptors": capture_descriptors(cap, cfg), "agreement": agree,
               "reference": reference_label(agree), "mip": mip.astype(np.float32)}
        if default_volumes:
            vol = reconstruct(replace(raw, transient=counts), default, device=queue).volume
            dm = pooled(mip_of(vol), most)
            first.setdefault("default", dm)
            agree_d = pearson_r(dm, first["default"])
            row.update(features_default=mip_features(dm), agreement_default=agree_d,
                       reference_default=reference_label(agree_d),
                       mip_default=dm.astype(np.float32))
        rows.append(row)
    return rows


def judged_rows(rows: list[dict], judge) -> list[dict]:
    """:func:`ladder_views` rows with ``judge``'s verdicts: the capture model's
    (``p_legible``, ``interval``, ``notes``), the volume model's on the judge's own
    reconstruction (``p_volume``) and, where the rows hold it, on the default one
    (``p_default``, ``interval_default``, ``notes_default``)."""
    out = []
    for r in rows:
        a = judge.assess("capture", r["features"], r["descriptors"])
        row = {**r, "p_legible": a.p, "interval": a.interval, "notes": a.notes,
               "p_volume": judge.assess("volume", mip_features(r["mip"])).p}
        if "features_default" in r:
            v = judge.assess("volume", r["features_default"],
                             {"points": int(max(r["mip_default"].shape))})
            row.update(p_default=v.p, interval_default=v.interval, notes_default=v.notes)
        out.append(row)
    return out


def default_config(options: ReconstructionConfig | None) -> ReconstructionConfig:
    """``clnlos reconstruct``'s defaults (LCT) with a user's ``options`` (their geometry and
    slab)."""
    kw = {} if options is None else {k: getattr(options, k) for k in USER_FIELDS
                                     if getattr(options, k) is not None}
    return ReconstructionConfig(method=JUDGE_METHOD, **kw).validate()


def family_split(root, judge, fractions=REAL_FRACTIONS, device=None,
                 progress=None, default_volumes: bool = False) -> list[dict]:
    """:func:`judge_ladder` of every real capture under ``root``; ``progress(done, total)``
    after each capture. A capture clnlos cannot read is skipped with its reason."""
    paths = real_capture_paths(root)
    rows = []
    for k, (fam, p) in enumerate(paths):
        try:
            rows += judge_ladder(p, judge, fractions, device=device, family=fam,
                                 default_volumes=default_volumes)
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
