"""The slab SNR's thinning rule (``snr_rule = "thinning"``, :mod:`clnlos.inverse.thinning`)
against GCV's pick (``snr_rule = "gcv"``) and the stored oracle tables (:func:`clnlos.bench.oracle.
snr_rule_rows`): writes
tools/results/experiments/snr_rule_thinning/snr_rule_thinning[_both_ways].{csv,json} and prints
the mean change, the worst gap and the worst change against today.

    .venv/bin/python tools/snr_rule_check.py [--device P:D] [--holdout-seeds 2]
        [--table-seeds] [--sweep-seeds] [--fresh-seeds 3] [--both-ways] [--out STEM]

``--both-ways`` lets the search lower GCV's pick too (factors 1e-2 to 1e2): the measurement
that set CV_FACTOR_RANGE (deeper only). The defaults are the check after it: captures the
choice had not seen (the held-out captures at noise seed 2, FRESH_CASES at seed 3).
Captures without a stored oracle row (or whose row was not made at GCV's pick) get GCV's IoU
run here and no oracle.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from clnlos.bench.harness import read_rows
from clnlos.bench.oracle import (
    HOLDOUT_CASES,
    ORACLE_CASES,
    SWEEP_CASE,
    SWEEP_EXPOSURES_S,
    OracleCase,
    case_named,
    snr_rule_rows,
    write_rows,
)
from clnlos.inverse.pipeline import ReconstructionPipeline

RESULTS = Path(__file__).resolve().parent / "results" / "experiments"
ORACLE = RESULTS / "oracle"  # the stored oracle rows (tools/oracle_params.py)
OUT = RESULTS / "snr_rule_thinning"
BOTH_WAYS = (1e-2, 1e2)
# letters and bins neither the table nor the held-out captures have (48 and 64 ps bins too)
FRESH_CASES = (
    OracleCase("A 0.25 m, scan 0.5 m, 0.55 m deep, 0.1 s, 48 ps", "A", 0.25, 0.55, 0.5, 0.1,
               bins=192, bin_width_s=48e-12),
    OracleCase("Z 0.3 m, scan 0.6 m, 0.5 m deep, 0.3 s, 64 ps", "Z", 0.3, 0.5, 0.6, 0.3,
               bins=144, bin_width_s=64e-12),
    OracleCase("N 0.2 m, scan 0.45 m, 0.45 m deep, 0.02 s, 48 ps", "N", 0.2, 0.45, 0.45,
               0.02, bins=192, bin_width_s=48e-12),
    OracleCase("R 0.25 m, scan 0.5 m, 0.6 m deep, 1 s", "R", 0.25, 0.6, 0.5, 1.0),
    OracleCase("plus 0.15 m, scan 0.35 m, 0.55 m deep, 0.1 s", "plus", 0.15, 0.55, 0.35, 0.1),
    OracleCase("V 0.3 m, scan 0.6 m, 0.7 m deep, 0.03 s", "V", 0.3, 0.7, 0.6, 0.03),
)


def _stored(name: str) -> list[dict]:
    path = ORACLE / f"{name}.json"
    return read_rows(path) if path.exists() else []


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None)
    ap.add_argument("--holdout-seeds", nargs="*", type=int, default=[2])
    ap.add_argument("--table-seeds", nargs="*", type=int, default=[])
    ap.add_argument("--sweep-seeds", nargs="*", type=int, default=[])
    ap.add_argument("--fresh-seeds", nargs="*", type=int, default=[3])
    ap.add_argument("--both-ways", action="store_true",
                    help="let the search lower GCV's pick too (factors 1e-2 to 1e2)")
    ap.add_argument("--out", default=None,
                    help="results stem under tools/results/experiments/snr_rule_thinning "
                         "(default snr_rule_thinning"
                         "[_both_ways]): another selection of captures keeps the stored one")
    a = ap.parse_args(argv)
    if a.both_ways:
        ReconstructionPipeline.thinning_factor_range = BOTH_WAYS
    rows = snr_rule_rows(FRESH_CASES, a.fresh_seeds, [], queue=a.device)
    rows += snr_rule_rows(HOLDOUT_CASES, a.holdout_seeds, _stored("oracle_holdout"),
                          queue=a.device)
    rows += snr_rule_rows(ORACLE_CASES, a.table_seeds, _stored("oracle_seeds"), queue=a.device)
    sweep = [r for r in _stored("exposure_sweep") if r["method"] == "iterative"]
    case = case_named(SWEEP_CASE)
    for e in SWEEP_EXPOSURES_S if a.sweep_seeds else ():
        stored = [{**r, "capture": f"sweep {e:g} s"} for r in sweep if r["exposure_s"] == e]
        rows += snr_rule_rows([replace(case, name=f"sweep {e:g} s", exposure_s=e)],
                              a.sweep_seeds, stored, queue=a.device)
    stem = a.out or "snr_rule_thinning" + ("_both_ways" if a.both_ways else "")
    print("wrote", *write_rows(rows, OUT / stem))
    change = np.array([r["rule_iou"] - r["gcv_iou"] for r in rows])
    print(f"{len(rows)} captures: mean change {change.mean():+.3f}, up by > 0.01 on "
          f"{int(np.sum(change > 0.01))}, down by > 0.01 on {int(np.sum(change < -0.01))} "
          f"(worst {change.min():+.3f})")
    gaps = [r for r in rows if r["gap"] is not None]
    if gaps:
        worst = max(gaps, key=lambda r: r["gap"])
        low = min(gaps, key=lambda r: r["vs_today"])
        print(f"worst gap {worst['gap']:+.3f} ({worst['capture']}, seed {worst['seed']}); "
              f"worst against today {low['vs_today']:+.3f} ({low['capture']})")


if __name__ == "__main__":
    main()
