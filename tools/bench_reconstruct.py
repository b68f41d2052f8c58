#!/usr/bin/env python3
"""Reconstruction speed and memory: OpenCL (clnlos) vs numpy/scipy float64 vs torch CPU.

Times each stage (slab Wiener deconvolution, LCT, f-k) and end to end (upload, deconvolve,
LCT, download) at 32x32x128, 64x64x256 and 128x128x512 (float32 for OpenCL and torch),
median of repeats after a warm-up; each (implementation, size) runs in its own process so
its peak resident memory (ru_maxrss, which for PoCL includes the device buffers) is its own.

    python tools/bench_reconstruct.py [--device SPEC] [-o DIR] [--sizes 32,64] [--impl ...]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import device_meta, print_table, timeit, write_rows  # noqa: E402

from clnlos import C0  # noqa: E402
from clnlos.config import slab_table  # noqa: E402
from clnlos.physics.slab import CDT_SLAB  # noqa: E402

SIZES = {32: (128, 32, 32), 64: (256, 64, 64), 128: (512, 128, 128)}
SLAB = slab_table(CDT_SLAB)


def _geometry(shape):
    nt = shape[0]
    return dict(bin_width_s=2.0 / (C0 * nt), scan_width_m=0.7)  # 2 m of round-trip path


def worker(impl: str, size: int, device: str | None, repeat: int) -> dict:
    from clnlos.diffusion import Slab

    shape = SIZES[size]
    geo = _geometry(shape)
    rng = np.random.default_rng(0)
    x_np = rng.random(shape).astype(np.float32)
    slab = Slab(**SLAB)
    row = {"impl": impl, "size": f"{shape[2]}x{shape[1]}x{shape[0]}"}
    t0 = time.perf_counter()
    if impl.startswith("opencl"):
        import pyopencl.array as cla

        from clnlos.forward.blur import slab_blur
        from clnlos.inverse.fk import FKMigration
        from clnlos.inverse.lct import LCT
        from clnlos.runtime.device import get_queue

        q = get_queue(device)
        row.update(device_meta(q))
        dec = slab_blur(slab, shape, **{k: geo[k] for k in ("bin_width_s",)},
                        pitch_m=geo["scan_width_m"] / shape[2], mode="wiener", snr=1e4,
                        queue=q)
        lct = LCT(shape, **geo, snr=1e4, queue=q)
        fk = FKMigration(shape, **geo, queue=q)
        x_g = cla.to_device(q, x_np)
        q.finish()
        row["plan_s"] = time.perf_counter() - t0
        row["fft_backend"] = dec.fft.backend
        stages = {"deconvolve": lambda: dec(x_g), "lct": lambda: lct(x_g),
                  "fk": lambda: fk(x_g),
                  "end_to_end": lambda: lct(dec(cla.to_device(q, x_np))).get()}
    else:
        from clnlos.bench.baselines import NumpyReconstruction, TorchReconstruction
        from clnlos.runtime.device import get_queue

        q = get_queue(device)
        if impl == "torch":
            import torch

            torch.set_num_threads(os.cpu_count() or 1)
            p = TorchReconstruction(shape, **geo, slab=slab, snr=1e4, lct_snr=1e4, queue=q)
            x = torch.from_numpy(x_np)
        else:
            p = NumpyReconstruction(shape, **geo, slab=slab, snr=1e4, lct_snr=1e4, queue=q)
            x = x_np.astype(np.float64)
        row["plan_s"] = time.perf_counter() - t0
        q = None
        stages = {"deconvolve": lambda: p.deconvolve(x), "lct": lambda: p.lct(x),
                  "fk": lambda: p.fk(x), "end_to_end": lambda: p.lct(p.deconvolve(x))}
    for name, fn in stages.items():
        r = timeit(fn, q, warmup=1, repeat=repeat)
        row[f"{name}_s"] = r["median_s"]
        row[f"{name}_min_s"] = r["min_s"]
    row["peak_rss_gib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None)
    ap.add_argument("-o", "--out", default="out/bench", type=Path)
    ap.add_argument("--sizes", default="32,64,128")
    ap.add_argument("--impl", default="opencl,opencl-hostfft,torch,numpy",
                    help="opencl (FFT backend auto: pyvkfft), opencl-hostfft (CLNLOS_FFT=host), "
                         "torch, numpy")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--worker", nargs=2, metavar=("IMPL", "SIZE"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        print(json.dumps(worker(args.worker[0], int(args.worker[1]), args.device, args.repeat)))
        return None
    rows = []
    for size in (int(s) for s in args.sizes.split(",")):
        for impl in args.impl.split(","):
            cmd = [sys.executable, __file__, "--worker", impl, str(size), "--repeat",
                   str(args.repeat)] + (["--device", args.device] if args.device else [])
            env = dict(os.environ)
            if impl == "opencl-hostfft":
                env["CLNLOS_FFT"] = "host"
            r = subprocess.run(cmd, capture_output=True, text=True, env=env)
            if r.returncode != 0:
                print(f"{impl} {size}: failed\n{r.stderr[-2000:]}", file=sys.stderr)
                continue
            rows.append(json.loads(r.stdout.strip().splitlines()[-1]))
            print(f"  done {impl} {rows[-1]['size']}: end to end {rows[-1]['end_to_end_s']:.3f} s",
                  flush=True)
    by = {(r["size"], r["impl"]): r for r in rows}
    for r in rows:
        t = by.get((r["size"], "torch"))
        if t and "end_to_end_s" in r:
            r["speedup_vs_torch"] = t["end_to_end_s"] / r["end_to_end_s"]
    meta = next((r for r in rows if r["impl"] == "opencl"), {})
    print(f"device: {meta.get('device')} ({meta.get('platform')}, PoCL {meta.get('pocl')}), "
          f"FFT {meta.get('fft_backend')}")
    print_table(rows, ["size", "impl", "fft_backend", "plan_s", "deconvolve_s", "lct_s", "fk_s",
                       "end_to_end_s", "peak_rss_gib", "speedup_vs_torch"])
    csv_path, _ = write_rows(rows, args.out, "bench_reconstruct")
    print(f"wrote {csv_path}")
    return rows


if __name__ == "__main__":
    main()
