"""The cold 128 x 128 x 512 photon-count reconstruction's peak memory, stage by stage (issue 49).

The bench's end-to-end capture (:func:`clnlos.bench.sections.end_to_end_scene`) made photon
counts (:data:`clnlos.bench.sections.END_TO_END_PHOTONS`, no slab recorded: GCV's slab SNR
and the light cone's UPRE with its noise probe), reconstructed cold by each method with the
default rules in a fresh process of its own, as the bench's ``reconstruct@cold,photons``
rows do but alone in that process: one r2c + c2r FFT pair of the padded grid timed first (its
buffers freed), then VmHWM reset and one cold run. Per method: FFT pairs, CPU seconds of the
process, peak resident memory (on PoCL it includes the device buffers), and the peak VmRSS
sampled during each stage the volume's timings name (``plan and set-up`` before the first,
``after X`` between X and the next).

    python tools/cold_memory.py [--grid 128 512] [--methods lct,fk] [--noise-free]
                                [--code DIR [--code-label TEXT]] [-o FILE]

``--code DIR`` runs the reconstructions with the package in DIR (an export of another
commit: a before/after comparison on the same capture); the capture is simulated once.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

SAMPLE_S = 0.005  # VmRSS sampling period


def _vm(field: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(f"{field}:"):
            return int(line.split()[1]) * 1024
    return 0


def worker(method: str, capture_path: str, max_path_m: float, bins: int) -> dict:
    """One cold reconstruction in this process (see the module docstring)."""
    import numpy as np
    import pyopencl.array as cla

    import clnlos.inverse.pipeline as pipeline
    from clnlos.bench.harness import timeit
    from clnlos.config import ReconstructionConfig
    from clnlos.io.capture import Capture
    from clnlos.physics.slab import CDT_SLAB
    from clnlos.runtime.caches import PIPELINES
    from clnlos.runtime.device import get_queue
    from clnlos.runtime.fft import RealFFT3

    z = np.load(capture_path)
    cap = Capture(z["transient"], float(z["bin_width_s"]), 0.0, float(z["scan_width_m"]))
    cfg = ReconstructionConfig(max_path_m=max_path_m, bins=bins, slab=CDT_SLAB,
                               method=method).validate()
    q = get_queue(None)
    _, ny, nx = cap.transient.shape
    fft = RealFFT3((2 * bins, 2 * ny, 2 * nx), np.float32, q)
    xg = cla.zeros(q, fft.shape, np.float32)
    pair = timeit(lambda: fft.inverse(fft.forward(xg)), q, repeat=5)["median_s"]
    del xg, fft

    label, peaks, running = ["plan and set-up"], {}, [True]
    timed = pipeline.ReconstructionPipeline._timed

    def labelled(self, timings, name, fn, *a, **kw):
        label[0] = name
        try:
            return timed(self, timings, name, fn, *a, **kw)
        finally:
            label[0] = f"after {name}"

    def sample():
        while running[0]:
            peaks[label[0]] = max(peaks.get(label[0], 0), _vm("VmRSS"))
            time.sleep(SAMPLE_S)

    pipeline.ReconstructionPipeline._timed = labelled
    PIPELINES.clear()
    Path("/proc/self/clear_refs").write_text("5")  # VmHWM <- VmRSS
    start = _vm("VmRSS")
    thread = threading.Thread(target=sample, daemon=True)
    thread.start()
    cpu0, t0 = time.process_time(), time.perf_counter()
    rec = pipeline.reconstruct(cap, cfg, device=q)
    wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    running[0] = False
    thread.join()
    p = rec.params
    return {"method": method, "fft_pair_s": pair, "wall_s": wall, "fft_pairs": wall / pair,
            "cpu_s": cpu, "peak_rss_bytes": _vm("VmHWM"), "start_rss_bytes": start,
            "stage_peak_rss_bytes": peaks, "stages_s": rec.timings_s,
            "snr_used": p.get("snr_used"), "snr_rule_used": p.get("snr_rule_used"),
            "inversion_snr_used": p.get("inversion_snr_used"),
            "inversion_snr_rule": p.get("inversion_snr_rule"),
            "volume_sum": float(np.sum(rec.volume, dtype=np.float64))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grid", type=int, nargs=2, default=(128, 512), metavar=("N", "NT"))
    ap.add_argument("--methods", default="lct,fk")
    ap.add_argument("--code", help="the package's folder for the reconstructions")
    ap.add_argument("--code-label", help="what --code holds (recorded: e.g. 'git archive "
                    "236ca5d')")
    ap.add_argument("--noise-free", action="store_true",
                    help="the expected transient itself, not photon counts")
    ap.add_argument("-o", "--output", help="JSON file of the rows (default: print them)")
    ap.add_argument("--worker", nargs=4, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.worker:
        m, path, max_path, bins = a.worker
        print(json.dumps(worker(m, path, float(max_path), int(bins))))
        return 0
    import numpy as np

    from clnlos.bench.sections import (
        END_TO_END_PHOTONS,
        end_to_end_config,
        end_to_end_scene,
        photon_capture,
    )
    from clnlos.forward.model import ForwardModel
    from clnlos.io.capture import Capture
    from clnlos.io.outputs import provenance

    n, nt = a.grid
    scene = end_to_end_scene(n, nt)
    tau = ForwardModel(scene).run()
    cap = (Capture(tau, scene.bin_width_s, 0.0, scene.width_m) if a.noise_free
           else photon_capture(tau, scene, END_TO_END_PHOTONS))
    env = dict(os.environ)
    if a.code:
        env["PYTHONPATH"] = os.pathsep.join([a.code] + [p for p in [env.get("PYTHONPATH")] if p])
    rows = []
    with tempfile.TemporaryDirectory() as d:
        path = str(Path(d) / "capture.npz")
        np.savez(path, transient=cap.transient, bin_width_s=cap.bin_width_s,
                 scan_width_m=cap.scan_width_m)
        for method in a.methods.split(","):
            cfg = end_to_end_config(nt, method)
            out = subprocess.run([sys.executable, __file__, "--worker", method, path,
                                  str(cfg.max_path_m), str(cfg.bins)], env=env, check=True,
                                 capture_output=True, text=True).stdout
            rows.append(json.loads(out.strip().splitlines()[-1]))
            print(json.dumps(rows[-1]), flush=True)
    if a.output:
        doc = {"provenance": {**provenance(), "command": "python tools/cold_memory.py "
                              + " ".join(argv if argv is not None else sys.argv[1:])},
               "grid": [n, n, nt], "photons": None if a.noise_free else END_TO_END_PHOTONS,
               "code": a.code_label or a.code or "this checkout", "rows": rows}
        tmp = Path(a.output).with_suffix(".tmp")
        tmp.write_text(json.dumps(doc, indent=1))
        tmp.replace(a.output)
    return 0


if __name__ == "__main__":
    sys.exit(main())
