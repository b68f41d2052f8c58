"""LCT's and f-k's "auto" SNRs by split-half reproducibility (clnlos.inverse.reproducibility,
issue 24): the agreement measure, the search order, and the pipeline's use of them."""

import json
from dataclasses import replace

import numpy as np
import pytest

from clnlos.bench.oracle import OracleCase, simulate_case
from clnlos.config import ReconstructionConfig
from clnlos.errors import ParameterError
from clnlos.inverse.parameter_choice import DECONVOLVED_KEPT
from clnlos.inverse.pipeline import ReconstructionPipeline, reconstruct
from clnlos.inverse.preprocessing import resolve_geometry
from clnlos.inverse.reproducibility import (
    KAPPA_MIN,
    KAPPA_MIN_SLAB_ONLY,
    LIGHTCONE_SNRS,
    SLAB_SNRS,
    SLAB_SNRS_SLAB_ONLY,
    candidate_order,
    cohen_kappa,
    first_reproducible,
    kappa_min,
    mask_agreement,
    otsu_mask,
)
from clnlos.inverse.snr import MEASURED_MODEL_SNR
from clnlos.inverse.tail_fill import TAIL_FILL_SNR, TailFilledDeconvolution
from clnlos.inverse.thinning import thin_counts
from clnlos.physics.grid import block_sums
from clnlos.study.score.metrics import mip_iou

# 'UT' 0.3 m tall 0.5 m behind the CDT slab, 16 x 16 scan of 0.6 m, 128 bins of 64 ps,
# ~1.2e8 photons
SMALL = OracleCase("small UT", "UT", 0.3, 0.5, 0.6, 0.1, points=16, bins=128,
                   bin_width_s=64e-12, seed=4)


def _kappa_from_table(a: np.ndarray, b: np.ndarray) -> float:
    """Cohen's kappa from the 2 x 2 contingency table (float64), the form
    2 (n11 n00 - n10 n01) / ((n11 + n10)(n10 + n00) + (n11 + n01)(n01 + n00))."""
    a, b = a.ravel(), b.ravel()
    n11 = float(np.sum(a & b))
    n00 = float(np.sum(~a & ~b))
    n10 = float(np.sum(a & ~b))
    n01 = float(np.sum(~a & b))
    return 2 * (n11 * n00 - n10 * n01) / ((n11 + n10) * (n10 + n00)
                                          + (n11 + n01) * (n01 + n00))


def test_kappa_against_the_contingency_table_form():
    """On random masks of several areas and correlations, kappa equals the contingency
    table's form to 1e-12; the same mask gives 1, its complement -1 (half the area) and
    independent masks of 2e5 pixels |kappa| < 0.02."""
    rng = np.random.default_rng(3)
    for p, q, rho in ((0.5, 0.5, 0.0), (0.2, 0.35, 0.5), (0.05, 0.1, 0.9), (0.7, 0.3, 0.2)):
        a = rng.random((40, 50)) < p
        b = np.where(rng.random(a.shape) < rho, a, rng.random(a.shape) < q)
        assert cohen_kappa(a, b) == pytest.approx(_kappa_from_table(a, b), abs=1e-12)
    a = rng.random((64, 64)) < 0.5
    assert cohen_kappa(a, a) == 1.0
    half = np.zeros((8, 8), bool)
    half[:4] = True
    assert cohen_kappa(half, ~half) == pytest.approx(-1.0)
    big = rng.random(200_000) < 0.3
    assert abs(cohen_kappa(big, rng.random(200_000) < 0.4)) < 0.02


def test_kappa_hard_cases():
    """Two equal constant masks agree (1.0: nothing to disagree on); opposite constant
    masks have chance agreement 0 and kappa 0; shapes must match. The search scores a
    constant mask 0 whatever the other (an empty or flat image is not a reproducible one)."""
    empty, full = np.zeros((4, 4), bool), np.ones((4, 4), bool)
    assert cohen_kappa(empty, empty) == 1.0 and cohen_kappa(full, full) == 1.0
    assert cohen_kappa(empty, full) == 0.0
    with pytest.raises(ValueError, match="shapes"):
        cohen_kappa(empty, np.zeros((4, 5), bool))
    some = np.eye(4, dtype=bool)
    assert mask_agreement(empty, empty) == mask_agreement(full, full) == 0.0
    assert mask_agreement(some, full) == 0.0 and mask_agreement(some, some) == 1.0


def test_candidates_from_the_least_regularised_down():
    """By the product of the SNRs, at equal products the deeper slab deconvolution first;
    a method without a light-cone filter (None) by its slab SNR alone."""
    order = candidate_order(SLAB_SNRS, LIGHTCONE_SNRS)
    assert len(order) == len(SLAB_SNRS) * len(LIGHTCONE_SNRS)
    assert order[0] == (1e7, 1e4) and order[-1] == (SLAB_SNRS[0], 1e2)
    assert order[1:3] == [(1e7, 1e3), (1e6, 1e4)]
    products = [a * b for a, b in order]
    assert products == sorted(products, reverse=True)
    assert candidate_order(SLAB_SNRS, (None,)) == [(s, None) for s in SLAB_SNRS[::-1]]


def test_the_first_reproducible_candidate_stops_the_search():
    calls = []
    kappas = {(1e3, None): 0.2, (1e2, None): 0.95, (10.0, None): 0.99}

    def agreement(c):
        calls.append(c)
        return kappas[c]

    chosen, tried, agreed = first_reproducible(list(kappas), agreement, 0.7)
    assert chosen == (1e2, None) and calls == [(1e3, None), (1e2, None)] and agreed
    assert tried == [((1e3, None), 0.2), ((1e2, None), 0.95)]
    chosen, tried, agreed = first_reproducible(list(kappas), lambda c: 0.5 - c[0] / 1e4, 0.7)
    assert chosen == (10.0, None) and len(tried) == 3  # none agrees: the most reproducible
    assert not agreed
    with pytest.raises(ValueError):
        first_reproducible([], agreement, KAPPA_MIN)


def test_the_mask_compared_is_the_mask_scored():
    """otsu_mask is the thresholded MIP that mip_iou scores (one threshold rule)."""
    v = np.random.default_rng(1).gamma(2.0, size=(12, 9, 11))
    truth = np.zeros((9, 11), bool)
    assert np.array_equal(otsu_mask(v), mip_iou(v, truth)[1])


@pytest.fixture(scope="module")
def small_capture(queue):
    return simulate_case(SMALL, queue)


def _config(cap, **kw):
    return ReconstructionConfig(slab=cap.recorded_slab()[0], **kw).validate()


def test_lct_takes_the_first_candidate_whose_halves_agree(small_capture, queue):
    """The default for LCT on a capture with its own slab: the candidates are tried in
    candidate_order, every one before the chosen has kappa < KAPPA_MIN, the chosen one
    at least KAPPA_MIN, and its SNRs are the ones used. The kappas recorded are recomputed
    here through the public path (the halves of thin_counts reconstructed with those SNRs
    given as numbers), and a second run repeats the choice."""
    cap, _ = small_capture
    cfg = _config(cap, method="lct")
    assert cfg.reproducibility and not cfg.replace(snr_rule="gcv").reproducibility
    rec = reconstruct(cap, cfg, device=queue)
    p = rec.params
    assert p["snr_rule_used"] == "reproducibility"
    assert p["inversion_snr_rule"] == "reproducibility"
    tried = [((s, c), k) for s, c, k in json.loads(p["reproducibility_tried"])]
    order = candidate_order(SLAB_SNRS, LIGHTCONE_SNRS)
    assert [c for c, _ in tried] == order[:len(tried)]
    assert all(k < KAPPA_MIN for _, k in tried[:-1]) and tried[-1][1] >= KAPPA_MIN
    assert (p["snr_used"], p["inversion_snr_used"]) == tried[-1][0]
    assert p["reproducibility_kappa"] == tried[-1][1]
    halves = [replace(cap, transient=h) for h in thin_counts(np.asarray(cap.transient))]
    for (s, c), k in (tried[-1], tried[0]):
        given = cfg.replace(snr=s, inversion_snr=c)
        masks = [otsu_mask(reconstruct(h, given, device=queue).volume) for h in halves]
        assert cohen_kappa(*masks) == pytest.approx(k, abs=1e-9)
    again = reconstruct(cap, cfg, device=queue)
    assert again.params["reproducibility_tried"] == p["reproducibility_tried"]
    assert np.array_equal(again.volume, rec.volume)
    given = reconstruct(cap, cfg.replace(snr=p["snr_used"], inversion_snr=p["inversion_snr_used"]),
                        device=queue)  # the chosen SNRs as numbers: the same volume
    assert np.array_equal(given.volume, rec.volume)
    assert SLAB_SNRS[0] == 1e5 and SLAB_SNRS[-1] == 1e7  # a decade below the GCV rule's floor


def test_no_candidate_agreeing_takes_the_most_reproducible(small_capture, queue, monkeypatch):
    """Where no candidate reaches the threshold (here: a threshold above 1), every candidate
    is tried, the most reproducible is used, and a note says so."""
    import clnlos.inverse.parameter_choice as choice

    cap, _ = small_capture
    monkeypatch.setattr(choice, "kappa_min", lambda lightcone_filter: 1.01)
    rec = reconstruct(cap, _config(cap, method="lct"), device=queue)
    tried = json.loads(rec.params["reproducibility_tried"])
    assert len(tried) == len(SLAB_SNRS) * len(LIGHTCONE_SNRS)
    best = max(tried, key=lambda t: t[2])
    assert (rec.params["snr_used"], rec.params["inversion_snr_used"]) == (best[0], best[1])
    assert any("no candidate's halves agreed to kappa >= 1.01" in n for n in rec.notes)


def test_fk_searches_its_slab_snr_alone_to_its_own_bar(small_capture, queue):
    """f-k's default on a capture with its own slab: the slab SNR alone is searched, from
    the highest down, to KAPPA_MIN_SLAB_ONLY (no light-cone filter follows the slab stage);
    every earlier candidate is below that bar, the chosen one at least at it; "gcv" by
    name keeps GCV's pick."""
    cap, _ = small_capture
    assert kappa_min(True) == KAPPA_MIN < kappa_min(False) == KAPPA_MIN_SLAB_ONLY
    rec = reconstruct(cap, _config(cap, method="fk"), device=queue)
    p = rec.params
    tried = json.loads(p["reproducibility_tried"])
    assert p["snr_rule_used"] == "reproducibility"
    assert p["reproducibility_kappa_min"] == KAPPA_MIN_SLAB_ONLY
    assert all(c is None for _, c, _ in tried)
    assert [s for s, _, _ in tried] == list(SLAB_SNRS_SLAB_ONLY[::-1])[:len(tried)]
    agreed = p["reproducibility_agreed"]
    assert all(k < KAPPA_MIN_SLAB_ONLY for *_, k in tried[:-1])
    assert (tried[-1][2] >= KAPPA_MIN_SLAB_ONLY) == agreed
    if agreed:
        assert p["snr_used"] == tried[-1][0]
    else:
        assert p["snr_used"] == max(tried, key=lambda t: t[2])[0]
    assert reconstruct(cap, _config(cap, method="fk", snr_rule="gcv"), device=queue
                       ).params["snr_rule_used"] == "gcv"


def test_each_method_searches_to_its_own_bar(small_capture, queue, monkeypatch):
    """With every pair of halves agreeing at kappa 0.75 (between the two bars): LCT, whose
    light-cone filter follows the slab stage, takes its first candidate; f-k, whose slab
    filter is its only regularisation, finds none at KAPPA_MIN_SLAB_ONLY, tries all of
    SLAB_SNRS_SLAB_ONLY and notes the fallback."""
    import clnlos.inverse.parameter_choice as choice

    cap, _ = small_capture
    monkeypatch.setattr(choice, "mask_agreement", lambda a, b: 0.75)
    lct = reconstruct(cap, _config(cap, method="lct"), device=queue).params
    assert lct["reproducibility_agreed"] and len(json.loads(lct["reproducibility_tried"])) == 1
    assert (lct["snr_used"], lct["inversion_snr_used"]) == (SLAB_SNRS[-1], LIGHTCONE_SNRS[-1])
    fk = reconstruct(cap, _config(cap, method="fk"), device=queue)
    tried = json.loads(fk.params["reproducibility_tried"])
    assert not fk.params["reproducibility_agreed"]
    assert [s for s, _, _ in tried] == list(SLAB_SNRS_SLAB_ONLY[::-1])
    assert fk.params["snr_used"] == SLAB_SNRS_SLAB_ONLY[-1]  # ties: the first tried
    assert any(f"kappa >= {KAPPA_MIN_SLAB_ONLY:g}" in n for n in fk.notes)


def test_a_light_cone_snr_given_is_kept(small_capture, queue):
    """A configured light-cone SNR with an "auto" slab SNR: the search runs over the slab
    SNR alone and the light cone keeps the number."""
    cap, _ = small_capture
    rec = reconstruct(cap, _config(cap, method="lct", inversion_snr=300.0), device=queue)
    tried = json.loads(rec.params["reproducibility_tried"])
    assert all(c is None for _, c, _ in tried) and rec.params["inversion_snr_used"] == 300.0


def test_measured_captures_keep_the_gcv_rule(small_capture, queue):
    """Given another slab than the one it was simulated with (a measured capture's case:
    the model's error is in both halves alike), "auto" keeps the GCV rule without a note;
    "reproducibility" by name searches there too."""
    cap, _ = small_capture
    other = replace(cap.recorded_slab()[0], mu_a=0.6)
    cfg = _config(cap, method="lct").replace(slab=other).validate()
    rec = reconstruct(cap, cfg, device=queue)
    assert rec.params["model_snr_used"] == MEASURED_MODEL_SNR
    assert rec.params["snr_rule_used"] == "gcv" and "reproducibility_kappa" not in rec.params
    assert rec.params["inversion_snr_rule"] == "upre" and not rec.notes
    named = reconstruct(cap, cfg.replace(snr_rule="reproducibility").validate(), device=queue)
    assert named.params["snr_rule_used"] == "reproducibility"
    assert named.params["snr_used"] in SLAB_SNRS  # as given: no model share combined


def test_no_split_without_counts(small_capture, queue):
    """Data that are not counts have no binomial split: by name, a note says the rule was
    not applied; one photon leaves a half empty (the split's own answer) and holds no light
    above the background: the GCV rule stands, no search runs."""
    cap, _ = small_capture
    cfg = _config(cap, method="lct", snr_rule="reproducibility")
    bw, start, sw = resolve_geometry(cap, cfg)
    pipe = ReconstructionPipeline(cap.transient.shape, bin_width_s=bw, start_s=start,
                                  scan_width_m=sw, config=cfg, queue=queue)
    rec = pipe.run(cap.transient * 1.0001)
    assert "reproducibility_kappa" not in rec.params
    assert any("reproducibility not applied" in n for n in rec.notes)
    one = np.zeros_like(cap.transient)
    one[0, 0, 0] = 1.0
    chosen, params = pipe.reproducibility_snrs(one)
    assert chosen is None and params["snr_rule_used"].startswith("gcv")
    rec = pipe.run(one)
    assert rec.params["snr_rule_used"] == "gcv" and "reproducibility_kappa" not in rec.params
    assert any("reproducibility not applied" in n for n in rec.notes)


def test_noise_alone_runs_no_search_and_no_tail_fill(small_capture, queue):
    """A capture of background counts alone (no bin above its floor): the split-half search
    would try every candidate for halves that agree on nothing and the window-end test would
    read the floor as light still arriving; neither runs: the GCV rule, the plain Wiener
    filter, and the note that the volume shows noise."""
    cap, _ = small_capture
    noise = replace(cap, transient=np.random.default_rng(3).poisson(
        2.0, cap.transient.shape).astype(np.float32))
    rec = reconstruct(noise, _config(cap, method="lct"), device=queue)
    assert rec.params["snr_rule_used"] == "gcv" and "reproducibility_tried" not in rec.params
    assert rec.params["window_end_level"] == 0.0 and "tail_fill_snr" not in rec.params
    assert any("the volume shows noise" in n for n in rec.notes)


def test_the_rule_by_name_is_for_the_closed_forms():
    with pytest.raises(ParameterError, match="snr_rule"):
        ReconstructionConfig(method="iterative", snr_rule="reproducibility").validate()
    assert ReconstructionConfig(method="fk").validate().reproducibility
    assert not ReconstructionConfig(method="fk", snr_rule="gcv").validate().reproducibility
    assert not ReconstructionConfig(method="iterative").validate().reproducibility
    assert ReconstructionConfig(method="lct", snr_rule="reproducibility").validate().reproducibility


def test_candidates_share_each_half_prepared_once(small_capture, queue, monkeypatch):
    """A split search prepares each half once, deconvolves it once per slab SNR and fills a
    cut window's tail once per fill SNR (counted here); a candidate's volume from the
    prepared half, after the other candidates, equals a fresh run of that half with the
    candidate's SNRs (what the search shares changes nothing)."""
    cap, _ = small_capture
    cfg = _config(cap, method="lct")
    bw, start, sw = resolve_geometry(cap, cfg)
    pipe = ReconstructionPipeline(cap.transient.shape, bin_width_s=bw, start_s=start,
                                  scan_width_m=sw, config=cfg, queue=queue)
    calls = {"prepare": 0, "deconvolution": 0, "fill": 0}

    def counted(name, fn):
        def wrapper(*a, **kw):
            calls[name] += 1
            return fn(*a, **kw)
        return wrapper

    monkeypatch.setattr(pipe, "prepare", counted("prepare", pipe.prepare))
    monkeypatch.setattr(pipe, "_deconvolution_for",
                        counted("deconvolution", pipe._deconvolution_for))
    monkeypatch.setattr(TailFilledDeconvolution, "_fill",
                        counted("fill", TailFilledDeconvolution._fill))
    chosen, params = pipe.reproducibility_snrs(cap.transient)
    tried = [(s, c) for s, c, _ in json.loads(params["reproducibility_tried"])]
    assert calls["prepare"] == 2 and len(tried) >= 2
    assert calls["deconvolution"] == 2 * len({s for s, _ in tried})
    assert calls["fill"] <= 2 * len({min(s, TAIL_FILL_SNR) for s, _ in tried})
    halves = thin_counts(np.asarray(cap.transient))
    prepared = pipe.prepare(halves[0])
    for cand in tried[::-1] + tried:  # every slab SNR deconvolved before its second use
        shared = pipe._reconstruct(prepared, {}, snrs=cand).volume
        fresh = pipe.run(halves[0], snrs=cand).volume
        assert np.array_equal(shared, fresh), cand
    assert len(prepared.deconvolved) <= DECONVOLVED_KEPT


def test_search_block_keeps_the_search_grid_between_its_bounds():
    """The scan points per side a capture is searched on the sums of: none within
    REPRODUCIBILITY_SEARCH_POINTS (64) a side; else the fewest f dividing both sides that
    brings the longer within 64 while the shorter keeps at least 48; the capture's own grid
    where none does (130 = 2 x 5 x 13: 65 or 26 a side; 128 x 72: 64 x 36)."""
    from clnlos.inverse.reproducibility import (
        REPRODUCIBILITY_SEARCH_POINTS,
        REPRODUCIBILITY_SEARCH_POINTS_MIN,
        search_block,
    )

    assert (REPRODUCIBILITY_SEARCH_POINTS, REPRODUCIBILITY_SEARCH_POINTS_MIN) == (64, 48)
    cases = {(16, 16): 1, (40, 40): 1, (64, 64): 1, (66, 66): 1, (96, 96): 2, (100, 100): 2,
             (128, 128): 2, (256, 256): 4, (192, 128): 1, (128, 96): 2, (130, 130): 1,
             (128, 72): 1, (127, 127): 1}
    assert {k: search_block(*k) for k in cases} == cases


def _search_bounds(monkeypatch, points: int, least: int) -> None:
    import clnlos.inverse.reproducibility as rp

    monkeypatch.setattr(rp, "REPRODUCIBILITY_SEARCH_POINTS", points)
    monkeypatch.setattr(rp, "REPRODUCIBILITY_SEARCH_POINTS_MIN", least)


def test_a_large_capture_is_searched_on_block_sums(small_capture, queue, monkeypatch):
    """A capture of more scan points per side than the search's grid (here at most 8,
    against the 16-point capture) is searched on its counts summed over 2 x 2 blocks: the
    params name that grid, the choice is the search of a pipeline built on the block sums
    themselves (the same candidates, kappas and SNRs), and the chosen SNRs then run on the
    capture's own grid (its volume keeps all 16 x 16 columns)."""
    cap, _ = small_capture
    cfg = _config(cap, method="lct")
    _search_bounds(monkeypatch, 8, 8)
    rec = reconstruct(cap, cfg, device=queue)
    p = rec.params
    nt = rec.volume.shape[0]
    assert p["reproducibility_grid"] == f"{nt}x8x8" and rec.volume.shape[1:] == (16, 16)
    assert "reproducibility_block_grid" not in p
    bw, start, sw = resolve_geometry(cap, cfg)
    small = ReconstructionPipeline((cap.transient.shape[0], 8, 8), bin_width_s=bw,
                                   start_s=start, scan_width_m=sw, config=cfg, queue=queue)
    chosen, params = small.reproducibility_snrs(block_sums(np.asarray(cap.transient), 2))
    assert params["reproducibility_tried"] == p["reproducibility_tried"]
    assert (p["snr_used"], p["inversion_snr_used"]) == chosen
    given = reconstruct(cap, cfg.replace(snr=chosen[0], inversion_snr=chosen[1]), device=queue)
    assert np.array_equal(given.volume, rec.volume)


def test_no_agreement_on_block_sums_is_decided_on_the_capture_grid(small_capture, queue,
                                                                   monkeypatch):
    """Where no candidate agrees on the block sums (here: a bar above 1), the search runs
    again on the capture's own grid, which decides the most reproducible candidate: the
    params name that grid and its kappas are those of the search without block sums; the
    block sums' search is recorded beside it (every candidate tried there too)."""
    import clnlos.inverse.parameter_choice as pc

    cap, _ = small_capture
    cfg = _config(cap, method="fk")
    monkeypatch.setattr(pc, "kappa_min", lambda lightcone_filter: 1.01)
    own = reconstruct(cap, cfg, device=queue).params
    _search_bounds(monkeypatch, 8, 8)
    p = reconstruct(cap, cfg, device=queue).params
    nt = int(p["reproducibility_grid"].split("x")[0])
    assert p["reproducibility_grid"] == own["reproducibility_grid"] == f"{nt}x16x16"
    assert p["reproducibility_tried"] == own["reproducibility_tried"]
    assert p["reproducibility_agreed"] is False and p["snr_used"] == own["snr_used"]
    assert p["reproducibility_block_grid"] == f"{nt}x8x8"
    block = json.loads(p["reproducibility_block_tried"])
    assert len(block) == len(SLAB_SNRS_SLAB_ONLY) and all(k < 1.01 for *_, k in block)
    assert block != json.loads(p["reproducibility_tried"])  # the kappas of other masks
