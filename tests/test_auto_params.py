"""Reconstruction parameters chosen from the data (issue 24): generalised cross-validation
for the Wiener SNRs (clnlos.inverse.gcv), against the oracle grid and across exposures
(clnlos.bench.oracle)."""

import math
from dataclasses import replace

import numpy as np
import pyopencl.array as cla
import pytest
import scipy.sparse as sp

from clnlos.bench.oracle import (
    BENCH_CASE,
    HOLDOUT_CASES,
    MONOTONE_FLOOR,
    ORACLE_CASES,
    OracleCase,
    case_named,
    compare_method,
    exposure_sweep,
    grid_rows,
    grid_settings,
    seed_spread,
    simulate_case,
    sweep_summary,
    transfer_rows,
    write_rows,
)
from clnlos.config import ReconstructionConfig
from clnlos.inverse.gcv import GcvBins, binned_power, row_counts
from clnlos.inverse.lct import LCT
from clnlos.inverse.methods import method_class
from clnlos.inverse.parameter_choice import auto_snrs
from clnlos.inverse.pipeline import reconstruct
from clnlos.inverse.reproducibility import kappa_min
from clnlos.inverse.snr import (
    K_SNR,
    MEASURED_MODEL_SNR,
    SNR_MAX,
    NoiseEstimate,
    combined_snr,
)
from clnlos.study.score.metrics import mip_iou

# 'UT' 0.3 m tall 0.5 m behind the CDT slab, a 16 x 16 scan of 0.6 m, 128 bins of 64 ps
# (8.2 ns: the return has decayed well before the window ends), ~6e8 photons: the photon
# rule's SNR (6e6) deconvolves far past what the data hold
TINY = OracleCase("tiny UT", "UT", 0.3, 0.5, 0.6, 0.5, points=16, bins=128,
                  bin_width_s=64e-12)


def _expected_power(lam_true: float):
    """A half spectrum (|H|^2, E|Y|^2, noise power) of a Gaussian blur, a signal spectrum
    falling as k^-4 and white noise, with the Wiener lam that minimises the expected
    predictive risk sum (1 - phi)^2 |H X|^2 + phi^2 N over a fine grid."""
    k = np.linspace(0.0, 1.0, 4000)
    h2 = np.exp(-(k / 0.08) ** 2)[None, None, :]
    x2 = 1e8 / (1.0 + (k / 0.01) ** 4)[None, None, :]
    noise = lam_true * 1e8 * np.ones_like(h2)
    return h2, h2 * x2 + noise, noise


@pytest.mark.parametrize("level", [1e-6, 1e-4, 1e-2])
def test_gcv_finds_the_predictive_risk_minimum(level):
    """On expected power spectra, the SNR GCV picks is within a factor 2 of the one that
    minimises the predictive risk, and it falls as the noise rises (no noise level given)."""
    h2, y2, n = _expected_power(level)
    bins = GcvBins.from_gain(h2, 2 * (h2.shape[-1] - 1))
    w = np.broadcast_to(np.where(np.arange(h2.shape[-1]) == 0, 1.0, 2.0), h2.shape)
    snrs = np.logspace(0, 10, 2001)
    lam = 1.0 / snrs[:, None]
    phi = h2.ravel()[None] / (h2.ravel()[None] + lam)
    risk = (w.ravel() * ((1 - phi) ** 2 * (y2 - n).ravel() + phi**2 * n.ravel())).sum(1)
    best = snrs[np.argmin(risk)]
    got = bins.snr(y2, 1.0, 1e10)
    assert best / 2 <= got <= best * 2, (got, best)


def test_gcv_snr_falls_with_noise_and_stays_in_range():
    snrs = [GcvBins.from_gain(h2, 7998).snr(y2, 1e2, 1e10)
            for h2, y2, _ in (_expected_power(v) for v in (1e-8, 1e-6, 1e-4))]
    assert snrs[0] > snrs[1] > snrs[2] >= 1e2
    h2 = _expected_power(1e-6)[0]
    assert GcvBins.from_gain(h2, 7998).snr(np.zeros_like(h2), 1e2, 1e10) == 1e10


@pytest.mark.parametrize("level", [1e-6, 1e-4, 1e-2])
def test_upre_finds_the_risk_minimum_under_coloured_noise(level):
    """Noise rising with frequency (as after a deconvolution): the unbiased predictive risk
    estimate with the noise spectrum given lands within a factor 1.5 of the SNR that
    minimises the expected predictive risk; GCV, which assumes white noise, lands more
    than 3x below it (too strong a filter)."""
    h2, _, _ = _expected_power(level)
    k = np.linspace(0.0, 1.0, h2.shape[-1])
    x2 = 1e8 / (1.0 + (k / 0.01) ** 4)
    noise = (level * 1e8 * (1.0 + (k / 0.1) ** 2))[None, None, :]
    y2 = h2 * x2 + noise
    bins = GcvBins.from_gain(h2, 2 * (h2.shape[-1] - 1))
    w = np.where(np.arange(h2.shape[-1]) == 0, 1.0, 2.0)
    snrs = np.logspace(0, 10, 2001)
    phi = h2.ravel()[None] / (h2.ravel()[None] + 1.0 / snrs[:, None])
    risk = (w * ((1 - phi) ** 2 * (y2 - noise).ravel() + phi**2 * noise.ravel())).sum(1)
    best = snrs[np.argmin(risk)]
    got = bins.upre_snr(y2, noise, 1.0, 1e10)
    assert best / 1.5 <= got <= best * 1.5, (got, best)
    assert bins.snr(y2, 1.0, 1e10) < best / 3


def test_auto_snrs_uses_the_data_snr_and_keeps_numbers():
    ne = NoiseEstimate(True, 1e9, 0.0, 1e9, 1.0, 1e9, 1e9 / K_SNR, None)
    auto = ReconstructionConfig()
    assert auto_snrs(ne, auto) == (1e7, math.sqrt(1e7))  # the photon rule: nothing else
    snr, inv = auto_snrs(ne, auto, MEASURED_MODEL_SNR, data_snr=3e4, data_inversion_snr=500.0)
    assert snr == pytest.approx(combined_snr(3e4, MEASURED_MODEL_SNR)) and inv == 500.0
    fixed = ReconstructionConfig(snr=2e3, inversion_snr=70.0)
    assert auto_snrs(ne, fixed, data_snr=3e4, data_inversion_snr=500.0) == (2e3, 70.0)


@pytest.fixture(scope="module")
def tiny_capture(queue):
    return simulate_case(TINY, queue)


def test_numbers_given_keep_the_constant(tiny_capture, queue):
    cap, _ = tiny_capture
    cfg = ReconstructionConfig(slab=cap.recorded_slab()[0], method="lct", snr=2e3,
                               inversion_snr=70.0).validate()
    rec = reconstruct(cap, cfg, device=queue)
    assert rec.params["snr_used"] == 2e3 and rec.params["inversion_snr_used"] == 70.0
    assert "snr_data" not in rec.params and "choose_snr" not in rec.timings_s
    assert "inversion_snr_rule" not in rec.params


def test_lightcone_snr_of_counts_from_their_noise(tiny_capture, queue):
    """Photon counts: the light-cone SNR is UPRE's with the capture's own Poisson noise
    carried through the pipeline; the same capture as non-integer data (no noise model)
    falls back to GCV. The noise realisation is seeded: the choice is reproducible."""
    cap, _ = tiny_capture
    cfg = ReconstructionConfig(slab=cap.recorded_slab()[0], method="lct",
                               snr_rule="gcv").validate()  # "auto": the halves' agreement
    a, b = (reconstruct(cap, cfg, device=queue) for _ in range(2))
    assert a.params["inversion_snr_rule"] == "upre"
    assert a.params["inversion_snr_used"] == b.params["inversion_snr_used"]
    scaled = replace(cap, transient=cap.transient.astype(np.float32) * np.float32(0.37))
    c = reconstruct(scaled, cfg, device=queue)
    assert c.params["inversion_snr_rule"] == "gcv"


def test_upre_lightcone_snr_falls_as_the_slab_snr_rises(tiny_capture, queue):
    """The light-cone UPRE adapts to the slab deconvolution before it: a deeper slab
    deconvolution (higher slab SNR) leaves more amplified noise, and the light-cone SNR
    chosen for it falls (the low-exposure diagnosis,
    tools/results/experiments/lct_low_exposure/lct_low_exposure_*: at the slab SNR the LCT
    needs, UPRE's light-cone SNR gives the oracle's IoU; at GCV's lower slab SNR it rises
    towards its cap)."""
    cap, _ = tiny_capture
    base = ReconstructionConfig(slab=cap.recorded_slab()[0], method="lct")
    inv = [reconstruct(cap, base.replace(snr=a).validate(), device=queue
                       ).params["inversion_snr_used"] for a in (1e3, 1e5, 1e7)]
    assert inv[0] >= inv[1] >= inv[2] and inv[2] < inv[0] / 3, inv


def test_oracle_cases_cover_the_low_exposure_regime():
    """The table reaches down to 1e7 photons at the seed geometry (0.01 s), where LCT's
    auto SNRs fell below the photon rule, and spans at least two decades of exposure."""
    seed = [c for c in ORACLE_CASES if (c.shape, c.size_m, c.scan_width_m, c.depth_m)
            == ("UT", 0.15, 0.3, 0.5)]
    exposures = sorted(c.exposure_s for c in seed)
    assert exposures[0] <= 0.01 and 0.1 in exposures
    assert exposures[-1] / exposures[0] >= 100
    names = [c.name for c in ORACLE_CASES + HOLDOUT_CASES]
    assert len(set(names)) == len(names)  # case_named searches both


@pytest.mark.parametrize("method", ["lct", "fk"])
def test_auto_within_the_oracle_gap(tiny_capture, queue, method):
    """auto (split-half reproducibility, to the method's bar) within 0.08 of the best IoU of
    the oracle grid (slab SNRs 1e2..1e8 for these methods) x {1e2..1e4} and at least as good
    as the photon rule within 0.01 (on this capture the photon rule's f-k is the grid's
    best, 0.004 above auto's: LCT 0.736 against 0.522, f-k 0.699 against 0.703); the GCV
    rule it replaced takes a slab SNR well below the photon rule's (the data hold less than
    the photons say). The comparison of the rules is over many captures
    (tools/results/experiments/oracle/oracle_*.csv)."""
    cap, mask = tiny_capture
    row = compare_method(cap, mask, method, queue=queue)
    assert row["auto_snr_rule"] == "reproducibility", row
    assert row["auto_kappa"] >= kappa_min(method_class(method).lightcone_filter), row
    assert row["gap"] <= 0.08, row
    assert row["vs_today"] >= -0.01, row
    base = ReconstructionConfig(slab=cap.recorded_slab()[0], method=method, snr_rule="gcv")
    gcv = reconstruct(cap, base.validate(), device=queue)
    # f-k's GCV rule takes GCV's geometric mean with the photon rule's
    assert gcv.params["snr_used"] < row["today_snr"] / (10 if method == "lct" else 3), row


def test_compare_without_the_grid(tiny_capture, queue):
    """grid=False (the seed measurements of auto against today): the same auto and today
    as with the grid, no oracle."""
    cap, mask = tiny_capture
    row = compare_method(cap, mask, "lct", grid=False, queue=queue)
    full = compare_method(cap, mask, "lct", queue=queue)
    assert row["oracle_iou"] is None and row["gap"] is None
    assert (row["auto_iou"], row["today_iou"]) == (full["auto_iou"], full["today_iou"])
    assert list(full)[-2:] == ["gap", "vs_today"]


@pytest.mark.slow
def test_iterative_auto_within_the_oracle_gap(tiny_capture, queue):
    cap, mask = tiny_capture
    row = compare_method(cap, mask, "iterative", iterations=50, queue=queue)
    assert row["gap"] <= 0.05, row
    assert row["vs_today"] >= -0.03, row


def test_auto_monotone_in_exposure(queue, tmp_path):
    """LCT and f-k with auto SNRs do not get worse as the exposure grows 1000x (within the
    spread over two noise seeds)."""
    rows = exposure_sweep(TINY, exposures=(0.005, 0.5, 5.0), seeds=(0, 1),
                          methods=("lct", "fk"), queue=queue)
    summary = sweep_summary(rows)
    assert [r["exposure_s"] for r in summary] == [0.005, 0.5, 5.0] * 2
    assert all(r["monotone"] for r in summary), summary
    photons = [r["photons"] for r in rows]
    assert photons[-1] > 500 * photons[0]
    csv_path, json_path = write_rows(summary, tmp_path / "sweep")
    assert csv_path.read_text().splitlines()[0].startswith("method,exposure_s")
    assert json_path.is_file()


def test_counts_past_the_photon_cap_are_still_cross_validated(queue):
    """A capture of 1.3e12 photon counts is Poisson, not noise-free: the slab SNR is
    cross-validation's, below the cap SNR_MAX that the photon rule reaches there, and LCT
    keeps the IoU it has at 1000x fewer photons. The cap deconvolved the 1e-6 noise of this
    0.6 m wide 'UT' into speckle (IoU 0.27 against 0.70 at 1.3e9 photons; now 0.82)."""
    ious = {"auto": [], "gcv": []}
    for exposure in (0.5, 500.0):
        cap, mask = simulate_case(replace(case_named(BENCH_CASE), exposure_s=exposure), queue)
        for rule, light_cone_rule in (("auto", "reproducibility"), ("gcv", "upre")):
            rec = reconstruct(cap, ReconstructionConfig(
                slab=cap.recorded_slab()[0], method="lct", snr_rule=rule).validate(),
                device=queue)
            assert rec.noise["photon_counts"] and rec.params["snr_used"] < SNR_MAX / 10
            assert rec.params["inversion_snr_rule"] == light_cone_rule
            ious[rule].append(mip_iou(rec.volume, mask)[0])
    assert np.sum(cap.transient) > 1e12  # the photon rule: SNR_MAX
    assert all(v[1] >= v[0] - MONOTONE_FLOOR for v in ious.values()), ious


def test_closed_form_methods_take_a_deeper_slab_stage(queue):
    """The seed geometry at 1e7 photons (the table's first case): GCV's slab SNR (2e4) is
    the slab stage's own optimum, and LCT behind it drew bright arcs in front of the target
    (IoU 0.43 against an oracle of 0.56). LCT raises it to the floor
    CLOSED_FORM_SLAB_SNR_MIN, is within 0.08 of the oracle grid again and well above its
    IoU at GCV's pick; f-k takes the same floor; the iterative method, which models the
    deconvolution's smoothing, keeps GCV's (all under ``snr_rule = "gcv"``: the default's
    thinning may deepen the iterative method's, tests/test_thinning.py, and LCT's and f-k's
    default is the halves' agreement, which is within 0.08 of the oracle here too)."""
    from clnlos.inverse.snr import CLOSED_FORM_SLAB_SNR_MIN

    cap, mask = simulate_case(ORACLE_CASES[0], queue)
    row = compare_method(cap, mask, "lct", queue=queue)
    assert row["gap"] <= 0.08, row  # the default
    base = ReconstructionConfig(slab=cap.recorded_slab()[0], snr_rule="gcv")
    lct = reconstruct(cap, base.replace(method="lct").validate(), device=queue)
    assert lct.params["snr_used"] == CLOSED_FORM_SLAB_SNR_MIN
    at_gcv = reconstruct(cap, base.replace(method="lct", snr=lct.params["snr_data"]).validate(),
                         device=queue)
    iou_rule, iou_gcv = mip_iou(lct.volume, mask)[0], mip_iou(at_gcv.volume, mask)[0]
    assert row["oracle_iou"] - iou_rule <= 0.08 and iou_rule > iou_gcv + 0.1, (iou_rule, row)
    assert iou_rule == row["gcv_rule_iou"]
    fk = reconstruct(cap, base.replace(method="fk").validate(), device=queue)
    assert fk.params["snr_used"] == fk.params["slab_snr_min"] == CLOSED_FORM_SLAB_SNR_MIN
    it = reconstruct(cap, base.replace(method="iterative", iterations=5,
                                       snr_rule="gcv").validate(), device=queue)
    assert it.params["snr_used"] == it.params["snr_data"] < CLOSED_FORM_SLAB_SNR_MIN / 3
    assert "slab_snr_min" not in it.params


def test_a_slab_snr_floor_acts_before_the_model_accuracy():
    """The floor raises the data's SNR, never lowers it, and comes before the model's
    accuracy is combined: a measured capture (MEASURED_MODEL_SNR) stays below that."""
    from clnlos.inverse.parameter_choice import method_slab_snr

    assert method_slab_snr(2e4, None) == 2e4
    assert method_slab_snr(2e4, 3e5) == 3e5 and method_slab_snr(5e7, 3e5) == 5e7
    # towards the photon rule: the geometric mean where that is higher, then the floor
    assert method_slab_snr(1e6, 3e5, 1e8) == pytest.approx(1e7)
    assert method_slab_snr(4e5, 3e5, 1e5) == 4e5 and method_slab_snr(2e4, 3e5, 1.1e5) == 3e5
    ne = NoiseEstimate(True, 1e9, 0.0, 1e9, 1.0, 1e9, 1e9 / K_SNR, None)
    snr, _ = auto_snrs(ne, ReconstructionConfig(), MEASURED_MODEL_SNR,
                       data_snr=method_slab_snr(2e4, 3e5))
    assert snr == pytest.approx(combined_snr(3e5, MEASURED_MODEL_SNR))
    assert combined_snr(2e4, MEASURED_MODEL_SNR) < snr < MEASURED_MODEL_SNR


def _seed_row(capture, seed, auto, today):
    return {"capture": capture, "method": "lct", "seed": seed, "auto_iou": auto,
            "today_iou": today, "oracle_iou": max(auto, today) + 0.01,
            "gap": max(auto, today) + 0.01 - auto, "vs_today": auto - today}


def test_seed_spread_tells_a_regression_from_seed_luck():
    """A mean drop below today of more than 0.03 is a regression only when auto is worse on
    every (paired) noise seed."""
    luck = [_seed_row("a", 0, 0.54, 0.62), _seed_row("a", 1, 0.59, 0.57),
            _seed_row("a", 2, 0.55, 0.61)]   # 0.04 below today on the mean, one seed above
    real = [_seed_row("b", 0, 0.58, 0.64), _seed_row("b", 1, 0.585, 0.635),
            _seed_row("b", 2, 0.59, 0.645)]  # 0.055 below on every seed
    out = {r["capture"]: r for r in seed_spread(luck + real)}
    assert out["a"]["seeds"] == 3 and not out["a"]["regression"]
    assert out["a"]["vs_today_mean"] == pytest.approx(-0.04)
    assert out["a"]["today_iou_spread"] == pytest.approx(0.05)
    assert out["b"]["regression"]
    assert out["b"]["vs_today_mean"] == pytest.approx(-0.055)


def _grid_seed(capture, seed, auto, ious, method="lct"):
    """grid_rows-shaped rows of one seed: auto's IoU and two grid settings' (f-k: no
    light-cone SNR)."""
    inv = None if method == "fk" else 1e3
    rows = [{"capture": capture, "seed": seed, "method": method, "setting": "auto",
             "snr": 3e5, "inversion_snr": None if inv is None else 300.0, "iou": auto}]
    return rows + [{"capture": capture, "seed": seed, "method": method, "setting": "grid",
                    "snr": a, "inversion_snr": inv, "iou": v}
                   for a, v in zip((1e4, 1e6), ious, strict=True)]


def test_transfer_tells_noise_luck_from_a_setting_the_capture_needs():
    """The transferred setting is the best over the other seeds: where one seed's best is
    luck it loses that seed's lead (transfer_gap > 0), where every seed agrees it is the
    oracle (transfer_gap 0); gap = transfer_gap + auto_vs_transfer; one seed: no rows."""
    luck = (_grid_seed("luck", 0, 0.60, (0.70, 0.60)) + _grid_seed("luck", 1, 0.60, (0.60, 0.66))
            + _grid_seed("luck", 2, 0.60, (0.61, 0.65)))
    needs = _grid_seed("needs", 0, 0.55, (0.50, 0.75)) + _grid_seed("needs", 1, 0.58, (0.52, 0.72))
    out = {(r["capture"], r["seed"]): r
           for r in transfer_rows(luck + needs + _grid_seed("alone", 0, 0.5, (0.4, 0.6)))}
    assert set(out) == {("luck", 0), ("luck", 1), ("luck", 2), ("needs", 0), ("needs", 1)}
    r = out["luck", 0]  # the others prefer 1e6 (0.655 against 0.605 on the mean)
    assert (r["oracle_snr"], r["transfer_snr"]) == (1e4, 1e6)
    assert r["transfer_gap"] == pytest.approx(0.10) and r["gap"] == pytest.approx(0.10)
    assert r["auto_vs_transfer"] == pytest.approx(0.0)
    r = out["luck", 1]
    assert r["transfer_snr"] == 1e4 and r["transfer_gap"] == pytest.approx(0.06)
    for s in (0, 1):
        r = out["needs", s]
        assert r["transfer_snr"] == r["oracle_snr"] == 1e6 and r["transfer_gap"] == 0.0
        assert r["auto_vs_transfer"] == pytest.approx(r["gap"]) and r["gap"] > 0.1
    for r in out.values():
        assert r["gap"] == pytest.approx(r["transfer_gap"] + r["auto_vs_transfer"])
    # f-k rows (no light-cone SNR) and a tie: the first grid setting, as compare_method takes
    fk = transfer_rows(_grid_seed("fk", 0, 0.5, (0.6, 0.6), "fk")
                       + _grid_seed("fk", 1, 0.5, (0.55, 0.7), "fk"))
    r0, r1 = sorted(fk, key=lambda r: r["seed"])
    assert r0["method"] == "fk" and r0["oracle_snr"] == 1e4 and r0["transfer_snr"] == 1e6
    assert r0["transfer_inversion_snr"] is None and r0["transfer_gap"] == 0.0
    assert r1["transfer_snr"] == 1e4 and r1["transfer_gap"] == pytest.approx(0.15)


def test_grid_rows_keep_what_compare_method_reduces(tiny_capture, queue):
    """grid_rows on two seeds of the tiny case: auto and every grid setting per seed, the
    same auto and oracle IoU as compare_method on that capture; transfer_gap >= 0."""
    rows = grid_rows([TINY], (0, 1), ("lct",), queue=queue, progress=None)
    grid = [r for r in rows if r["seed"] == 0 and r["setting"] == "grid"]
    assert len(grid) == len(grid_settings("lct")) and len(rows) == 2 * (len(grid) + 1)
    cap, mask = tiny_capture  # TINY at seed 0
    row = compare_method(cap, mask, "lct", queue=queue)
    auto = next(r for r in rows if r["seed"] == 0 and r["setting"] == "auto")
    assert auto["iou"] == row["auto_iou"] and auto["snr"] == row["auto_snr"]
    moved = {r["seed"]: r for r in transfer_rows(rows)}
    assert moved[0]["oracle_iou"] == row["oracle_iou"]
    for s, r in moved.items():  # the transferred setting's IoU is this seed's at it
        at = {(g["snr"], g["inversion_snr"]): g["iou"] for g in rows
              if g["seed"] == s and g["setting"] == "grid"}
        assert r["transfer_iou"] == at[r["transfer_snr"], r["transfer_inversion_snr"]]
        other = {(g["snr"], g["inversion_snr"]): g["iou"] for g in rows
                 if g["seed"] != s and g["setting"] == "grid"}
        assert other[r["transfer_snr"], r["transfer_inversion_snr"]] == max(other.values())


def test_noise_l1_weight_leaves_pure_noise_empty(queue):
    """l1_weight "auto" (twice max(L^T n) of a noise realisation n): the inversion of
    another realisation of the same noise, alone, returns an empty volume, where today's
    constant (0.1 of max(L^T I), I the data) switches voxels on."""
    from clnlos.inverse.iterative import IterativeInversion

    rng = np.random.default_rng(3)
    shape = (64, 8, 8)
    n1, n2 = (rng.standard_normal(shape).astype(np.float32) for _ in range(2))
    kw = dict(bin_width_s=64e-12, scan_width_m=0.3, iterations=60, tv_weight=0.0,
              queue=queue)
    auto = IterativeInversion(shape, l1_weight="auto", **kw)
    empty = auto(n1, noise=cla.to_device(queue, n2))
    assert auto.l1_rule == "noise" and auto.report.l1 > auto.report.lam_max
    fixed = IterativeInversion(shape, l1_weight=0.1, **kw)
    lit = fixed(n1)
    assert fixed.l1_rule == "fixed" and lit.sum() > 0
    assert empty.sum() <= 1e-3 * lit.sum(), (empty.sum(), lit.sum())
    # without a noise realisation "auto" keeps today's constant
    auto(n1)
    assert auto.l1_rule == "fixed"
    assert auto.report.l1 == pytest.approx(0.1 * auto.report.lam_max, rel=1e-6)


@pytest.mark.slow
def test_iterative_l1_weight_from_the_noise(tiny_capture, queue):
    """Photon counts: the iterative method's L1 weight comes from the capture's own noise
    (here below today's constant 0.1); a number given keeps the constant."""
    cap, _ = tiny_capture
    cfg = ReconstructionConfig(slab=cap.recorded_slab()[0], method="iterative",
                               iterations=20)
    rec = reconstruct(cap, cfg.validate(), device=queue)
    assert rec.params["l1_rule"] == "noise"
    assert 0.0 < rec.params["l1_weight_used"] < 0.1
    rec = reconstruct(cap, cfg.replace(l1_weight=0.1).validate(), device=queue)
    assert rec.params["l1_rule"] == "fixed"
    assert rec.params["l1_weight_used"] == pytest.approx(0.1, rel=1e-6)


def test_noise_free_capture_takes_the_caps(queue):
    """Without noise (no [detector]) there is nothing to cross-validate against: the slab
    and light-cone SNRs are the caps SNR_MAX and LIGHTCONE_SNR_MAX, as before."""
    from clnlos.forward.model import ForwardModel
    from clnlos.forward.scene import Scene
    from clnlos.inverse.snr import LIGHTCONE_SNR_MAX, SNR_MAX

    d = replace(TINY, points=32, bins=256, bin_width_s=32e-12).scene_dict()
    del d["detector"]
    cap = ForwardModel(Scene.from_dict(d), queue=queue).capture()
    cfg = ReconstructionConfig(slab=cap.recorded_slab()[0], method="lct").validate()
    rec = reconstruct(cap, cfg, device=queue)
    assert rec.noise["snr"] == SNR_MAX
    assert rec.params["snr_used"] == SNR_MAX
    assert rec.params["inversion_snr_used"] == LIGHTCONE_SNR_MAX


@pytest.mark.slow
def test_lct_auto_monotone_at_the_seed_geometry(queue):
    """'UT' 0.15 m, 0.3 m scan of 32 x 32, 0.5 m deep: from 0.05 s to 5 s of exposure LCT
    with auto SNRs does not lose IoU; with the photon rule it lost 0.22 (0.62 -> 0.40)."""
    case = OracleCase("seed UT", "UT", 0.15, 0.5, 0.3, 0.05)
    rows = exposure_sweep(case, exposures=(0.05, 5.0), seeds=(0, 1), methods=("lct",),
                          queue=queue)
    summary = sweep_summary(rows)
    assert all(r["monotone"] for r in summary), summary


@pytest.mark.slow
def test_slab_influence_in_the_model_recovers_a_deep_plus(queue):
    """A '+' of 7.5 cm bars 0.7 m behind the CDT slab (24 x 24 scan of 0.5 m, 4e9 photons):
    with the smoothing the slab deconvolution leaves in the model (Phi o L) the iterative
    method's default reconstruction is at least 0.03 IoU above Wiener first (L alone; 0.73
    against 0.80 on the oracle table's 32 x 32 case), at the same slab SNR."""
    case = replace(case_named("plus 0.25 m, scan 0.5 m, 0.7 m deep, 0.5 s"), points=24)
    cap, mask = simulate_case(case, queue)
    base = ReconstructionConfig(slab=cap.recorded_slab()[0], method="iterative",
                                snr_rule="gcv")  # the same slab SNR for both models
    recs = {m: reconstruct(cap, base.replace(slab_model=m).validate(), device=queue)
            for m in ("none", "influence")}
    iou = {m: mip_iou(r.volume, mask)[0] for m, r in recs.items()}
    assert recs["influence"].params["slab_model_used"] == "influence"
    assert recs["none"].params["slab_model_used"] == "none"
    assert recs["influence"].params["snr_used"] == recs["none"].params["snr_used"]
    assert iou["influence"] >= iou["none"] + 0.03, iou


# --- the resampled model (clnlos.inverse.snr: represented_snr, rebinning_error) -------------

def test_represented_snr_is_that_of_white_noise_of_the_errors_power():
    """The bound is 1 / mean |E|^2 (white noise of the error's power, as the photon rule
    turns a noise level into an SNR); no error gives none; independent errors add."""
    from clnlos.inverse.snr import combined_accuracy, represented_snr

    err = np.array([0.0, 1e-6, 3e-6, 4e-6])
    assert represented_snr(err) == pytest.approx(5e5)
    assert represented_snr(np.zeros(8)) == math.inf
    assert combined_accuracy(math.inf, 1e6, 1e6) == pytest.approx(5e5)
    assert combined_accuracy(math.inf) == math.inf


def test_rebinning_error_is_zero_for_whole_bins_and_grows_with_the_bin_ratio():
    """Selecting whole bins (a shift by 3 bins) leaves the slab model exact; rebinning 16 ps
    to 128, 64, 41 ps bins leaves a bound that rises as the bins shrink (the sub-bin
    arrival time the model loses matters less): 1.7e3, 1.3e4, 1.1e5 measured."""
    from clnlos.forward.blur import confocal_lag_energy
    from clnlos.inverse.preprocessing import preprocess_matrix
    from clnlos.inverse.snr import rebinning_error, represented_snr
    from clnlos.physics.slab import CDT_SLAB

    nt, dt = 512, 16e-12
    h_in = confocal_lag_energy(CDT_SLAB, nt=nt, bin_width_s=dt)
    shift, _, n = preprocess_matrix(nt, dt, -3 * dt, None, None)
    assert represented_snr(rebinning_error(shift, h_in, h_in[:n])) > 1e20  # round-off
    bounds = []
    for bins in (64, 128, 200):
        a, dto, n = preprocess_matrix(nt, dt, 0.0, None, bins)
        h_out = confocal_lag_energy(CDT_SLAB, nt=a.shape[0], bin_width_s=dto)
        bounds.append(represented_snr(rebinning_error(a, h_in, h_out)))
    assert 1e2 < bounds[0] < bounds[1] < bounds[2] < 1e8, bounds


def test_gcv_bins_block_by_block_equal_one_pass(monkeypatch):
    """GcvBins built and summed in blocks of rows (no spectrum-sized temporary) give the
    counts, gains, per-bin power and picks of one block; an odd last axis (no Nyquist
    column) and an even one."""
    import clnlos.inverse.gcv as gcv

    rng = np.random.default_rng(3)
    for n_last in (14, 13):
        g = np.exp(-rng.random((9, 5, n_last // 2 + 1)) * 30)
        p = rng.random(g.shape) * 1e3
        whole = GcvBins.from_gain(g, n_last)
        monkeypatch.setattr(gcv, "row_blocks",
                            lambda shape, values=7: [(r, min(r + 2, shape[0]))
                                                     for r in range(0, shape[0], 2)])
        blocks = GcvBins.from_gain(g, n_last)
        monkeypatch.undo()
        np.testing.assert_allclose(blocks.count, whole.count)
        np.testing.assert_allclose(blocks.gain, whole.gain)
        np.testing.assert_array_equal(blocks.index, whole.index)
        w = np.broadcast_to(np.where(np.arange(g.shape[-1]) == 0, 1.0, 2.0), g.shape).copy()
        if n_last % 2 == 0:
            w[..., -1] = 1.0
        direct = np.bincount(whole.index.ravel(), weights=(w * p).ravel(),
                             minlength=whole.count.size)
        np.testing.assert_allclose(binned_power(whole, [(0, p[:4]), (4, p[4:])]), direct)
        assert whole.count.sum() == pytest.approx(w.sum())
        rows = rng.random(g.shape[0])  # a power constant along each row: no spectrum pass
        np.testing.assert_allclose(rows @ row_counts(whole), binned_power(
            whole, [(0, np.broadcast_to(rows[:, None, None], g.shape))]))
        assert whole.snr(p, 1.0, 1e8) == blocks.snr(p, 1.0, 1e8)


def test_gcv_bins_of_a_folded_spectrum_equal_the_whole():
    """A filter's spectrum stored folded (even in y; the slab's, the light cone's) is binned
    on its quarter: the same bins of every frequency, counts, gains, per-bin power, row
    counts and picks as the whole half spectrum's; odd and even first two axes."""
    rng = np.random.default_rng(5)
    for n0, n1, n_last in ((10, 8, 14), (9, 7, 13)):
        f0, f1, n2h = n0 // 2 + 1, n1 // 2 + 1, n_last // 2 + 1
        quarter = np.exp(-rng.random((f0, f1, n2h)) * 30)
        w, ky = np.arange(n0), np.arange(n1)
        g = quarter[np.minimum(w, n0 - w)][:, np.minimum(ky, n1 - ky)]
        whole = GcvBins.from_gain(g, n_last)
        folded = GcvBins.from_blocks(lambda r0, r1: quarter[r0:r1], g.shape, n_last,
                                     folded=True)
        assert folded.index.size == quarter.size and folded.spectrum_shape == g.shape
        np.testing.assert_array_equal(folded.rows(0, n0), whole.index)
        np.testing.assert_allclose(folded.count, whole.count)
        np.testing.assert_allclose(folded.gain, whole.gain)
        p = rng.random(g.shape) * 1e3
        np.testing.assert_allclose(binned_power(folded, [(0, p[:3]), (3, p[3:])]),
                                   binned_power(whole, [(0, p)]))
        np.testing.assert_allclose(row_counts(folded), row_counts(whole))
        assert folded.snr(p, 1.0, 1e8) == whole.snr(p, 1.0, 1e8)


@pytest.mark.fp64
def test_lightcone_noise_power_from_its_law(queue):
    """Without a slab the light-cone UPRE takes the noise's power spectrum from its law
    (LCT.column_noise_power, no realisation): Parseval's total exactly, and the mean power
    per bin of realisations of that noise."""
    rng = np.random.default_rng(5)
    nt, n = 32, 4
    lct = LCT((nt, n, n), bin_width_s=64e-12, scan_width_m=0.4, falloff=2.0, queue=queue,
              dtype=np.float64)
    counts = rng.poisson(20.0, (nt + 8, n, n)).astype(np.float64)
    K = sp.random(nt, nt + 8, density=0.2, random_state=6, format="csr")  # any t-only map
    d = counts.reshape(nt + 8, -1).sum(axis=1)
    law = lct.column_noise_power(K, d)
    M = (lct.to_v.matrix @ K).toarray()
    assert law.sum() == pytest.approx(8 * nt * n * n * float((M**2 @ d).sum()), rel=1e-9)
    draws = []
    for _ in range(300):
        e = np.sqrt(counts) * rng.standard_normal(counts.shape)
        x = (K @ e.reshape(nt + 8, -1)).reshape(nt, n, n)
        draws.append(lct.power(cla.to_device(queue, x)))
    mean = np.mean(draws, axis=0)
    assert np.abs(mean - law).sum() / law.sum() < 0.05


def test_upre_without_a_slab_reuses_the_spectrum(tiny_capture, queue):
    """A photon-count capture without a slab: the light-cone SNR by UPRE from the noise's
    law, reproducible, and the inversion reusing the choice's forward FFT gives the volume
    of the same SNR given as a number (a fresh transform)."""
    cap, _ = tiny_capture
    cfg = ReconstructionConfig(method="lct").validate()
    auto = reconstruct(cap, cfg, device=queue)
    assert auto.params["inversion_snr_rule"] == "upre"
    assert reconstruct(cap, cfg, device=queue).params["inversion_snr_used"] == \
        auto.params["inversion_snr_used"]
    fixed = reconstruct(cap, cfg.replace(inversion_snr=auto.params["inversion_snr_used"])
                        .validate(), device=queue)
    np.testing.assert_allclose(auto.volume, fixed.volume, rtol=1e-5,
                               atol=1e-6 * float(fixed.volume.max()))
