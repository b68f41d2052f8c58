"""The error of the seed's confocal approximation (Eq. 9) against Eq. 8 per material preset.

Writes tools/results/confocal_error.csv and .json (confocal_error_<N>pt.* with --points N)
and prints the table (clnlos.study.findings.confocal_error.confocal_error_table: the issue's 6 cm
patch tilted 5 degrees, 0.5 m behind the CDT slab, at the study's 0.3 m scan of 32 x 32 points and
48 ps bins).

    .venv/bin/python tools/confocal_error.py [--points N] [--no-refine] [--device D]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from clnlos.bench.harness import print_table, write_rows
from clnlos.runtime.device import get_queue
from clnlos.study.findings.confocal_error import confocal_error_table

OUT = Path(__file__).resolve().parent / "results"
COLUMNS = ["material", "total_ratio", "worst_point_ratio", "rel_l2", "shape_error_peak",
           "eq8_quadrature_error", "lobe_halfwidth_deg", "footprint_spread_deg", "auto",
           "seconds_confocal", "seconds_bistatic"]


def main(argv=None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=None, help="scan points per side "
                    "(default: the study's 32)")
    ap.add_argument("--no-refine", action="store_true", help="skip the refined Eq. 8 run")
    ap.add_argument("--device", default=None)
    args = ap.parse_args(argv)
    rows = confocal_error_table(points=args.points, refine=not args.no_refine,
                                queue=get_queue(args.device))
    stem = "confocal_error" + (f"_{args.points}pt" if args.points else "")
    csv_path, json_path = write_rows(rows, OUT, stem)
    print_table(rows, [c for c in COLUMNS if any(c in r for r in rows)])
    print(f"wrote {csv_path} and {json_path}")
    return rows


if __name__ == "__main__":
    main()
