"""The rule a measured capture gets, against the oracle (issue 59, item 6).

Under the defaults a capture's slab model is exact only where the file records the config's
own slab (a clnlos simulation): there LCT and f-k choose their SNRs by split-half
reproducibility, and the oracle tables (:mod:`clnlos.bench.oracle`) measure that search. A
measured capture gets the GCV rule with the model's accuracy MEASURED_MODEL_SNR combined
(:func:`clnlos.inverse.parameter_choice.model_snr_for`): this tool runs that rule on the
oracle's own captures (the config's ``model_snr`` set to MEASURED_MODEL_SNR, everything else
the defaults) and sets its IoU beside the stored rows of the same captures and seeds: the
default's (``stored_auto_iou``; ``auto_iou`` the default rerun on this commit), the GCV rule
with an exact model (``gcv_rule_iou``) and the oracle grid's best (``oracle_iou``). Writes
tools/results/measured_rule_check.{csv,json} (one row per capture, seed and method) and prints per
method the mean IoU and the rows more than 0.08 below the oracle.

    .venv/bin/python tools/measured_rule_check.py [--holdout] [--methods lct fk iterative]
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "tools" / "results"
STORED = RESULTS / "experiments" / "oracle"
MISS = 0.08  # a row this far below the oracle grid is a miss (docs/validation/parameter-rules.md)


def main(argv=None) -> int:
    from clnlos.bench.harness import read_rows
    from clnlos.bench.oracle import HOLDOUT_CASES, ORACLE_CASES, simulate_case, write_rows
    from clnlos.config import ReconstructionConfig
    from clnlos.inverse.pipeline import reconstruct
    from clnlos.inverse.snr import MEASURED_MODEL_SNR
    from clnlos.study.score.metrics import mip_iou

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--holdout", action="store_true", help="the held-out captures (seeds 1-2)")
    ap.add_argument("--methods", nargs="+", default=["lct", "fk", "iterative"])
    ap.add_argument("--out", default=None, help="path stem (default tools/results/"
                    "measured_rule_check[_holdout])")
    args = ap.parse_args(argv)
    stem = "oracle_holdout" if args.holdout else "oracle_seeds"
    stored = [r for r in read_rows(STORED / f"{stem}.json") if r["method"] in args.methods]
    cases = {c.name: c for c in (HOLDOUT_CASES if args.holdout else ORACLE_CASES)}
    rows, captures = [], {}
    for r in stored:
        key = (r["capture"], int(r["seed"]))
        if key not in captures:
            captures.clear()  # one capture at a time in memory
            captures[key] = simulate_case(replace(cases[r["capture"]], seed=key[1]))
        capture, mask = captures[key]
        cfg = ReconstructionConfig(slab=capture.recorded_slab()[0], method=r["method"],
                                   model_snr=MEASURED_MODEL_SNR).validate()
        rec = reconstruct(capture, cfg)
        iou = mip_iou(rec.volume, mask)[0]
        now = mip_iou(reconstruct(capture, cfg.replace(model_snr="auto").validate()).volume,
                      mask)[0]  # the default on this commit, beside the stored one
        row = {"capture": r["capture"], "seed": key[1], "method": r["method"],
               "measured_rule_iou": iou, "measured_rule_snr": rec.params.get("snr_used"),
               "measured_rule_inversion_snr": rec.params.get("inversion_snr_used"),
               "measured_rule": rec.params.get("snr_rule_used", "gcv"),
               "auto_iou": now, "stored_auto_iou": r["auto_iou"],
               "auto_snr_rule": r.get("auto_snr_rule") or "gcv",
               "gcv_rule_iou": r.get("gcv_rule_iou"), "oracle_iou": r["oracle_iou"],
               "measured_gap": r["oracle_iou"] - iou, "auto_gap": r["oracle_iou"] - now}
        rows.append(row)
        print(f"{r['capture']} seed {key[1]} [{r['method']}]: measured rule {iou:.3f} "
              f"(SNR {row['measured_rule_snr']}), default {now:.3f}, oracle "
              f"{r['oracle_iou']:.3f}", flush=True)
    out = Path(args.out) if args.out else RESULTS / ("measured_rule_check_holdout"
                                                     if args.holdout else "measured_rule_check")
    print("wrote", *write_rows(rows, out))
    for m in args.methods:
        mine = [r for r in rows if r["method"] == m]
        if not mine:
            continue
        print(f"{m}: {len(mine)} rows; mean IoU measured rule "
              f"{np.mean([r['measured_rule_iou'] for r in mine]):.3f}, default "
              f"{np.mean([r['auto_iou'] for r in mine]):.3f}, oracle "
              f"{np.mean([r['oracle_iou'] for r in mine]):.3f}; > {MISS} below the oracle: "
              f"measured rule {sum(r['measured_gap'] > MISS for r in mine)}, default "
              f"{sum(r['auto_gap'] > MISS for r in mine)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
