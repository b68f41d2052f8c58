"""The "auto" reconstruction parameters against an oracle that knows the truth.

For simulated captures (Lambertian shapes through the CDT slab, photon noise), each method
is run with its default "auto" SNRs (on these captures of their own slab: LCT and f-k by
split-half reproducibility, :mod:`clnlos.inverse.reproducibility`; the GCV rule,
:mod:`clnlos.inverse.gcv`, for the iterative method -- thinning,
:mod:`clnlos.inverse.thinning`, by name -- and elsewhere), with the photon rule the auto SNRs
replaced (SNR = photons / K_SNR and its square root, :mod:`clnlos.inverse.snr`: "today"), and
with every setting of the grid SLAB_SNRS x INVERSION_SNRS (LCT and f-k: CLOSED_FORM_SLAB_SNRS,
which reaches past their slab floor; f-k has no light-cone SNR: the slab SNRs alone). The
iterative method's L1 weight is "auto" (from the noise, :mod:`clnlos.inverse.iterative`) in
the auto and the grid runs, today's constant FIXED_L1_WEIGHT in the "today" run, which is
also Wiener first (``slab_model = "none"``: the deconvolved transient fitted as the slab-free
one; auto and the grid fit the slab filter's influence,
:mod:`clnlos.inverse.iterative`). The oracle is the best IoU of the grid (Otsu-thresholded
MIP against the true mask, :func:`clnlos.study.score.metrics.mip_iou`); the gap is oracle minus
auto. Only the slab recorded in the capture is used, as ``clnlos reconstruct`` does with no
slab flags.

:func:`oracle_rows` gives one row per capture and method, :func:`exposure_sweep` the auto IoU
over a range of exposures and noise seeds (auto must not get worse with more photons), and
:func:`write_rows` writes either as CSV and JSON. ``tools/oracle_params.py`` runs them on
:data:`ORACLE_CASES` and :data:`SWEEP_EXPOSURES_S`. :func:`grid_rows` keeps every grid
setting's IoU and :func:`transfer_rows` asks of them whether the oracle's lead over auto is
the truth fitting one noise draw or a setting the capture itself calls for.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from clnlos.bench.harness import rows_document
from clnlos.config import ReconstructionConfig, slab_table
from clnlos.forward.model import ForwardModel
from clnlos.forward.scene import Scene
from clnlos.inverse.iterative import FIXED_L1_WEIGHT
from clnlos.inverse.methods import method_class, method_names
from clnlos.inverse.pipeline import reconstruct
from clnlos.inverse.reproducibility import SLAB_SNRS_SLAB_ONLY as REPRODUCIBILITY_SLAB_SNRS
from clnlos.inverse.snr import combined_snr, lightcone_snr
from clnlos.io.files import atomic_path
from clnlos.physics.slab import CDT_SLAB
from clnlos.study.score.metrics import mip_iou, truth_mask

SLAB_SNRS = (1e2, 1e3, 1e4, 1e5)  # the grid, the iterative method's
# LCT and f-k: under the GCV rule slab SNRs of at least CLOSED_FORM_SLAB_SNR_MIN, by
# reproducibility from 1e5 to 1e8 (f-k): their grid reaches the top of those candidates
CLOSED_FORM_SLAB_SNRS = SLAB_SNRS + tuple(s for s in REPRODUCIBILITY_SLAB_SNRS
                                          if s > SLAB_SNRS[-1])
INVERSION_SNRS = (1e2, 1e3, 1e4)
METHODS = tuple(sorted(method_names(), key=lambda m: m != "iterative"))  # iterative first
# 1e7 to 1e12 photons at the seed geometry: past 1e12 the photon rule reached its cap
SWEEP_EXPOSURES_S = (0.01, 0.1, 1.0, 10.0, 100.0, 1000.0)
MONOTONE_FLOOR = 0.02  # IoU steps below this count as unchanged (2-5 pixels of a 16 x 16 mask)


@dataclass(frozen=True)
class OracleCase:
    """A simulated capture: ``shape`` "UT" (letters of ``size_m`` height, strokes 0.27 of
    it), "S" (a letter likewise) or "plus" (bars 0.3 of ``size_m`` wide) at ``depth_m``
    behind the CDT slab, a ``points`` x ``points`` scan of ``scan_width_m``, ``bins`` bins of
    ``bin_width_s`` from t = 0, the detector of ``examples/scene_ut_wide_noisy.toml`` with
    ``exposure_s``; noise ``seed``."""

    name: str
    shape: str
    size_m: float
    depth_m: float
    scan_width_m: float
    exposure_s: float
    seed: int = 0
    points: int = 32
    bins: int = 256
    bin_width_s: float = 32e-12

    def objects(self) -> list[dict]:
        z = [0.0, 0.0, self.depth_m]
        if self.shape == "plus":
            b = 0.3 * self.size_m
            return [{"shape": "rectangle", "size_m": [self.size_m, b], "translate_m": z},
                    {"shape": "rectangle", "size_m": [b, self.size_m], "translate_m": z}]
        return [{"shape": "letters", "text": self.shape, "height_m": self.size_m,
                 "stroke_m": 0.27 * self.size_m, "translate_m": z}]

    def scene_dict(self) -> dict:
        return {"seed": self.seed,
                "scan": {"width_m": self.scan_width_m, "points": self.points},
                "time": {"bin_width_s": self.bin_width_s, "bins": self.bins, "start_s": 0.0},
                "objects": self.objects(), "slab": slab_table(CDT_SLAB),
                "laser": {"pulse_width_s": 35e-12},
                "sampling": {"density_per_m2": 4e4},
                "detector": {"power_w": 0.4, "rep_rate_hz": 10e6,
                             "exposure_s": self.exposure_s, "efficiency": 0.3,
                             "wavelength_m": 532e-9, "etendue_m2_sr": 1e-9,
                             "dark_count_rate_hz": 1e3}}


# exposures over 2.7 decades (1e7 to 6e9 photons), scans 0.3-0.7 m, depths 0.4-0.8 m,
# three shapes; 256 bins of 32 ps (8.2 ns) end well after the deepest return has decayed
ORACLE_CASES = (
    # the seed geometry below the others' photon range (1e7 and 1e8 photons): where LCT's
    # auto SNRs fell below the photon rule
    # (tools/results/experiments/lct_low_exposure/lct_low_exposure*.csv)
    OracleCase("UT 0.15 m, scan 0.3 m, 0.5 m deep, 0.01 s", "UT", 0.15, 0.5, 0.3, 0.01),
    OracleCase("UT 0.15 m, scan 0.3 m, 0.5 m deep, 0.1 s", "UT", 0.15, 0.5, 0.3, 0.1),
    OracleCase("UT 0.15 m, scan 0.3 m, 0.5 m deep, 0.05 s", "UT", 0.15, 0.5, 0.3, 0.05),
    OracleCase("UT 0.15 m, scan 0.3 m, 0.5 m deep, 0.5 s", "UT", 0.15, 0.5, 0.3, 0.5),
    OracleCase("UT 0.15 m, scan 0.3 m, 0.5 m deep, 5 s", "UT", 0.15, 0.5, 0.3, 5.0),
    OracleCase("UT 0.3 m, scan 0.6 m, 0.5 m deep, 0.5 s", "UT", 0.3, 0.5, 0.6, 0.5),
    OracleCase("plus 0.25 m, scan 0.5 m, 0.7 m deep, 0.5 s", "plus", 0.25, 0.7, 0.5, 0.5),
    OracleCase("S 0.35 m, scan 0.7 m, 0.4 m deep, 0.05 s", "S", 0.35, 0.4, 0.7, 0.05),
    OracleCase("UT 0.25 m, scan 0.45 m, 0.8 m deep, 5 s", "UT", 0.25, 0.8, 0.45, 5.0),
    # examples/scene_ut_wide_noisy.toml (issue 24's "wide UT": 512 bins of 16 ps)
    OracleCase("UT 0.3 m, scan 0.6 m, 0.5 m deep, 0.5 s, 16 ps", "UT", 0.3, 0.5, 0.6, 0.5,
               bins=512, bin_width_s=16e-12),
)


# captures outside the table, other glyphs, grids and bin widths (3e6-3e10 photons): the
# check of constants chosen on the table. The first eight were looked at when
# CLOSED_FORM_SLAB_SNR_MIN was chosen (clnlos.inverse.snr), the last eight only after
HOLDOUT_CASES = (
    OracleCase("H 0.2 m, scan 0.4 m, 0.6 m deep, 0.02 s", "H", 0.2, 0.6, 0.4, 0.02),
    OracleCase("X 0.25 m, scan 0.5 m, 0.45 m deep, 0.2 s", "X", 0.25, 0.45, 0.5, 0.2),
    OracleCase("LP 0.2 m, scan 0.5 m, 0.55 m deep, 2 s", "LP", 0.2, 0.55, 0.5, 2.0),
    OracleCase("E 0.15 m, scan 0.35 m, 0.4 m deep, 0.01 s", "E", 0.15, 0.4, 0.35, 0.01),
    OracleCase("plus 0.2 m, scan 0.4 m, 0.75 m deep, 1 s", "plus", 0.2, 0.75, 0.4, 1.0),
    OracleCase("T 0.3 m, scan 0.65 m, 0.65 m deep, 0.05 s", "T", 0.3, 0.65, 0.65, 0.05),
    OracleCase("U 0.12 m, scan 0.3 m, 0.6 m deep, 0.03 s", "U", 0.12, 0.6, 0.3, 0.03),
    OracleCase("F 0.3 m, scan 0.6 m, 0.5 m deep, 20 s", "F", 0.3, 0.5, 0.6, 20.0),
    OracleCase("L 0.25 m, scan 0.45 m, 0.7 m deep, 0.01 s", "L", 0.25, 0.7, 0.45, 0.01),
    OracleCase("HI 0.2 m, scan 0.55 m, 0.5 m deep, 0.3 s", "HI", 0.2, 0.5, 0.55, 0.3),
    OracleCase("P 0.3 m, scan 0.6 m, 0.8 m deep, 0.1 s", "P", 0.3, 0.8, 0.6, 0.1),
    OracleCase("plus 0.3 m, scan 0.7 m, 0.45 m deep, 0.02 s", "plus", 0.3, 0.45, 0.7, 0.02),
    OracleCase("C 0.2 m, scan 0.4 m, 0.5 m deep, 3 s, 24 points", "C", 0.2, 0.5, 0.4, 3.0,
               points=24),
    OracleCase("UT 0.2 m, scan 0.35 m, 0.45 m deep, 0.005 s", "UT", 0.2, 0.45, 0.35, 0.005),
    OracleCase("Y 0.25 m, scan 0.5 m, 0.6 m deep, 0.05 s, 48 ps", "Y", 0.25, 0.6, 0.5, 0.05,
               bins=192, bin_width_s=48e-12),
    OracleCase("K 0.3 m, scan 0.6 m, 0.4 m deep, 1 s, 40 points", "K", 0.3, 0.4, 0.6, 1.0,
               points=40),
)


# the glyphs random_cases draws from: letters none of the table's or the held-out captures
# spell, two pairs, and the '+' (whose bars both sets have at other sizes and depths)
RANDOM_GLYPHS = tuple("ADGJMNORVWZ") + ("NO", "AV", "plus")


def random_cases(seed: int, count: int = 16) -> list[OracleCase]:
    """``count`` captures drawn with numpy's generator ``seed``, for checks on captures no
    constant was chosen on: a glyph of RANDOM_GLYPHS, scan 0.3-0.7 m, glyph height 0.35-0.65
    of the scan, depth 0.4-0.8 m, exposure 5 ms-20 s (log-uniform; about 3e6-3e10 photons),
    24, 32 or 40 scan points, 256 bins of 32 ps or 192 of 48 ps. The name spells it out."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        glyph = RANDOM_GLYPHS[rng.integers(len(RANDOM_GLYPHS))]
        scan = float(np.round(rng.uniform(0.3, 0.7), 2))
        size = float(np.round(rng.uniform(0.35, 0.65) * scan, 2))
        depth = float(np.round(rng.uniform(0.4, 0.8), 2))
        exposure = float(f"{10 ** rng.uniform(math.log10(0.005), math.log10(20.0)):.2g}")
        points = int(rng.choice([24, 32, 32, 40]))
        bin_width = float(rng.choice([32e-12, 32e-12, 48e-12]))
        bins = 256 if bin_width == 32e-12 else 192
        name = (f"random {glyph} {size} m, scan {scan} m, {depth} m deep, {exposure} s, "
                f"{points} points, {bin_width * 1e12:.0f} ps")
        out.append(OracleCase(name, glyph, size, depth, scan, exposure, points=points,
                              bins=bins, bin_width_s=bin_width))
    return out


def case_named(name: str) -> OracleCase:
    """The case of :data:`ORACLE_CASES` (or :data:`HOLDOUT_CASES`) called ``name`` (cases
    are referred to by name, not by position: the table grows)."""
    for c in ORACLE_CASES + HOLDOUT_CASES:
        if c.name == name:
            return c
    raise KeyError(f"no oracle case {name!r}")


SWEEP_CASE = "UT 0.15 m, scan 0.3 m, 0.5 m deep, 0.05 s"  # the exposure sweep's scene
BENCH_CASE = "UT 0.3 m, scan 0.6 m, 0.5 m deep, 0.5 s"    # clnlos bench's (reduced) case


def simulate_case(case: OracleCase, queue=None):
    """(capture, true mask [y, x]) of a case (:class:`clnlos.forward.model.ForwardModel`)."""
    scene = Scene.from_dict(case.scene_dict())
    fm = ForwardModel(scene, queue=queue)
    return fm.capture(), truth_mask(fm.samples.elements, scene.scan_centres())


def _run(capture, mask, config: ReconstructionConfig, queue) -> tuple[float, dict]:
    rec = reconstruct(capture, config, device=queue)
    return mip_iou(rec.volume, mask)[0], rec


def grid_settings(method: str) -> list[tuple[float, float]]:
    """The (slab SNR, light-cone SNR) settings the oracle tries (f-k: the slab SNR only)."""
    inv = INVERSION_SNRS if method != "fk" else INVERSION_SNRS[:1]
    slab = SLAB_SNRS if method_class(method).slab_snr_min is None else CLOSED_FORM_SLAB_SNRS
    return [(a, b) for a in slab for b in inv]


def grid_ious(capture, mask, base: ReconstructionConfig, method: str, queue=None
              ) -> list[tuple[float, float, float]]:
    """(slab SNR, light-cone SNR, IoU) for every setting of :func:`grid_settings` (``base``:
    the config the settings replace the SNRs of), in the grid's order."""
    return [(a, b, _run(capture, mask, base.replace(snr=a, inversion_snr=b).validate(),
                        queue)[0]) for a, b in grid_settings(method)]


def compare_method(capture, mask, method: str, *, iterations: int | None = None,
                   grid: bool = True, queue=None) -> dict:
    """auto, today's photon rule and the oracle grid for one capture and method: a row
    with the IoUs, the parameters each used, gap = oracle - auto and
    vs_today = auto - today (``grid=False``: auto and today only, the oracle's fields
    None)."""
    kw = {} if iterations is None else {"iterations": iterations}
    base = ReconstructionConfig(slab=capture.recorded_slab()[0], method=method, **kw)
    auto_iou, rec = _run(capture, mask, base.validate(), queue)
    row = {"method": method, "photons": float(np.sum(capture.transient, dtype=np.float64)),
           "auto_iou": auto_iou, "auto_snr": rec.params.get("snr_used"),
           "auto_inversion_snr": rec.params.get("inversion_snr_used")}
    old = combined_snr(rec.noise["snr"], rec.params.get("model_snr_used", float("inf")))
    old_inv = lightcone_snr(old)
    today = base.replace(snr=old, inversion_snr=old_inv)
    row["auto_snr_rule"] = rec.params.get("snr_rule_used", "gcv")
    if method == "iterative":  # today's constant L1 weight (auto: from the noise), Wiener first
        today = today.replace(l1_weight=FIXED_L1_WEIGHT, slab_model="none")
        row["auto_l1_weight"] = rec.params.get("l1_weight_used")
        row["auto_thinning_factor"] = rec.params.get("thinning_factor")  # None: GCV's pick
    if row["auto_snr_rule"] == "reproducibility":  # and the GCV rule it replaced
        row["auto_kappa"] = rec.params.get("reproducibility_kappa")
        row["gcv_rule_iou"] = _run(capture, mask, base.replace(snr_rule="gcv").validate(),
                                   queue)[0]
    if rec.params.get("slab_snr_raised"):  # the method's rule raised GCV's pick: without it
        row["auto_gcv_slab_iou"] = _run(capture, mask, base.replace(
            snr=combined_snr(rec.params["snr_data"], rec.params["model_snr_used"])
        ).validate(), queue)[0]
    elif "slab_snr_raised" in rec.params:  # a rule that left GCV's pick: the same one
        row["auto_gcv_slab_iou"] = auto_iou
    row["today_iou"] = _run(capture, mask, today.validate(), queue)[0]
    row["today_snr"], row["today_inversion_snr"] = old, old_inv if method != "fk" else None
    row["vs_today"] = auto_iou - row["today_iou"]
    if not grid:
        return {**row, "oracle_iou": None, "oracle_snr": None, "oracle_inversion_snr": None,
                "gap": None}
    a, b, v = max(grid_ious(capture, mask, base, method, queue), key=lambda t: t[2])  # first best
    row["oracle_iou"], row["oracle_snr"] = v, a
    row["oracle_inversion_snr"] = b if method != "fk" else None
    row["gap"] = row["oracle_iou"] - auto_iou
    row["vs_today"] = row.pop("vs_today")  # the column after gap, as before
    return row


def oracle_rows(cases=ORACLE_CASES, methods=METHODS, *, iterations: int | None = None,
                seeds=None, grid: bool = True, queue=None, progress=print) -> list[dict]:
    """One row per case and method (:func:`compare_method`), with the case's name; with
    ``seeds``, one per case, noise seed and method, the seed in the row."""
    rows = []
    for case in cases:
        for s in (None,) if seeds is None else seeds:
            c = case if s is None else replace(case, seed=int(s))
            capture, mask = simulate_case(c, queue)
            for m in methods:
                row = {"capture": case.name, **({} if s is None else {"seed": c.seed}),
                       **compare_method(capture, mask, m, iterations=iterations,
                                        grid=grid, queue=queue)}
                rows.append(row)
                if progress:
                    oracle = "-" if row["oracle_iou"] is None else f"{row['oracle_iou']:.3f}"
                    progress(f"{case.name}{'' if s is None else f' seed {s}'} [{m}]: auto "
                             f"{row['auto_iou']:.3f}, oracle {oracle}, today "
                             f"{row['today_iou']:.3f}")
    return rows


def grid_rows(cases, seeds, methods=("lct", "fk"), *, iterations: int | None = None,
              queue=None, progress=print) -> list[dict]:
    """Every setting the oracle tries, kept (:func:`compare_method` keeps only the best):
    per case, noise seed and method one row for the auto run (``setting`` "auto", the SNRs
    it chose) and one per grid setting (:func:`grid_settings`), with its IoU. The input of
    :func:`transfer_rows`."""
    kw = {} if iterations is None else {"iterations": iterations}
    rows = []
    for case in cases:
        for s in seeds:
            capture, mask = simulate_case(replace(case, seed=int(s)), queue)
            for m in methods:
                base = ReconstructionConfig(slab=capture.recorded_slab()[0], method=m, **kw)
                v, rec = _run(capture, mask, base.validate(), queue)
                mine = [{"setting": "auto", "snr": rec.params.get("snr_used"),
                         "inversion_snr": rec.params.get("inversion_snr_used"), "iou": v}]
                mine += [{"setting": "grid", "snr": a,
                          "inversion_snr": b if m != "fk" else None, "iou": iou}
                         for a, b, iou in grid_ious(capture, mask, base, m, queue)]
                rows += [{"capture": case.name, "seed": int(s), "method": m, **r}
                         for r in mine]
                if progress:
                    best = max(r["iou"] for r in mine[1:])
                    progress(f"{case.name} seed {s} [{m}]: auto {v:.3f}, oracle {best:.3f}")
    return rows


def transfer_rows(rows: list[dict]) -> list[dict]:
    """Is the oracle's lead noise luck? Per capture, method and seed of :func:`grid_rows`
    (captures with at least two seeds): the oracle (this seed's best grid IoU and its
    setting), the transferred setting (the grid setting of the best mean IoU over the
    *other* seeds: the best fixed choice for this capture that has not seen this seed's
    noise) and its IoU on this seed, and auto's. ``gap`` = oracle - auto;
    ``transfer_gap`` = oracle - transferred, the part of the gap a rule blind to the truth
    cannot be expected to close (the oracle fitting this noise draw);
    ``auto_vs_transfer`` = transferred - auto, the part a better rule could recover."""
    def key(r):
        return r["snr"], r["inversion_snr"]

    groups: dict = {}
    for r in rows:
        groups.setdefault((r["capture"], r["method"]), {}).setdefault(r["seed"], []).append(r)
    out = []
    for (cap, m), by_seed in groups.items():
        if len(by_seed) < 2:
            continue
        grids = {s: {key(r): r["iou"] for r in rs if r["setting"] == "grid"}
                 for s, rs in by_seed.items()}
        for s, rs in sorted(by_seed.items()):
            auto = next(r for r in rs if r["setting"] == "auto")
            others = [g for t, g in grids.items() if t != s]
            moved = max(grids[s], key=lambda k: float(np.mean([g[k] for g in others])))
            best = max(grids[s], key=grids[s].get)
            oracle, transferred = grids[s][best], grids[s][moved]
            out.append({"capture": cap, "method": m, "seed": s, "auto_iou": auto["iou"],
                        "auto_snr": auto["snr"], "auto_inversion_snr": auto["inversion_snr"],
                        "oracle_iou": oracle, "oracle_snr": best[0],
                        "oracle_inversion_snr": best[1], "transfer_iou": transferred,
                        "transfer_snr": moved[0], "transfer_inversion_snr": moved[1],
                        "gap": oracle - auto["iou"], "transfer_gap": oracle - transferred,
                        "auto_vs_transfer": transferred - auto["iou"]})
    return out


def seed_spread(rows: list[dict]) -> list[dict]:
    """Per capture and method of :func:`oracle_rows` over several seeds: mean and spread
    (max - min over the seeds) of the auto, today and oracle IoU, of vs_today and of the
    gap; ``regression``: auto worse than today by more than 0.03 on the mean and worse on
    every seed (the seeds are paired: both rules see the same noise; a mean drop that some
    seed reverses is inside the seeds' spread, noise-seed luck)."""
    out = []
    keys = list(dict.fromkeys((r["capture"], r["method"]) for r in rows))
    for cap, m in keys:
        mine = [r for r in rows if r["capture"] == cap and r["method"] == m]
        row = {"capture": cap, "method": m, "seeds": len(mine)}
        for k in ("auto_iou", "auto_gcv_slab_iou", "gcv_rule_iou", "today_iou", "oracle_iou",
                  "gap", "vs_today"):
            # only for a method with a slab floor / whose auto rule is not GCV's
            optional = k in ("auto_gcv_slab_iou", "gcv_rule_iou")
            if any((r.get(k) if optional else r[k]) is None for r in mine):  # no grid run
                row[f"{k}_mean"] = row[f"{k}_spread"] = None
                continue
            v = np.array([r[k] for r in mine], np.float64)
            row[f"{k}_mean"], row[f"{k}_spread"] = float(v.mean()), float(np.ptp(v))
        row["vs_today_max"] = float(max(r["vs_today"] for r in mine))
        row["regression"] = bool(row["vs_today_mean"] < -0.03 and row["vs_today_max"] < 0)
        out.append(row)
    return out


def exposure_sweep(case: OracleCase, exposures=SWEEP_EXPOSURES_S, seeds=(0, 1, 2),
                   methods=METHODS, *, iterations: int | None = None, queue=None
                   ) -> list[dict]:
    """auto IoU of each method for ``case`` at each exposure and noise seed: rows of
    (method, exposure_s, photons, seed, auto_iou, auto SNRs)."""
    rows = []
    kw = {} if iterations is None else {"iterations": iterations}
    for e in exposures:
        for s in seeds:
            capture, mask = simulate_case(replace(case, exposure_s=e, seed=s), queue)
            for m in methods:
                cfg = ReconstructionConfig(slab=capture.recorded_slab()[0], method=m,
                                           **kw).validate()
                v, rec = _run(capture, mask, cfg, queue)
                rows.append({"method": m, "exposure_s": e, "seed": s,
                             "photons": float(np.sum(capture.transient, dtype=np.float64)),
                             "auto_iou": v, "auto_snr": rec.params.get("snr_used"),
                             "auto_inversion_snr": rec.params.get("inversion_snr_used")})
    return rows


def sweep_summary(rows: list[dict]) -> list[dict]:
    """Per method and exposure: mean and spread (max - min) of the auto IoU over seeds, the
    drop of the mean below the best mean at a smaller exposure, and ``monotone``: that drop
    within the larger spread of the two exposures (the noise seeds' own variation), or
    below MONOTONE_FLOOR."""
    out = []
    for m in dict.fromkeys(r["method"] for r in rows):
        best, best_spread = -np.inf, 0.0
        for e in sorted({r["exposure_s"] for r in rows if r["method"] == m}):
            v = [r["auto_iou"] for r in rows if r["method"] == m and r["exposure_s"] == e]
            mean, spread = float(np.mean(v)), float(np.max(v) - np.min(v))
            drop = max(0.0, best - mean)
            out.append({"method": m, "exposure_s": e, "mean_iou": mean, "spread": spread,
                        "drop": drop,
                        "monotone": drop <= max(spread, best_spread, MONOTONE_FLOOR)})
            if mean > best:
                best, best_spread = mean, spread
    return out


def write_rows(rows: list[dict], stem) -> tuple[Path, Path]:
    """``stem``.csv and ``stem``.json (:func:`clnlos.bench.harness.rows_document`: the rows
    with the version and commit that made them), written atomically
    (:func:`clnlos.io.files.atomic_path`)."""
    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    keys = list(dict.fromkeys(k for r in rows for k in r))
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=keys)
    w.writeheader()
    w.writerows(rows)
    paths = stem.with_suffix(".csv"), stem.with_suffix(".json")
    texts = (buf.getvalue(), json.dumps(rows_document(rows), indent=1))
    for path, text in zip(paths, texts, strict=True):
        with atomic_path(path) as tmp:
            Path(tmp).write_text(text, encoding="utf-8")
    return paths


def snr_rule_rows(cases, seeds, stored: list[dict], *, rule: str = "thinning",
                  method: str = "iterative", iterations: int | None = None, queue=None,
                  progress=print) -> list[dict]:
    """The slab SNR rule ``rule`` (``snr_rule``, :mod:`clnlos.inverse.thinning`) against the
    stored rows of :func:`oracle_rows` (``stored``: the same cases, seeds and method, made
    with GCV's pick, ``snr_rule = "gcv"``): per case and seed its IoU and chosen SNR beside
    the stored GCV rule's (``gcv_iou``), today's and the oracle's, its gap to the oracle and
    its change against today. Cases without a stored row get GCV's IoU run here and no
    oracle."""
    kw = {} if iterations is None else {"iterations": iterations}
    index = {(r["capture"], r.get("seed", 0), r["method"]): r for r in stored}
    rows = []
    for case in cases:
        for s in seeds:
            c = replace(case, seed=int(s))
            capture, mask = simulate_case(c, queue)
            base = ReconstructionConfig(slab=capture.recorded_slab()[0], method=method, **kw)
            v, rec = _run(capture, mask, base.replace(snr_rule=rule).validate(), queue)
            old = index.get((case.name, c.seed, method), {})
            # rows stored before "auto" thinned (no auto_snr_rule) are GCV's
            gcv = old.get("auto_iou") if old.get("auto_snr_rule", "gcv") == "gcv" else None
            if gcv is None:
                gcv = _run(capture, mask, base.replace(snr_rule="gcv").validate(), queue)[0]
            row = {"capture": case.name, "seed": c.seed, "method": method, "rule": rule,
                   "rule_iou": v, "rule_snr": rec.params.get("snr_used"),
                   "rule_factor": rec.params.get("thinning_factor"),
                   "rule_tried": rec.params.get("thinning_tried"),
                   "rule_time_s": float(sum(rec.timings_s.values())),
                   "gcv_iou": gcv, "gcv_snr": old.get("auto_snr"),
                   "today_iou": old.get("today_iou"), "oracle_iou": old.get("oracle_iou")}
            for k, ref in (("gap", "oracle_iou"), ("vs_today", "today_iou")):
                r = row[ref]
                row[k] = None if r is None else (r - v if k == "gap" else v - r)
            rows.append(row)
            if progress:
                progress(f"{case.name} seed {c.seed} [{method}, {rule}]: {v:.3f} (GCV "
                         f"{gcv:.3f}, oracle {row['oracle_iou']}, factor "
                         f"{row['rule_factor']})")
    return rows
