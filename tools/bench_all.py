#!/usr/bin/env python3
"""What accuracy costs in time: every accuracy knob of every kernel, one report.

Each knob's error is measured against a float64 high-accuracy reference computed in the same
run on the same device; times are medians over repeats after a warm-up (queue.finish() around
each run). Baselines (vectorised numpy float64, torch CPU for the reconstruction) run beside
them and are reported as ratios. A trivial copy kernel gives the device's memory bandwidth,
and the bandwidth-bound stages are reported as a fraction of it.

Writes DIR/bench.json (one row per measurement) and DIR/bench.html (Pareto plots of error
against time per kernel, and a table of recommended settings).

    python tools/bench_all.py [--quick | --tiny] [-o DIR] [--device SPEC]
"""

from __future__ import annotations

import argparse
import base64
import html
import io
import json
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import device_meta, print_table, timeit  # noqa: E402

import pyopencl as cl  # noqa: E402
import pyopencl.array as cla  # noqa: E402

from clnlos import C0  # noqa: E402
from clnlos.runtime import get_queue, has_fp64  # noqa: E402

ROW_KEYS = ("device", "driver", "pocl", "kernel", "knob", "value", "dtype", "impl", "median_s",
            "min_s", "max_s", "error", "peak_mem_bytes")


def _rel(a, b) -> float:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-300))


class Bench:
    def __init__(self, queue, size: str):
        self.q, self.size = queue, size
        self.meta = device_meta(queue)
        self.rows: list[dict] = []
        self.repeat = {"tiny": 1, "quick": 3, "full": 5}[size]
        self.f64 = has_fp64(queue.device)

    def add(self, kernel, knob, value, dtype, fn, error, impl="opencl", sync=True, **extra):
        t = timeit(fn, self.q if sync else None, repeat=self.repeat)
        row = {"device": self.meta["device"], "driver": self.meta["driver"],
               "pocl": self.meta["pocl"], "kernel": kernel, "knob": knob, "value": value,
               "dtype": np.dtype(dtype).name, "impl": impl, **t,
               "error": None if error is None else float(error),
               "peak_mem_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
               **extra}
        self.rows.append(row)
        return row

    @property
    def dtypes(self):
        return [np.float32] + ([np.float64] if self.f64 else [])


# ------------------------------------------------------------------ kernels
def bench_diffusion(b: Bench):
    from bench_diffusion import numpy_transmittance

    from clnlos.diffusion import Slab, SlabTransmittance, grid_offsets

    slab = Slab(thickness_m=0.0254, mu_a=0.53, mu_s_prime=262.0, n=1.12)
    n, nt = {"tiny": (8, 64), "quick": (32, 256), "full": (64, 512)}[b.size]
    off = grid_offsets(n, 0.01)
    rho = np.sqrt(off[:, None] ** 2 + off[None, :] ** 2).ravel()
    t = np.arange(nt) * 16e-12
    ref_dt = b.dtypes[-1]
    ref = SlabTransmittance(slab, dtype=ref_dt, queue=b.q).outer_device(
        cla.to_device(b.q, rho.astype(ref_dt)), cla.to_device(b.q, t.astype(ref_dt))).get()
    for dt in b.dtypes:
        rg, tg = cla.to_device(b.q, rho.astype(dt)), cla.to_device(b.q, t.astype(dt))
        for M in (1, 2, 3, 5, 10, 20, None):
            p = SlabTransmittance(slab, n_dipoles=M, dtype=dt, queue=b.q)
            err = _rel(p.outer_device(rg, tg).get(), ref)
            b.add("diffusion", "n_dipoles", "auto" if M is None else M, dt,
                  lambda p=p, rg=rg, tg=tg: p.outer_device(rg, tg), err)
    R, T = rho[None, :], t[:, None]
    b.add("diffusion", "n_dipoles", 20, np.float64, lambda: numpy_transmittance(slab, R, T, 20),
          _rel(numpy_transmittance(slab, R, T, 20), ref), impl="numpy", sync=False)


def _ut_scene(points, bins, density, material="lambertian"):
    from clnlos.scene import Scene

    return Scene.from_dict({
        "scan": {"width_m": 0.6, "points": points},
        "time": {"bin_width_s": 4.0 / (C0 * bins), "bins": bins, "start_s": 0.0},
        "objects": [{"shape": "letters", "text": "UT", "height_m": 0.3, "stroke_m": 0.06,
                     "translate_m": [0.0, 0.0, 0.5], "material": material}],
        "sampling": {"density_per_m2": density}})


def bench_lightcone(b: Bench):
    from bench_forward import numpy_lightcone

    from clnlos.forward import LightCone, sample_scene

    pts, bins = {"tiny": (8, 128), "quick": (32, 512), "full": (32, 512)}[b.size]
    dens = {"tiny": (2.5e3, 1e4, 4e4), "quick": (2.5e3, 1e4, 4e4, 1.6e5),
            "full": (2.5e3, 1e4, 4e4, 1.6e5, 6.4e5)}[b.size]
    ref_s = _ut_scene(pts, bins, 16 * dens[-1])
    ref = LightCone(points=pts, width_m=0.6, bins=bins, bin_width_s=ref_s.bin_width_s,
                    start_s=0.0, retro=False, dtype=b.dtypes[-1], queue=b.q)(
        sample_scene(ref_s)).get()
    for dt in b.dtypes:
        for splat in (0, 1):
            for d in dens:
                s = _ut_scene(pts, bins, d)
                smp = sample_scene(s)
                lc = LightCone(points=pts, width_m=0.6, bins=bins, bin_width_s=s.bin_width_s,
                               start_s=0.0, retro=False, splat_order=splat, dtype=dt,
                               queue=b.q)
                err = _rel(lc(smp).get(), ref)
                knob = "density_per_m2" if splat == 1 else "density_per_m2@splat0"
                b.add("lightcone", knob, d, dt, lambda lc=lc, smp=smp: lc(smp), err,
                      elements=len(smp.elements))
    s = _ut_scene(pts, bins, dens[-1])
    smp = sample_scene(s)
    b.add("lightcone", "density_per_m2", dens[-1], np.float64, lambda: numpy_lightcone(s, smp),
          _rel(numpy_lightcone(s, smp), ref), impl="numpy", sync=False)


def bench_brdf(b: Bench):
    from clnlos.brdf.models import BRDFModel
    from clnlos.brdf.texture import TextureLookup, tabulate

    model = BRDFModel("microfacet", {"kd": 0.1, "ks": 1.0, "alpha": 0.2, "f0": 0.9})
    rng = np.random.default_rng(0)
    n = {"tiny": 20_000, "quick": 200_000, "full": 1_000_000}[b.size]
    a = np.column_stack([rng.uniform(0, 1.45, n), rng.uniform(-np.pi, np.pi, n),
                         rng.uniform(0, 1.45, n), rng.uniform(-np.pi, np.pi, n)])
    truth = model(*a.T)
    for res in (8, 16, 32, 64) if b.size == "tiny" else (8, 16, 32, 64, 128):
        tex = tabulate(model, res, res, 16)
        for path in ("buffer", "image"):
            if path == "image" and not b.q.device.image_support:
                continue
            lk = TextureLookup(tex, path=path, queue=b.q)
            b.add("brdf", f"resolution@{path}", res, np.float32, lambda lk=lk: lk(a),
                  _rel(lk(a), truth))
    b.add("brdf", "model-eval", "analytic", np.float64, lambda: model(*a.T), 0.0,
          impl="numpy", sync=False)


def bench_model_level(b: Bench):
    """Forward model level: Lambertian confocal vs BRDF (glossy) confocal, same scene."""
    from clnlos.forward import ForwardModel

    pts, bins = {"tiny": (8, 128), "quick": (32, 512), "full": (32, 512)}[b.size]
    ref = ForwardModel(_ut_scene(pts, bins, 4e4, "painted steel plate"), queue=b.q,
                       dtype=b.dtypes[-1]).run()
    for level, mat in (("lambertian-confocal", "lambertian"),
                       ("brdf-confocal", "painted steel plate")):
        fm = ForwardModel(_ut_scene(pts, bins, 4e4, mat), queue=b.q)
        out = fm.run()
        err = _rel(out / max(out.sum(), 1e-300), ref / max(ref.sum(), 1e-300))
        b.add("forward", "model_level", level, np.float32, fm.run, err)


def bench_reconstruction(b: Bench):
    from clnlos.blur import slab_blur
    from clnlos.diffusion import Slab
    from clnlos.fk import FKMigration
    from clnlos.lct import LCT

    sizes = {"tiny": [16], "quick": [32, 64], "full": [32, 64, 128]}[b.size]
    slab = Slab(thickness_m=0.0254, mu_a=0.53, mu_s_prime=262.0, n=1.12)
    for n in sizes:
        shape = (4 * n, n, n)
        dt_s = 2.0 / (C0 * shape[0])
        x = np.random.default_rng(0).random(shape)
        refs = {}
        for dt in reversed(b.dtypes):
            ops = {"wiener": slab_blur(slab, shape, bin_width_s=dt_s, pitch_m=0.7 / n,
                                       mode="wiener", snr=1e4, dtype=dt, queue=b.q),
                   "lct": LCT(shape, bin_width_s=dt_s, scan_width_m=0.7, snr=1e4, dtype=dt,
                              queue=b.q),
                   "fk": FKMigration(shape, bin_width_s=dt_s, scan_width_m=0.7, dtype=dt,
                                     queue=b.q)}
            xg = cla.to_device(b.q, x.astype(dt))
            for name, op in ops.items():
                out = op(xg).get()
                if dt == b.dtypes[-1]:
                    refs[name] = out
                b.add("reconstruction", f"{name}@grid", f"{shape[2]}x{shape[1]}x{shape[0]}",
                      dt, lambda op=op, xg=xg: op(xg), _rel(out, refs[name]),
                      fft_backend=ops["wiener"].fft.backend)
            if dt == np.float32:
                _bandwidth_rows(b, ops, xg, f"{shape[2]}x{shape[1]}x{shape[0]}")
        if b.size != "tiny":
            from recon_baselines import NumpyReconstruction, TorchReconstruction

            for impl, cls_ in (("numpy", NumpyReconstruction), ("torch", TorchReconstruction)):
                p = cls_(shape, bin_width_s=dt_s, scan_width_m=0.7, slab=slab, snr=1e4,
                         lct_snr=1e4, queue=b.q)
                xi = x if impl == "numpy" else __import__("torch").from_numpy(
                    x.astype(np.float32))
                for name, fn in (("wiener", p.deconvolve), ("lct", p.lct), ("fk", p.fk)):
                    out = np.asarray(fn(xi))
                    b.add("reconstruction", f"{name}@grid", f"{shape[2]}x{shape[1]}x{shape[0]}",
                          np.float64 if impl == "numpy" else np.float32,
                          lambda fn=fn, xi=xi: fn(xi), _rel(out, refs[name]), impl=impl,
                          sync=False)


def _bandwidth_rows(b: Bench, ops, xg, grid: str) -> None:
    """The bandwidth-bound pieces alone, with the bytes each must move at least."""
    from clnlos.runtime import round_up

    w = ops["wiener"]
    spec = w.fft.forward(w._buf)
    n = spec.size
    k = w._k.wiener_apply
    r = b.add("roofline", "wiener_multiply", grid, np.float32,
              lambda: k(b.q, (round_up(n, 256),), None, w.H.data, spec.data, np.float32(1e-4),
                        np.int32(0), np.int64(n)), None)
    r["bytes_moved"] = 3 * n * spec.dtype.itemsize  # read H and X, write X
    r = b.add("roofline", "fft_r2c_pass", grid, np.float32, lambda: w.fft.forward(w._buf, spec),
              None, fft_backend=w.fft.backend)
    r["bytes_moved"] = w._buf.nbytes + spec.nbytes  # one read + one write: a single pass
    lct = ops["lct"]
    r = b.add("roofline", "resample_t_to_v", grid, np.float32, lambda: lct.to_v(xg), None)
    r["bytes_moved"] = 2 * xg.nbytes + lct.to_v.matrix.nnz * 8  # columns read, rows written


def bench_end_to_end(b: Bench):
    from clnlos.config import ReconstructionConfig
    from clnlos.diffusion import Slab
    from clnlos.forward import ForwardModel
    from clnlos.io import Capture
    from clnlos.metrics import peak_depth_m
    from clnlos.reconstruct import reconstruct
    from clnlos.scene import Scene

    grids = {"tiny": [(16, 64)], "quick": [(32, 128), (64, 256)],
             "full": [(32, 128), (64, 256), (128, 512)]}[b.size]
    for n, nt in grids:
        d = {"scan": {"width_m": 0.6, "points": n},
             "time": {"bin_width_s": 2.46 / (C0 * nt), "bins": nt, "start_s": 0.0},
             "objects": [{"shape": "letters", "text": "UT", "height_m": 0.3, "stroke_m": 0.06,
                          "translate_m": [0.0, 0.0, 0.5]}],
             "slab": {"thickness_m": 0.0254, "mu_a": 0.53, "mu_s_prime": 262.0, "n": 1.12},
             "sampling": {"density_per_m2": 4e4}}
        scene = Scene.from_dict(d)
        fm = ForwardModel(scene, queue=b.q)
        cfg = ReconstructionConfig(max_path_m=2.0, bins=nt, slab=Slab(**d["slab"]),
                                   snr=1e6, inversion_snr=1e3).validate()

        def run(fm=fm, cfg=cfg, scene=scene):
            tau = fm.run()
            return reconstruct(Capture(tau, scene.bin_width_s, 0.0, scene.width_m), cfg,
                               device=b.q).volume

        vol = run()
        depth = peak_depth_m(vol, 2.0 / nt / 2)
        b.add("end_to_end", "grid", f"{n}x{n}x{nt}", np.float32, run, abs(depth - 0.5) / 0.5,
              error_kind="relative depth error")


def bench_roofline(b: Bench) -> float:
    """Copy bandwidth (GB/s) of a trivial kernel; bandwidth-bound stages as a fraction of it."""
    n = {"tiny": 1 << 22, "quick": 1 << 25, "full": 1 << 26}[b.size]
    prg = cl.Program(b.q.context, """
        __kernel void copy4(__global const float4 *a, __global float4 *b) {
            b[get_global_id(0)] = a[get_global_id(0)]; }""").build()
    k = prg.copy4
    a = cla.zeros(b.q, n, np.float32)
    c = cla.empty_like(a)
    r = b.add("roofline", "copy", f"{n * 4 / 2**20:.0f} MiB", np.float32,
              lambda: k(b.q, (n // 4,), None, a.data, c.data), None)
    bw = 2 * n * 4 / r["median_s"]
    r["bandwidth_gbs"] = bw / 1e9
    for row in b.rows:
        if row.get("bytes_moved"):
            row["bandwidth_fraction"] = row["bytes_moved"] / row["median_s"] / bw
            gbs = row["bytes_moved"] / row["median_s"] / 1e9
            print(f"  {row['knob']} {row['value']}: {gbs:.2f} GB/s = "
                  f"{row['bandwidth_fraction']:.2f} of copy bandwidth")
    return bw


# ------------------------------------------------------------------ report
def recommendations(rows) -> list[dict]:
    """For each kernel knob and target error, the cheapest OpenCL setting reaching it."""
    out = []
    groups = {}
    for r in rows:
        if r["impl"] == "opencl" and r["error"] is not None and r["kernel"] != "roofline":
            # a grid size is a different problem, not a knob: there, only the dtype is chosen
            per_value = r["kernel"] in ("reconstruction", "end_to_end")
            key = (r["kernel"], f"{r['knob']}={r['value']}" if per_value else r["knob"])
            groups.setdefault(key, []).append(r)
    for (kern, knob), rs in groups.items():
        for target in (0.1, 0.01, 1e-4):
            ok = [r for r in rs if r["error"] <= target]
            if ok:
                best = min(ok, key=lambda r: r["median_s"])
                out.append({"kernel": kern, "knob": knob, "target_error": target,
                            "value": best["value"], "dtype": best["dtype"],
                            "seconds": best["median_s"], "error": best["error"]})
    return out


def _png(fig) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=85, bbox_inches="tight")
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def write_html(path: Path, rows, recs, meta, bw):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    parts = [f"<h1>clnlos: what accuracy costs in time</h1><p>Device {html.escape(meta['device'])}"
             f" ({html.escape(meta['platform'])}, driver {html.escape(meta['driver'])}, PoCL "
             f"{meta['pocl']}); copy bandwidth {bw / 1e9:.1f} GB/s.</p>"]
    kernels = sorted({r["kernel"] for r in rows if r["error"] is not None})
    roof = [r for r in rows if r.get("bandwidth_fraction") is not None]
    if roof:
        parts.append("<h2>Memory-bandwidth roofline</h2><table border=1 cellpadding=3><tr><th>"
                     "stage</th><th>grid</th><th>s</th><th>GB/s</th><th>fraction of copy</th>"
                     "</tr>" + "".join(
                         f"<tr><td>{r['knob']}</td><td>{r['value']}</td><td>{r['median_s']:.3g}"
                         f"</td><td>{r['bytes_moved'] / r['median_s'] / 1e9:.2f}</td><td>"
                         f"{r['bandwidth_fraction']:.2f}</td></tr>" for r in roof) + "</table>")
    for kern in kernels:
        fig, ax = plt.subplots(figsize=(6, 4))
        knobs = sorted({(r["knob"], r["dtype"], r["impl"]) for r in rows
                        if r["kernel"] == kern and r["error"] is not None})
        for knob, dt, impl in knobs:
            rs = [r for r in rows if (r["kernel"], r["knob"], r["dtype"], r["impl"]) ==
                  (kern, knob, dt, impl) and r["error"] is not None]
            ax.loglog([r["median_s"] for r in rs], [max(r["error"], 1e-17) for r in rs], "o-",
                      label=f"{knob} {dt} {impl}")
        ax.set(xlabel="time (s)", ylabel="relative error vs float64 reference", title=kern)
        ax.legend(fontsize=6)
        parts.append(f"<h2>{kern}</h2><img src='data:image/png;base64,{_png(fig)}'/>")
    parts.append("<h2>Recommended settings</h2><table border=1 cellpadding=3><tr><th>kernel"
                 "</th><th>knob</th><th>for error</th><th>use</th><th>dtype</th><th>costs (s)"
                 "</th><th>error reached</th></tr>" + "".join(
                     f"<tr><td>{r['kernel']}</td><td>{r['knob']}</td><td>{r['target_error']:g}"
                     f"</td><td>{r['value']}</td><td>{r['dtype']}</td><td>{r['seconds']:.3g}"
                     f"</td><td>{r['error']:.2g}</td></tr>" for r in recs) + "</table>")
    parts.append("<h2>All rows</h2><pre>" + html.escape(json.dumps(rows, indent=0)) + "</pre>")
    path.write_text("<!doctype html><html><head><meta charset='utf-8'><title>clnlos bench"
                    "</title></head><body style='font-family:sans-serif'>" + "\n".join(parts)
                    + "</body></html>", encoding="utf-8")


SECTIONS = {"diffusion": bench_diffusion, "lightcone": bench_lightcone, "brdf": bench_brdf,
            "forward": bench_model_level, "reconstruction": bench_reconstruction,
            "end_to_end": bench_end_to_end}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None)
    ap.add_argument("-o", "--out", default="out/bench", type=Path)
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--quick", action="store_true", help="under 5 minutes on 2 CPU cores")
    g.add_argument("--tiny", action="store_true", help="seconds; for tests")
    ap.add_argument("--only", default=",".join(SECTIONS), help="comma-separated sections")
    args = ap.parse_args(argv)
    b = Bench(get_queue(args.device), "tiny" if args.tiny else "quick" if args.quick else "full")
    t0 = time.perf_counter()
    for name in args.only.split(","):
        if name not in SECTIONS:
            raise SystemExit(f"unknown section {name!r}: choose from {', '.join(SECTIONS)}")
        print(f"== {name}", flush=True)
        SECTIONS[name](b)
    bw = bench_roofline(b)
    for r in b.rows:  # ratios against the baselines of the same kernel/knob/value
        base = [x for x in b.rows if x["impl"] in ("numpy", "torch") and
                (x["kernel"], x["knob"], x["value"]) == (r["kernel"], r["knob"], r["value"])]
        for x in base:
            r[f"speedup_vs_{x['impl']}"] = x["median_s"] / r["median_s"]
    recs = recommendations(b.rows)
    args.out.mkdir(parents=True, exist_ok=True)
    doc = {"meta": b.meta, "size": b.size, "seconds": time.perf_counter() - t0,
           "copy_bandwidth_gbs": bw / 1e9, "rows": b.rows, "recommendations": recs}
    (args.out / "bench.json").write_text(json.dumps(doc, indent=1, default=str))
    write_html(args.out / "bench.html", b.rows, recs, b.meta, bw)
    print_table(b.rows, ["kernel", "knob", "value", "dtype", "impl", "median_s", "error"])
    print(f"wrote {args.out / 'bench.json'} and bench.html in {doc['seconds']:.1f} s")
    return doc


if __name__ == "__main__":
    main()
