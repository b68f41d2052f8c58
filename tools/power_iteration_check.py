"""How many power iterations the iterative method's step size needs (issue 59).

The solver's step is 1 / L with L = 1.05 x the power iteration's estimate of ||L^T L||
(``clnlos.inverse.solvers.lipschitz``, ``POWER_ITERATIONS`` from a seeded uniform start).
The estimate rises towards the norm from below; an estimate short of it by more than the 5%
margin would give a step past 1 / ||L^T L||. This tool builds the light-cone transports the
method builds (the LCT release's grids and falloffs, the CDT captures' grid, the lobe
search's 32 x 32 x 256 grids, the glossy 'E' behind the slab; the Lambertian lobe and the
known lobes: GGX alpha 0.3 / 0.1 / 0.03 / 0.01, the retroreflector; the search's lobes in
their finer terms), two finer scan pitches (3 and 6 mm), and records each estimate after 4,
6, 8, 10 and 15 iterations against 60 (float64 on the host's device).
Writes tools/results/experiments/power_iterations/<stem>.{csv,json}.

    .venv/bin/python tools/power_iteration_check.py [--stem power_iterations]
"""

from __future__ import annotations

import argparse
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "tools" / "results" / "experiments" / "power_iterations"
COUNTS = (4, 6, 8, 10, 15)
REFERENCE = 60

# name, shape [t, y, x], bin width (s), scan width (m), support from (m), falloff p, whether
# the lobe search builds it (its lobes' terms within SEARCH_LOBE_TOLERANCE, else the
# inversion's INVERSION_LOBE_TOLERANCE)
GRIDS = (
    ("LCT release S + U (retro falloff)", (512, 64, 64), 16e-12, 0.7, 0.2, 2.0, False),
    ("LCT release diffuse S", (512, 64, 64), 16e-12, 0.7, 0.2, 4.0, False),
    ("LCT release charts 40 cm", (512, 64, 64), 16e-12, 0.4, 0.2, 2.0, False),
    ("LCT release outdoor S", (1024, 32, 32), 16e-12, 1.0, 0.2, 2.0, False),
    ("lobe search, outdoor S", (256, 32, 32), 64e-12, 1.0, 0.2, 2.0, True),
    ("lobe search, S + U", (256, 32, 32), 32e-12, 0.7, 0.2, 2.0, True),
    ("CDT capture 32 x 32", (512, 32, 32), 16e-12, 0.7, 0.3, 4.0, False),
    ("glossy E behind the slab", (160, 24, 24), 48e-12, 0.6, 0.35, 4.0, False),
    ("glossy E, lobe search", (160, 24, 24), 48e-12, 0.6, 0.35, 4.0, True),
    ("fine pitch: 32 points over 0.2 m", (256, 32, 32), 32e-12, 0.2, 0.2, 4.0, False),
    ("fine pitch: 32 points over 0.1 m", (256, 32, 32), 32e-12, 0.1, 0.2, 4.0, False),
)


def main(argv=None) -> int:
    import numpy as np
    import pyopencl.array as cla

    from clnlos.bench.oracle import write_rows
    from clnlos.brdf.lobes import auto_challengers, auto_ladder
    from clnlos.inverse.iterative import IterativeInversion
    from clnlos.inverse.solvers import power_norm
    from clnlos.physics.lobe import SEARCH_LOBE_TOLERANCE
    from clnlos.runtime.device import get_queue

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stem", default="power_iterations")
    a = ap.parse_args(argv)
    q = get_queue(None)
    rows = []
    for name, shape, bw, width, depth_min, falloff, search in GRIDS:
        inv = IterativeInversion(shape, bin_width_s=bw, scan_width_m=width, iterations=1,
                                 l1_weight=0.1, tv_weight=0.0, falloff=falloff,
                                 dtype=np.float64, queue=q)
        if search:
            inv.lobe_tolerance = SEARCH_LOBE_TOLERANCE
        for lobe in auto_ladder() + auto_challengers():
            inv.set_lobe(lobe)
            op = inv.transport(depth_min)
            start = cla.to_device(q, np.random.default_rng(0).random(shape))
            ref = power_norm(op, start, REFERENCE)[0]
            row = {"grid": name, "shape": "x".join(map(str, shape)), "lobe": lobe.name,
                   "terms": op.lobe.terms, f"norm_{REFERENCE}": ref}
            for k in COUNTS:
                row[f"ratio_{k}"] = power_norm(op, start, k)[0] / ref
            rows.append(row)
            print(f"{name:34s} {lobe.name:18s} " + " ".join(
                f"{k}: {row[f'ratio_{k}']:.4f}" for k in COUNTS), flush=True)
    for k in COUNTS:
        worst = min(r[f"ratio_{k}"] for r in rows)
        print(f"{k:2d} iterations: lowest estimate {worst:.4f} of the {REFERENCE}-iteration norm")
    paths = write_rows(rows, OUT / a.stem)
    print("wrote", *paths)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
