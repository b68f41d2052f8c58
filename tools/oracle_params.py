"""The auto reconstruction parameters against the oracle grid and across exposures
(:mod:`clnlos.bench.oracle`): writes tools/results/oracle_params.{csv,json} and
tools/results/exposure_sweep.{csv,json} and prints the worst gaps.

    .venv/bin/python tools/oracle_params.py [--device P:D] [--iterations N] [--no-sweep]
        [--no-table] [--case NAME_PART ... --update]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from clnlos.bench.oracle import (
    ORACLE_CASES,
    exposure_sweep,
    oracle_rows,
    sweep_summary,
    write_rows,
)

RESULTS = Path(__file__).resolve().parent / "results"


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
                    help="replace these cases' rows in the existing table, keep the others")
    args = ap.parse_args(argv)
    if not args.no_table:
        cases = [c for c in ORACLE_CASES
                 if not args.case or any(s in c.name for s in args.case)]
        rows = oracle_rows(cases, iterations=args.iterations, queue=args.device)
        table = RESULTS / "oracle_params.json"
        if args.update and table.is_file():
            names = {c.name for c in cases}
            kept = [r for r in json.loads(table.read_text()) if r["capture"] not in names]
            order = {c.name: i for i, c in enumerate(ORACLE_CASES)}
            rows = sorted(kept + rows, key=lambda r: order.get(r["capture"], len(order)))
        print("wrote", *write_rows(rows, RESULTS / "oracle_params"))
        for m in dict.fromkeys(r["method"] for r in rows):
            mine = [r for r in rows if r["method"] == m]
            g = max(mine, key=lambda r: r["gap"])
            t = min(mine, key=lambda r: r["vs_today"])
            print(f"{m}: worst gap {g['gap']:+.3f} ({g['capture']}), worst against today "
                  f"{t['vs_today']:+.3f} ({t['capture']})")
    if not args.no_sweep:
        rows = exposure_sweep(ORACLE_CASES[0], iterations=args.iterations, queue=args.device)
        print("wrote", *write_rows(rows, RESULTS / "exposure_sweep"))
        summary = sweep_summary(rows)
        print("wrote", *write_rows(summary, RESULTS / "exposure_sweep_summary"))
        for r in summary:
            print(f"{r['method']} {r['exposure_s']:g} s: mean {r['mean_iou']:.3f} spread "
                  f"{r['spread']:.3f} drop {r['drop']:.3f}")


if __name__ == "__main__":
    main()
