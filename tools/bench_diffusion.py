#!/usr/bin/env python3
"""What accuracy costs in time for the slab diffusion kernel.

Error (relative L2 against float64 auto mode, which is converged to 1e-17 per sample) and
time for n_dipoles in {1,2,3,5,10,20,auto} x {float32, float64} on the chosen device,
evaluating the CDT PSF table (rho on a 64 x 64 grid of 1 cm pitch x 512 bins of 16 ps), plus
the same evaluation in vectorised numpy float64 (M = 20) for the ratio.

    python tools/bench_diffusion.py [--device SPEC] [-o DIR] [--quick]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from benchlib import device_meta, print_table, timeit, write_rows

from clnlos.bench.baselines import numpy_transmittance
from clnlos.diffusion import SlabTransmittance, grid_offsets
from clnlos.physics.slab import CDT_SLAB
from clnlos.runtime.device import get_queue, has_fp64


def main(argv=None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument("--device", default=None)
    ap.add_argument("-o", "--out", default="out/bench", type=Path)
    ap.add_argument("--quick", action="store_true", help="smaller grid, fewer repeats")
    args = ap.parse_args(argv)

    q = get_queue(args.device)
    slab = CDT_SLAB
    n, nt = (32, 256) if args.quick else (64, 512)
    off = grid_offsets(n, 0.01)
    rho = np.sqrt(off[:, None] ** 2 + off[None, :] ** 2).ravel()
    t = np.arange(nt) * 16e-12
    import pyopencl.array as cla

    dtypes = [np.float32] + ([np.float64] if has_fp64(q.device) else [])
    ref_plan = SlabTransmittance(slab, n_dipoles=None, dtype=dtypes[-1], queue=q)
    ref = ref_plan.outer_device(cla.to_device(q, rho.astype(dtypes[-1])),
                                cla.to_device(q, t.astype(dtypes[-1]))).get().astype(np.float64)
    meta = device_meta(q)
    rows = []
    repeat = 3 if args.quick else 7
    for dt in dtypes:
        rho_g = cla.to_device(q, rho.astype(dt))
        t_g = cla.to_device(q, t.astype(dt))
        for M in (1, 2, 3, 5, 10, 20, None):
            plan = SlabTransmittance(slab, n_dipoles=M, dtype=dt, queue=q)
            timing = timeit(lambda p=plan, r=rho_g, t=t_g: p.outer_device(r, t), q,
                            repeat=repeat)
            out = plan.outer_device(rho_g, t_g).get().astype(np.float64)
            err = float(np.linalg.norm(out - ref) / np.linalg.norm(ref))
            rows.append({**meta, "kernel": "diffusion", "knob": "n_dipoles",
                         "value": "auto" if M is None else M, "dtype": np.dtype(dt).name,
                         "impl": "opencl", "samples": rho.size * t.size, **timing,
                         "error": err})
    R, T = rho[None, :], t[:, None]
    timing = timeit(lambda: numpy_transmittance(slab, R, T, 20), repeat=max(2, repeat // 2))
    err = float(np.linalg.norm(numpy_transmittance(slab, R, T, 20) - ref) / np.linalg.norm(ref))
    rows.append({**meta, "kernel": "diffusion", "knob": "n_dipoles", "value": 20,
                 "dtype": "float64", "impl": "numpy", "samples": rho.size * t.size, **timing,
                 "error": err})
    np_time = rows[-1]["median_s"]
    for r in rows:
        r["speedup_vs_numpy"] = np_time / r["median_s"]
    print(f"device: {meta['device']} ({meta['platform']}, PoCL {meta['pocl']}); "
          f"{rho.size} radii x {t.size} bins = {rho.size * t.size} samples")
    print_table(rows, ["impl", "dtype", "value", "median_s", "min_s", "error",
                       "speedup_vs_numpy"])
    csv_path, _ = write_rows(rows, args.out, "bench_diffusion")
    print(f"wrote {csv_path}")
    return rows


if __name__ == "__main__":
    main()
