"""The exposure planner's arithmetic (clnlos.study.findings.exposure) and the real check's
refined thinning ladder (clnlos.study.real.check): pure functions on known inputs."""

import math

import numpy as np
import pytest

from clnlos.study.findings.exposure import (
    BELOW,
    BEYOND,
    BRACKETED,
    allowed_failures,
    exposure_needed,
    isotonic,
    need_order,
    refinement,
    rung_stopped,
    rungs_to_render,
)
from clnlos.study.real.ladder import AT_MOST, bounded_ratio, series_crossing, series_summary
from clnlos.study.score.legibility import wilson_interval


def _curve(exposures, ks, n=4, photons_per_s=1e9):
    return [{"exposure_s": e, "photons": e * photons_per_s, "n": n, "k": k,
             "fraction": k / n, "ci": wilson_interval(k, n)} for e, k in zip(exposures, ks,
                                                                            strict=True)]


def test_isotonic_pools_violators_and_keeps_monotone_data():
    assert isotonic([0, 0.5, 1], [1, 1, 1]) == [0, 0.5, 1]
    assert isotonic([0, 1, 0.5, 1], [1, 1, 1, 1]) == pytest.approx([0, 0.75, 0.75, 1])
    assert isotonic([1, 0], [3, 1]) == pytest.approx([0.75, 0.75])


def test_exposure_needed_interpolates_in_log_exposure_within_the_bracket():
    pts = _curve([1e-4, 1e-3, 1e-2], [0, 2, 4])          # fit 0, 0.5, 1: L = 0.9
    a = exposure_needed(pts, 0.9)
    assert a["status"] == BRACKETED and a["bracket_s"] == [1e-3, 1e-2]
    w = (0.9 - 0.5) / 0.5
    assert a["exposure_needed_s"] == pytest.approx(10 ** (-3 + w))
    assert a["photons_needed"] == pytest.approx(a["exposure_needed_s"] * 1e9)
    lo, hi = a["exposure_needed_interval_s"]
    # 2/4 has a Wilson upper bound above 0.9: that rung may already read in 90%
    assert lo == 1e-3 and hi == 1e-2 and lo <= a["exposure_needed_s"] <= hi
    assert (a["k"], a["n"]) == (4, 4) and a["legible_interval"][0] < 1.0


def test_exposure_needed_never_invents_a_number_beyond_the_sweep():
    a = exposure_needed(_curve([1e-4, 1e-3], [0, 1]), 0.9)
    assert a["status"] == BEYOND and a["exposure_needed_s"] is None
    assert a["exposure_needed_interval_s"][1] is None and a["bracket_s"] == [1e-3, None]
    b = exposure_needed(_curve([1e-4, 1e-3], [4, 4]), 0.9)
    assert b["status"] == BELOW and b["exposure_needed_s"] is None
    assert b["exposure_needed_interval_s"] == [None, 1e-4]
    # a dip is pooled with the rung before it: 4/4 then 3/4 is 7/8, below 0.9 at both
    c = exposure_needed(_curve([1e-5, 1e-4, 1e-3, 1e-2], [0, 4, 3, 4]), 0.9)
    assert c["status"] == BRACKETED and c["bracket_s"] == [1e-3, 1e-2]
    rows = [{"status": s, "exposure_needed_s": e, "exposure_needed_interval_s": i}
            for s, e, i in ((BEYOND, None, [1e-3, None]), (BRACKETED, 5e-4, [1e-4, 1e-3]),
                            (BELOW, None, [None, 1e-6]))]
    assert [r["status"] for r in sorted(rows, key=need_order)] == [BELOW, BRACKETED, BEYOND]


def test_refinement_adds_rungs_evenly_in_log_exposure_until_the_bracket_is_fine():
    curves = {"a": _curve([1e-4, 1e-3, 1e-2], [0, 2, 4]),     # a decade: two rungs
              "b": _curve([1e-4, 1.4e-4], [0, 4]),           # fine already
              "c": _curve([1e-4, 1e-3], [0, 0]),             # beyond the sweep
              "d": _curve([1e-4, 2e-4], [0, 4])}             # 2x: one rung
    add = refinement(curves, 0.9, 1.5)
    assert set(add) == {"a", "d"}
    assert add["a"] == [pytest.approx(10 ** (-3 + 1 / 3)), pytest.approx(10 ** (-3 + 2 / 3))]
    assert add["d"] == [pytest.approx(math.sqrt(2) * 1e-4)]
    assert refinement(curves, 0.9, 0) == {}


def test_series_crossing_brackets_the_loss_within_the_ratio_on_nested_rungs():
    """A score that falls below the keep level at a known fraction of the photons: the
    series stops at the first lost rung, inserts rungs nested between the last kept and
    the first lost until they are within 1.5x, and the crossing lies between them."""
    rng = np.random.default_rng(0)
    counts = rng.poisson(50.0, size=(16, 4, 4)).astype(np.float32)
    total = float(counts.sum())
    true = 0.0123   # the score is the photons kept: 0.8 at this fraction
    seen = []

    def score(y):
        seen.append(y.copy())
        frac = float(y.sum()) / total
        return 1.0 - 0.2 * math.log(frac) / math.log(true)

    s = series_crossing(score, counts, seed=3, level=0.8, ratio=1.5)
    assert s["status"] == "bracketed"
    assert s["kept"] / s["lost"] <= 1.5 and s["lost"] <= s["crossing"] <= s["kept"]
    assert s["crossing"] == pytest.approx(true, rel=0.1)
    # every rung tried is nested: each holds a subset of the photons of every brighter one
    ordered = sorted(seen, key=lambda y: -float(y.sum()))
    for brighter, fainter in zip(ordered, ordered[1:], strict=False):
        assert np.all(fainter <= brighter)


def test_series_that_keeps_its_image_is_a_bound_and_bounds_stay_bounds():
    counts = np.full((8, 2, 2), 1000.0, np.float32)
    s = series_crossing(lambda y: 1.0, counts, seed=0, level=0.8)
    assert s["status"] == AT_MOST and s["lost"] is None
    summary = series_summary([s, s, s], 100.0)
    assert summary["status"] == AT_MOST and summary["interval"][0] is None
    val = {"photons_needed": 10.0, "status": "bracketed"}
    bound = {"photons_needed": 10.0, "status": AT_MOST}
    assert bounded_ratio(val, val) == (1.0, None)
    assert bounded_ratio(bound, val)[1] == "<=" and bounded_ratio(val, bound)[1] == ">="
    assert bounded_ratio(bound, bound)[1] == "unknown"


def test_curtailed_realisations_render_what_decides_the_answer():
    """Every rung once; then the two lowest live rungs, one realisation at a time, until the
    lowest is complete and reads; a rung stops once even its best completion rules the
    level out; rungs above the decided one that read a failure are completed."""
    assert allowed_failures(4, 0.9) == 0 and allowed_failures(4, 0.5) == 2
    assert allowed_failures(10, 0.9) == 1
    # the best completion of 1 failure in 4 is 3 of 4 (Wilson upper 0.954): not ruled out;
    # of 2 failures 2 of 4 (0.85): ruled out, whatever order they came in
    assert not rung_stopped(1, 4, 0.9) and rung_stopped(2, 4, 0.9)
    assert not rung_stopped(2, 4, 0.5) and rung_stopped(3, 10, 0.9)
    c = ("curve",)
    rung = {e: (c, e) for e in (1e-6, 1e-5, 1e-4, 1e-3)}
    state = {rung[e]: (0, 0, 4) for e in rung}
    assert set(rungs_to_render(state, 0.9)) == set(rung.values())   # each rung first
    # after one each: 1e-6 failed once (not yet ruled out), the rest read
    state = {rung[1e-6]: (1, 1, 4), rung[1e-5]: (1, 0, 4), rung[1e-4]: (1, 0, 4),
             rung[1e-3]: (1, 0, 4)}
    assert rungs_to_render(state, 0.9) == [rung[1e-6], rung[1e-5]]
    # 1e-6 fails again: stopped; 1e-5 fails its second: 1e-5 and 1e-4 go on
    state.update({rung[1e-6]: (2, 2, 4), rung[1e-5]: (2, 1, 4)})
    assert rungs_to_render(state, 0.9) == [rung[1e-5], rung[1e-4]]
    # 1e-5 complete at 3 of 4 (below the level, not stopped): it decides nothing
    state.update({rung[1e-5]: (4, 1, 4), rung[1e-4]: (2, 0, 4)})
    assert rungs_to_render(state, 0.9) == [rung[1e-4], rung[1e-3]]
    # 1e-4 complete and read: the curve is decided, 1e-3 (read once) keeps what it has
    state.update({rung[1e-4]: (4, 0, 4)})
    assert rungs_to_render(state, 0.9) == []
    # ... unless a rung above read a failure: it is completed, stopped or not
    state.update({rung[1e-3]: (1, 1, 4)})
    assert rungs_to_render(state, 0.9) == [rung[1e-3]]
    state.update({rung[1e-3]: (4, 2, 4)})
    assert rungs_to_render(state, 0.9) == []
    # at level 0.5 one failure in 4 leaves a rung live
    state = {rung[1e-6]: (1, 1, 4), rung[1e-5]: (1, 0, 4)}
    assert rungs_to_render(state, 0.5) == [rung[1e-6], rung[1e-5]]
    # two curves are independent
    d = ("other",)
    state = {rung[1e-6]: (4, 0, 4), (d, 1e-6): (1, 0, 2), (d, 1e-5): (2, 0, 2)}
    assert rungs_to_render(state, 0.9) == [(d, 1e-6)]
