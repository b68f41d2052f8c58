"""One reconstruction implementation at one grid, in a process of its own (the worker of the
``reconstruction_process`` section, :func:`clnlos.bench.sections.bench_reconstruction_process`).

Its own process, so that each row's peak resident memory (``peak_mem_bytes``: the process's
VmHWM, which for PoCL includes the device buffers) is that implementation's alone, and so that
the host-FFT variant runs with ``CLNLOS_FFT=host`` set before anything is planned. (Not
ru_maxrss: Linux carries the parent's resident size at the fork into the child's across
exec.) Prints its rows (:class:`clnlos.bench.harness.Bench` rows) as one JSON line:

    python -c "import sys; from clnlos.bench.isolated import main; main(sys.argv[1:])" \
        IMPL N [--device P:D] [--size tiny|quick|full]

(not ``python -m``: the package imports this module first). IMPL: ``opencl`` (FFT backend
auto), ``opencl-hostfft`` (the same, run by the parent with ``CLNLOS_FFT=host``), ``torch``
(CPU float32) or ``numpy`` (float64); N: the grid is 4N x N x N (2 m of round-trip path over
0.7 m of scan, the CDT slab).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import time
from pathlib import Path

import numpy as np
import pyopencl.array as cla

from clnlos.physics.constants import C0
from clnlos.bench.baselines import NumpyReconstruction, TorchReconstruction
from clnlos.bench.harness import Bench
from clnlos.forward.blur import slab_blur
from clnlos.inverse.fk import FKMigration
from clnlos.inverse.lct import LCT
from clnlos.physics.slab import CDT_SLAB
from clnlos.runtime.device import get_queue

IMPLS = ("opencl", "opencl-hostfft", "torch", "numpy")
STAGES = ("deconvolve", "lct", "fk", "end_to_end")


def grid_of(n: int) -> tuple[int, int, int]:
    return (4 * n, n, n)


def _status_bytes(field: str) -> int | None:
    """A size field of /proc/self/status (bytes), or None where /proc lacks it."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(f"{field}:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def peak_rss_bytes() -> int:
    """This process's peak resident set since its exec (VmHWM; ru_maxrss where /proc lacks it)."""
    hwm = _status_bytes("VmHWM")
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 if hwm is None else hwm


def reset_peak_rss() -> int:
    """Reset this process's peak resident set (VmHWM) to its current size (writing 5 to
    /proc/self/clear_refs, Linux >= 4.0) and return that size; where /proc refuses, the
    peak since the exec stands and the current size (VmRSS) is returned."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        pass
    rss = _status_bytes("VmRSS")
    return peak_rss_bytes() if rss is None else rss


def worker(impl: str, n: int, device: str | None, size: str) -> list[dict]:
    """Plan and time each stage (deconvolve, LCT, f-k, end to end: upload, deconvolve, LCT,
    download) of ``impl`` on a 4n x n x n grid; returns its rows (kernel
    ``reconstruction_process``, knob ``<stage>@grid``, extras plan_s and fft_backend)."""
    q = get_queue(device)
    b = Bench(q, size)
    shape = grid_of(n)
    geo = {"bin_width_s": 2.0 / (C0 * shape[0]), "scan_width_m": 0.7}
    x_np = np.random.default_rng(0).random(shape).astype(np.float32)
    t0 = time.perf_counter()
    extra = {}
    if impl.startswith("opencl"):
        dec = slab_blur(CDT_SLAB, shape, bin_width_s=geo["bin_width_s"],
                        pitch_m=geo["scan_width_m"] / shape[2], mode="wiener", snr=1e4, queue=q)
        lct = LCT(shape, **geo, snr=1e4, queue=q)
        fk = FKMigration(shape, **geo, queue=q)
        x_g = cla.to_device(q, x_np)
        q.finish()
        extra["fft_backend"] = dec.fft.backend
        stages = {"deconvolve": lambda: dec(x_g), "lct": lambda: lct(x_g),
                  "fk": lambda: fk(x_g),
                  "end_to_end": lambda: lct(dec(cla.to_device(q, x_np))).get()}
        dtype, sync = np.float32, True
    else:
        cls_ = TorchReconstruction if impl == "torch" else NumpyReconstruction
        p = cls_(shape, **geo, slab=CDT_SLAB, snr=1e4, lct_snr=1e4, queue=q)
        if impl == "torch":
            import torch  # optional: the parent runs this worker only where torch is installed

            torch.set_num_threads(os.cpu_count() or 1)
            x, dtype = torch.from_numpy(x_np), np.float32
        else:
            x, dtype = x_np.astype(np.float64), np.float64
        stages = {"deconvolve": lambda: p.deconvolve(x), "lct": lambda: p.lct(x),
                  "fk": lambda: p.fk(x), "end_to_end": lambda: p.lct(p.deconvolve(x))}
        sync = False
    extra["plan_s"] = time.perf_counter() - t0
    grid = f"{shape[2]}x{shape[1]}x{shape[0]}"
    for stage, fn in stages.items():
        r = b.add("reconstruction_process", f"{stage}@grid", grid, dtype, fn, None, impl=impl,
                  sync=sync, **extra)
        r["peak_mem_bytes"] = peak_rss_bytes()
    return b.rows


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("impl", choices=IMPLS)
    ap.add_argument("n", type=int)
    ap.add_argument("--device", default=None)
    ap.add_argument("--size", default="full", choices=("tiny", "quick", "full"))
    args = ap.parse_args(argv)
    print(json.dumps(worker(args.impl, args.n, args.device, args.size), default=str))


if __name__ == "__main__":
    main()
