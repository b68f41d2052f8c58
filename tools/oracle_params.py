"""The auto reconstruction parameters against the oracle grid and across exposures
(:mod:`clnlos.bench.oracle`): writes tools/results/experiments/oracle/oracle_params.{csv,json}
and exposure_sweep.{csv,json} and prints the worst gaps (every file below is in that folder).

    .venv/bin/python tools/oracle_params.py [--device P:D] [--iterations N] [--no-sweep]
        [--no-table] [--case NAME_PART ... --update] [--methods M ...]
        [--seeds S ...]   (the table over these noise seeds, with mean and spread:
                           oracle_seeds{,_summary}.{csv,json}; with --update
                           the rows of other cases and methods are kept)
        [--holdout]       (HOLDOUT_CASES instead of ORACLE_CASES, with --seeds:
                           oracle_holdout{,_summary}.{csv,json})
        [--random SEED [--count N]]
                          (N captures drawn by clnlos.bench.oracle.random_cases(SEED), with
                           --seeds: oracle_random_SEED{,_summary}.{csv,json})
        [--grids]         (with --seeds: every grid setting's IoU and the transfer test of
                           the oracle, clnlos.bench.oracle.transfer_rows:
                           oracle_grids{,_holdout}{,_transfer}.{csv,json};
                           --methods default lct fk here)
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from clnlos.bench.harness import read_rows
from clnlos.bench.oracle import (
    HOLDOUT_CASES,
    METHODS,
    ORACLE_CASES,
    SWEEP_CASE,
    case_named,
    exposure_sweep,
    grid_rows,
    oracle_rows,
    random_cases,
    seed_spread,
    sweep_summary,
    transfer_rows,
    write_rows,
)

RESULTS = Path(__file__).resolve().parent / "results" / "experiments" / "oracle"


def _ordered(rows: list[dict]) -> list[dict]:
    """Rows in the order of ORACLE_CASES and HOLDOUT_CASES, then METHODS, then seed."""
    order = {c.name: i for i, c in enumerate(ORACLE_CASES + HOLDOUT_CASES)}
    return sorted(rows, key=lambda r: (order.get(r["capture"], len(order)),
                                       METHODS.index(r["method"]), r.get("seed", 0)))


def _grids(args) -> None:
    """--grids: grid_rows over the seeds, transfer_rows of them, and a summary per method."""
    pool = HOLDOUT_CASES if args.holdout else ORACLE_CASES
    cases = [c for c in pool if not args.case or any(s in c.name for s in args.case)]
    rows = grid_rows(cases, args.seeds, args.methods, iterations=args.iterations,
                     queue=args.device)
    stem = RESULTS / ("oracle_grids_holdout" if args.holdout else "oracle_grids")
    print("wrote", *write_rows(rows, stem))
    moved = transfer_rows(rows)
    print("wrote", *write_rows(moved, stem.with_name(stem.name + "_transfer")))
    for m in dict.fromkeys(r["method"] for r in moved):
        mine = [r for r in moved if r["method"] == m]
        n = len(mine)
        print(f"{m}: {n} rows; gap > 0.08 on {sum(r['gap'] > 0.08 for r in mine)}, "
              f"transfer_gap > 0.08 on {sum(r['transfer_gap'] > 0.08 for r in mine)} "
              f"(<= 0.01 on {sum(r['transfer_gap'] <= 0.01 for r in mine)}), mean gap "
              f"{np.mean([r['gap'] for r in mine]):.3f}, mean transfer_gap "
              f"{np.mean([r['transfer_gap'] for r in mine]):.3f}")


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
    ap.add_argument("--methods", nargs="+", default=None, choices=METHODS,
                    help="default: every method (with --grids: lct fk)")
    ap.add_argument("--seeds", nargs="+", type=int, default=None,
                    help="the table over these noise seeds (mean and spread per row)")
    ap.add_argument("--no-grid", action="store_true",
                    help="with --seeds: auto and today only, no oracle grid")
    ap.add_argument("--holdout", action="store_true",
                    help="with --seeds: the held-out cases (HOLDOUT_CASES)")
    ap.add_argument("--random", type=int, default=None, metavar="SEED",
                    help="with --seeds: captures drawn by random_cases(SEED)")
    ap.add_argument("--count", type=int, default=16, help="with --random: how many")
    ap.add_argument("--grids", action="store_true",
                    help="with --seeds (at least 2): keep every grid setting, test the "
                         "oracle's lead by transfer across seeds")
    args = ap.parse_args(argv)
    for flag in ("holdout", "grids", "random"):
        if getattr(args, flag) not in (None, False) and args.seeds is None:
            ap.error(f"--{flag} needs --seeds")
    if args.count != 16 and args.random is None:
        ap.error("--count needs --random")
    if args.holdout and args.random is not None:
        ap.error("--holdout and --random choose different captures: give one")
    if args.grids and len(set(args.seeds)) < 2:
        ap.error("--grids needs at least 2 distinct --seeds (the transfer test)")
    if args.methods is None:
        args.methods = ["lct", "fk"] if args.grids else list(METHODS)
    if args.grids:
        _grids(args)
        return
    if args.seeds is not None:
        pool = (HOLDOUT_CASES if args.holdout else ORACLE_CASES if args.random is None
                else random_cases(args.random, args.count))
        cases = [c for c in pool if not args.case or any(s in c.name for s in args.case)]
        rows = oracle_rows(cases, args.methods, iterations=args.iterations, seeds=args.seeds,
                           grid=not args.no_grid, queue=args.device)
        stem = RESULTS / ("oracle_holdout" if args.holdout else "oracle_seeds"
                          if args.random is None else f"oracle_random_{args.random}")
        if args.update and stem.with_suffix(".json").is_file():
            new = {(r["capture"], r["method"], r["seed"]) for r in rows}  # other seeds kept
            kept = [r for r in read_rows(stem.with_suffix(".json"))
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
            kept = [r for r in read_rows(table)
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
        rows = exposure_sweep(case_named(SWEEP_CASE), methods=args.methods,
                              iterations=args.iterations, queue=args.device)
        sweep = RESULTS / "exposure_sweep.json"
        if args.update and sweep.is_file():  # the other methods' rows kept
            kept = [r for r in read_rows(sweep) if r["method"] not in args.methods]
            rows = sorted(kept + rows, key=lambda r: (r["exposure_s"], r["seed"],
                                                      METHODS.index(r["method"])))
        print("wrote", *write_rows(rows, RESULTS / "exposure_sweep"))
        summary = sweep_summary(rows)
        print("wrote", *write_rows(summary, RESULTS / "exposure_sweep_summary"))
        for r in summary:
            print(f"{r['method']} {r['exposure_s']:g} s: mean {r['mean_iou']:.3f} spread "
                  f"{r['spread']:.3f} drop {r['drop']:.3f}")


if __name__ == "__main__":
    main()
