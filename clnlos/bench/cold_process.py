"""One cold reconstruction in a process of its own: the worker of the end-to-end section's
photon-count rows (:func:`clnlos.bench.sections.bench_end_to_end`) and of
``tools/cold_memory.py``.

Its own process, so that the peak resident memory (VmHWM, which on PoCL includes the device
buffers) is the reconstruction's with the interpreter and the capture, not the bench's
(whose earlier rows leave simulations and allocator arenas behind: 0.8 GB at 128 x 128 x
512). One r2c + c2r FFT pair of the padded grid is timed first (its buffers freed), then
VmHWM is reset and one cold reconstruction runs (plans built; the default rules of
``method`` with the CDT slab given: :func:`clnlos.bench.sections.end_to_end_config`'s);
VmRSS is sampled during each stage the volume's timings name (``plan and set-up`` before the first, ``after X`` between X and the next). Prints one
JSON line:

    python -c "import sys; from clnlos.bench.cold_process import main; main(sys.argv[1:])" \\
        METHOD CAPTURE.npz MAX_PATH_M BINS [--device P:D]

(CAPTURE.npz: ``transient``, ``bin_width_s``, ``scan_width_m``; t = 0 at bin 0.)
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import pyopencl.array as cla

from clnlos.bench.harness import timeit
from clnlos.config import ReconstructionConfig
from clnlos.inverse.pipeline import ReconstructionPipeline, reconstruct
from clnlos.io.capture import Capture
from clnlos.physics.slab import CDT_SLAB
from clnlos.runtime.caches import PIPELINES
from clnlos.runtime.device import get_queue
from clnlos.runtime.fft import RealFFT3
from clnlos.study.score.metrics import peak_depth_m

SAMPLE_S = 0.005  # VmRSS sampling period (s)
WORKER = "import sys; from clnlos.bench.cold_process import main; main(sys.argv[1:])"


def _status_bytes(field: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(f"{field}:"):
            return int(line.split()[1]) * 1024
    return 0


def cold_run(method: str, capture_path: str, max_path_m: float, bins: int,
             device: str | None = None) -> dict:
    """The row of one cold reconstruction in this process (module docstring): the FFT pair
    (s), wall and CPU seconds of the run, FFT pairs, peak and start RSS (bytes), the peak
    VmRSS per stage, the stage times and the SNRs chosen."""
    z = np.load(capture_path)
    cap = Capture(z["transient"], float(z["bin_width_s"]), 0.0, float(z["scan_width_m"]))
    cfg = ReconstructionConfig(max_path_m=max_path_m, bins=bins, slab=CDT_SLAB,
                               method=method).validate()
    q = get_queue(device)
    _, ny, nx = cap.transient.shape
    fft = RealFFT3((2 * bins, 2 * ny, 2 * nx), np.float32, q)
    xg = cla.zeros(q, fft.shape, np.float32)
    pair = timeit(lambda: fft.inverse(fft.forward(xg)), q, repeat=5)["median_s"]
    del xg, fft

    label, peaks, running = ["plan and set-up"], {}, [True]

    def stage(name: str, started: bool) -> None:
        label[0] = name if started else f"after {name}"

    def sample():
        while running[0]:
            peaks[label[0]] = max(peaks.get(label[0], 0), _status_bytes("VmRSS"))
            time.sleep(SAMPLE_S)

    ReconstructionPipeline.stage_hook = stage  # (a version without the hook: no labels)
    PIPELINES.clear()
    Path("/proc/self/clear_refs").write_text("5")  # VmHWM <- VmRSS
    start = _status_bytes("VmRSS")
    thread = threading.Thread(target=sample, daemon=True)
    thread.start()
    cpu0, t0 = time.process_time(), time.perf_counter()
    try:
        rec = reconstruct(cap, cfg, device=q)
        wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    finally:
        running[0] = False
        thread.join()
        ReconstructionPipeline.stage_hook = None
    p = rec.params
    return {"method": method, "fft_pair_s": pair, "wall_s": wall, "fft_pairs": wall / pair,
            "cpu_s": cpu, "peak_rss_bytes": _status_bytes("VmHWM"), "start_rss_bytes": start,
            "stage_peak_rss_bytes": peaks, "stages_s": rec.timings_s,
            "snr_used": p.get("snr_used"), "snr_rule_used": p.get("snr_rule_used"),
            "inversion_snr_used": p.get("inversion_snr_used"),
            "inversion_snr_rule": p.get("inversion_snr_rule"),
            "volume": rec.volume}


def cold_rows(cap, methods, max_path_m: float, bins: int, *, device: str | None = None,
              code: str | None = None, env: dict | None = None) -> list[dict]:
    """:func:`cold_run` of the capture ``cap`` for each method, each in a fresh process;
    ``code``: a folder holding another version of the package, run in its place (this
    module's file then runs as the worker: it needs nothing of this version; ``env``, the
    workers' environment, then puts it first on PYTHONPATH). Rows with
    ``volume_sum`` (float64) and ``peak_depth_m`` (the brightest depth slice's, m) in place
    of the volume."""
    head = [sys.executable, __file__] if code else [sys.executable, "-c", WORKER]
    rows = []
    with tempfile.TemporaryDirectory() as d:
        path = str(Path(d) / "capture.npz")
        np.savez(path, transient=cap.transient, bin_width_s=cap.bin_width_s,
                 scan_width_m=cap.scan_width_m)
        for method in methods:
            cmd = head + [method, path, str(max_path_m), str(bins)]
            cmd += [] if device is None else ["--device", device]
            r = subprocess.run(cmd, env=env, capture_output=True, text=True)
            if r.returncode != 0:
                raise RuntimeError(f"cold reconstruction ({method}) failed:\n{r.stderr[-2000:]}")
            rows.append(json.loads(r.stdout.strip().splitlines()[-1]))
    return rows


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description="one cold reconstruction in this process")
    ap.add_argument("method")
    ap.add_argument("capture")
    ap.add_argument("max_path_m", type=float)
    ap.add_argument("bins", type=int)
    ap.add_argument("--device")
    a = ap.parse_args(argv)
    row = cold_run(a.method, a.capture, a.max_path_m, a.bins, a.device)
    vol = row.pop("volume")
    row["volume_sum"] = float(np.sum(vol, dtype=np.float64))
    row["peak_depth_m"] = peak_depth_m(vol, a.max_path_m / a.bins / 2)
    print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
