#!/usr/bin/env python3
"""Light-cone accumulation: element-scan-point pairs per second, total time, error vs density.

UT letters (0.3 m high) 0.5 m from the scan plane, Lambertian, no slab: the light-cone
stage alone, at 32x32x512 and 64x64x1024, OpenCL (float32 / float64, linear splatting) vs
a vectorised numpy float64 implementation of the same sum; then the error of each sampling
density against a dense float64 reference (4e6 elements/m^2) and its cost; then, through the
slab, the blur-reach tolerance (how far past the scan border I is computed) against the
capture of a widened grid (tol 1e-5) and the forward model's time.

    python tools/bench_forward.py [--device SPEC] [-o DIR] [--quick]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import device_meta, print_table, timeit, write_rows  # noqa: E402

from clnlos.bench.baselines import numpy_lightcone, ut_scene  # noqa: E402
from clnlos.forward.model import LightCone, sample_scene  # noqa: E402
from clnlos.forward.scene import Scene  # noqa: E402
from clnlos.runtime.device import get_queue, has_fp64  # noqa: E402


def blur_reach_rows(q, meta, quick: bool) -> list[dict]:
    """Built-in demo scene (Table 1: UT behind the slab, 0.3 m scan): error of the capture
    for each blur_reach_tol (1 = no margin, the scan grid alone) against tol 1e-5, and the
    time of ForwardModel.run (light cone on the widened grid + blur + pulse)."""
    import importlib.resources
    import tomllib

    from clnlos.forward.model import ForwardModel

    base = tomllib.loads(importlib.resources.files("clnlos").joinpath(
        "data/demo_scene.toml").read_text())

    def model(tol):
        d = {**base, "sampling": {**base["sampling"], "blur_reach_tol": tol}}
        return ForwardModel(Scene.from_dict(d), queue=q)

    ref = model(1e-5).run().astype(np.float64)
    rows = []
    for tol in ((1.0, 1e-3) if quick else (1.0, 1e-1, 1e-2, 1e-3, 1e-4)):
        fm = model(tol)
        t = timeit(fm.run, q, repeat=3)
        err = float(np.linalg.norm(fm.run() - ref) / np.linalg.norm(ref))
        rows.append({**meta, "kernel": "forward(slab)", "knob": "blur_reach_tol",
                     "value": f"{tol:g} (margin {fm.margin})", "dtype": "float32",
                     "impl": "opencl", "elements": len(fm.samples.elements), **t,
                     "error": err})
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None)
    ap.add_argument("-o", "--out", default="out/bench", type=Path)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    q = get_queue(args.device)
    meta = device_meta(q)
    rows = []
    dtypes = [np.float32] + ([np.float64] if has_fp64(q.device) else [])
    sizes = [(32, 512)] if args.quick else [(32, 512), (64, 1024)]
    for points, bins in sizes:
        s = ut_scene(points, bins, 4e5)
        smp = sample_scene(s)
        pairs = len(smp.elements) * points * points
        for dt in dtypes:
            lc = LightCone(points=points, width_m=s.width_m, bins=bins,
                           bin_width_s=s.bin_width_s, start_s=0.0, retro=False, dtype=dt,
                           queue=q)
            t = timeit(lambda lc=lc, smp=smp: lc(smp), q, repeat=3)
            rows.append({**meta, "kernel": "lightcone", "knob": "grid",
                         "value": f"{points}x{points}x{bins}", "dtype": np.dtype(dt).name,
                         "impl": "opencl", "elements": len(smp.elements), **t,
                         "pairs_per_s": pairs / t["median_s"]})
        t0 = time.perf_counter()
        numpy_lightcone(s, smp)
        tn = time.perf_counter() - t0
        rows.append({**meta, "kernel": "lightcone", "knob": "grid",
                     "value": f"{points}x{points}x{bins}", "dtype": "float64", "impl": "numpy",
                     "elements": len(smp.elements), "median_s": tn, "min_s": tn, "max_s": tn,
                     "pairs_per_s": pairs / tn})
    # error vs time across sampling densities (32x32x512), against a dense float64 reference
    ref_s = ut_scene(32, 512, 4e6)
    ref_lc = LightCone(points=32, width_m=0.6, bins=512, bin_width_s=ref_s.bin_width_s,
                       start_s=0.0, retro=False, dtype=dtypes[-1], queue=q)
    ref = ref_lc(sample_scene(ref_s)).get().astype(np.float64)
    for dens in (2.5e3, 1e4, 4e4, 1.6e5, 6.4e5):
        for dt in dtypes:
            s = ut_scene(32, 512, dens)
            lc = LightCone(points=32, width_m=0.6, bins=512, bin_width_s=s.bin_width_s,
                           start_s=0.0, retro=False, dtype=dt, queue=q)

            def run(s=s, lc=lc):
                return lc(sample_scene(s))

            t = timeit(run, q, repeat=3)
            out = run().get().astype(np.float64)
            rows.append({**meta, "kernel": "lightcone", "knob": "density_per_m2",
                         "value": dens, "dtype": np.dtype(dt).name, "impl": "opencl",
                         "elements": len(sample_scene(s).elements), **t,
                         "error": float(np.linalg.norm(out - ref) / np.linalg.norm(ref))})
    rows += blur_reach_rows(q, meta, args.quick)
    print(f"device: {meta['device']} ({meta['platform']}, PoCL {meta['pocl']})")
    print_table(rows, ["knob", "value", "impl", "dtype", "elements", "median_s",
                       "pairs_per_s", "error"])
    p, _ = write_rows(rows, args.out, "bench_forward")
    print(f"wrote {p}")


if __name__ == "__main__":
    main()
