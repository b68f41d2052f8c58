"""The reproducibility search on block sums against the search on the capture's own grid (issue 59).

A capture of more than REPRODUCIBILITY_SEARCH_POINTS scan points per side is searched on its
counts summed over blocks of scan points (``ReconstructionPipeline.reproducibility_snrs``);
this tool reconstructs captures of ``--points`` per side (random glyphs behind the CDT slab,
:func:`clnlos.bench.oracle.random_cases` with the scan made ``--points`` wide, ``--bins``
bins of 16 ps, the exposure divided by ``--dim`` for the dimmer draws) by LCT and f-k with
the default rule twice: searched on the capture's own grid (the constant raised past the
capture) and on the block sums (the default), and records both choices, their IoU with the
true mask and their wall times. Writes tools/results/experiments/search_grid/<stem>.{csv,json}
and prints the rows whose choice differs.

    .venv/bin/python tools/search_grid_check.py [--draws 20261207:6 20261208:8 20261209:5/30]
        [--points 128] [--bins 512] [--stem search_grid]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "tools" / "results" / "experiments" / "search_grid"


def draws(spec: list[str]) -> list[tuple[int, int, float]]:
    """(seed, count, exposure divisor) per ``SEED:COUNT[/DIVISOR]``."""
    out = []
    for s in spec:
        seed, rest = s.split(":")
        count, _, dim = rest.partition("/")
        out.append((int(seed), int(count), float(dim or 1)))
    return out


def main(argv=None) -> int:
    import clnlos.inverse.reproducibility as choice
    from clnlos.bench.oracle import random_cases, simulate_case, write_rows
    from clnlos.config import ReconstructionConfig
    from clnlos.inverse.pipeline import reconstruct
    from clnlos.runtime.caches import PIPELINES
    from clnlos.study.score.metrics import mip_iou

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", nargs="+", default=["20261207:6", "20261208:8", "20261209:5/30"])
    ap.add_argument("--points", type=int, default=128)
    ap.add_argument("--bins", type=int, default=512)
    ap.add_argument("--stem", default="search_grid")
    a = ap.parse_args(argv)
    default = choice.REPRODUCIBILITY_SEARCH_POINTS
    rows = []
    for seed, count, dim in draws(a.draws):
        for case in random_cases(seed, count):
            case = replace(case, points=a.points, bins=a.bins, bin_width_s=16e-12,
                           exposure_s=case.exposure_s / dim)
            capture, mask = simulate_case(case)
            for method in ("lct", "fk"):
                row = {"draw": seed, "capture": case.name, "exposure_s": case.exposure_s,
                       "points": a.points, "method": method}
                for label, points in (("own", a.points), ("blocks", default)):
                    choice.REPRODUCIBILITY_SEARCH_POINTS = points
                    PIPELINES.clear()  # each rule's pipelines built afresh (timed alike)
                    cfg = ReconstructionConfig(slab=capture.recorded_slab()[0],
                                               method=method).validate()
                    t0 = time.perf_counter()
                    rec = reconstruct(capture, cfg)
                    p = rec.params
                    row.update({f"{label}_wall_s": round(time.perf_counter() - t0, 2),
                                f"{label}_iou": round(float(mip_iou(rec.volume, mask)[0]), 4),
                                f"{label}_snr": p.get("snr_used"),
                                f"{label}_inversion_snr": p.get("inversion_snr_used"),
                                f"{label}_kappa": p.get("reproducibility_kappa"),
                                f"{label}_agreed": p.get("reproducibility_agreed"),
                                f"{label}_grid": p.get("reproducibility_grid")})
                choice.REPRODUCIBILITY_SEARCH_POINTS = default
                row["photons"] = float(rec.noise.get("total", 0.0))
                row["same_choice"] = ((row["own_snr"], row["own_inversion_snr"])
                                      == (row["blocks_snr"], row["blocks_inversion_snr"]))
                rows.append(row)
                print(f"{case.name[:48]:48s} {method:4s} own {row['own_iou']:.3f} "
                      f"({row['own_wall_s']:.1f} s) blocks {row['blocks_iou']:.3f} "
                      f"({row['blocks_wall_s']:.1f} s){'' if row['same_choice'] else '  differs'}",
                      flush=True)
    paths = write_rows(rows, OUT / a.stem)
    same = sum(r["same_choice"] for r in rows)
    print(f"same choice on {same} of {len(rows)} rows; wrote {paths[0]} and {paths[1]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
