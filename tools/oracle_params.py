"""The auto reconstruction parameters against the oracle grid and across exposures
(:mod:`clnlos.bench.oracle`): writes tools/results/oracle_params.{csv,json} and
tools/results/exposure_sweep.{csv,json} and prints the worst gaps.

    .venv/bin/python tools/oracle_params.py [--device P:D] [--iterations N] [--no-sweep]
        [--no-table] [--case NAME_PART ... --update] [--methods M ...]
        [--seeds S ...]   (the table over these noise seeds, with mean and spread:
                           tools/results/oracle_seeds{,_summary}.{csv,json}; with --update
                           the rows of other cases and methods are kept)
        [--holdout]       (HOLDOUT_CASES instead of ORACLE_CASES, with --seeds:
                           tools/results/oracle_holdout{,_summary}.{csv,json})
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from clnlos.bench.oracle import (
    HOLDOUT_CASES,
    METHODS,
    ORACLE_CASES,
    SWEEP_CASE,
    case_named,
    exposure_sweep,
    oracle_rows,
    seed_spread,
    sweep_summary,
    write_rows,
)

RESULTS = Path(__file__).resolve().parent / "results"


def _ordered(rows: list[dict]) -> list[dict]:
    """Rows in the order of ORACLE_CASES and HOLDOUT_CASES, then METHODS, then seed."""
    order = {c.name: i for i, c in enumerate(ORACLE_CASES + HOLDOUT_CASES)}
    return sorted(rows, key=lambda r: (order.get(r["capture"], len(order)),
                                       METHODS.index(r["method"]), r.get("seed", 0)))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None)
    ap.add_argument("--iterations", type=int, default=None,
                    help="iterative method's iterations (default: the config default)")
    ap.add_argument("--no-sweep", action="store_true", help="the oracle table only")
    ap.add_argument("--no-table", action="store_true", help="the exposure sweep only")
    ap.add_argument("--case", action="append", default=[],
                    help="only the cases whose name contains this (repeatable)")
    ap.add_argument("--update", action="store_true",
                    help="replace these cases' rows in the existing table (with --seeds: "
                         "these seeds' rows), keep the others")
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    ap.add_argument("--seeds", nargs="+", type=int, default=None,
                    help="the table over these noise seeds (mean and spread per row)")
    ap.add_argument("--no-grid", action="store_true",
                    help="with --seeds: auto and today only, no oracle grid")
    ap.add_argument("--holdout", action="store_true",
                    help="with --seeds: the held-out cases (HOLDOUT_CASES)")
    args = ap.parse_args(argv)
    if args.holdout and args.seeds is None:
        ap.error("--holdout needs --seeds")
    if args.seeds is not None:
        pool = HOLDOUT_CASES if args.holdout else ORACLE_CASES
        cases = [c for c in pool if not args.case or any(s in c.name for s in args.case)]
        rows = oracle_rows(cases, args.methods, iterations=args.iterations, seeds=args.seeds,
                           grid=not args.no_grid, queue=args.device)
        stem = RESULTS / ("oracle_holdout" if args.holdout else "oracle_seeds")
        if args.update and stem.with_suffix(".json").is_file():
            new = {(r["capture"], r["method"], r["seed"]) for r in rows}  # other seeds kept
            kept = [r for r in json.loads(stem.with_suffix(".json").read_text())
                    if (r["capture"], r["method"], r.get("seed", 0)) not in new]
            rows = _ordered(kept + rows)
        print("wrote", *write_rows(rows, stem))
        summary = seed_spread(rows)
        print("wrote", *write_rows(summary, stem.with_name(stem.name + "_summary")))
        for r in summary:
            oracle = ("" if r["oracle_iou_mean"] is None else
                      f" oracle {r['oracle_iou_mean']:.3f} gap {r['gap_mean']:+.3f}")
            print(f"{r['capture']} [{r['method']}]: auto {r['auto_iou_mean']:.3f} "
                  f"(+-{r['auto_iou_spread'] / 2:.3f}) today {r['today_iou_mean']:.3f} "
                  f"(+-{r['today_iou_spread'] / 2:.3f}){oracle} vs today "
                  f"{r['vs_today_mean']:+.3f}{' REGRESSION' if r['regression'] else ''}")
        return
    if not args.no_table:
        cases = [c for c in ORACLE_CASES
                 if not args.case or any(s in c.name for s in args.case)]
        rows = oracle_rows(cases, args.methods, iterations=args.iterations,
                           queue=args.device)
        table = RESULTS / "oracle_params.json"
        if args.update and table.is_file():
            new = {(r["capture"], r["method"]) for r in rows}
            kept = [r for r in json.loads(table.read_text())
                    if (r["capture"], r["method"]) not in new]
            rows = _ordered(kept + rows)
        print("wrote", *write_rows(rows, RESULTS / "oracle_params"))
        for m in dict.fromkeys(r["method"] for r in rows):
            mine = [r for r in rows if r["method"] == m]
            g = max(mine, key=lambda r: r["gap"])
            t = min(mine, key=lambda r: r["vs_today"])
            print(f"{m}: worst gap {g['gap']:+.3f} ({g['capture']}), worst against today "
                  f"{t['vs_today']:+.3f} ({t['capture']})")
    if not args.no_sweep:
        rows = exposure_sweep(case_named(SWEEP_CASE), iterations=args.iterations,
                              queue=args.device)
        print("wrote", *write_rows(rows, RESULTS / "exposure_sweep"))
        summary = sweep_summary(rows)
        print("wrote", *write_rows(summary, RESULTS / "exposure_sweep_summary"))
        for r in summary:
            print(f"{r['method']} {r['exposure_s']:g} s: mean {r['mean_iou']:.3f} spread "
                  f"{r['spread']:.3f} drop {r['drop']:.3f}")


if __name__ == "__main__":
    main()
