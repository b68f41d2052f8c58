"""Benchmark sections: every accuracy knob of every stage against its cost."""

from __future__ import annotations

import importlib.resources
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from clnlos.physics.constants import C0
from clnlos.bench.baselines import (
    NumpyReconstruction,
    TorchReconstruction,
    numpy_lightcone,
    numpy_transmittance,
    ut_scene,
)
from clnlos.bench.cold_process import cold_rows
from clnlos.bench.harness import Bench, timed_once, timeit
from clnlos.bench.harness import rel_error as _rel
from clnlos.bench.isolated import IMPLS as PROCESS_IMPLS
from clnlos.bench.isolated import peak_rss_bytes, reset_peak_rss
from clnlos.bench.oracle import (
    BENCH_CASE,
    ORACLE_CASES,
    case_named,
    compare_method,
    simulate_case,
)
from clnlos.bench.oracle import METHODS as ORACLE_METHODS
from clnlos.brdf.data import BRDFSamples, agreement, read_gonio_csv, relative_error
from clnlos.brdf.fit import fit_analytic
from clnlos.brdf.mlp import MLPConfig, train_mlp
from clnlos.brdf.models import BRDFModel
from clnlos.brdf.texture import tabulate
from clnlos.brdf.texture_lookup import TextureLookup
from clnlos.config import ReconstructionConfig, slab_table
from clnlos.diffusion import SlabTransmittance
from clnlos.forward.bistatic import BistaticTransport, scene_textures
from clnlos.forward.blur import slab_blur
from clnlos.forward.lightcone import LightCone
from clnlos.forward.model import ForwardModel
from clnlos.forward.sampling import sample_scene
from clnlos.forward.scene import FACE_ANGLES, FACE_RINGS, TEXTURE_THETA, Scene
from clnlos.inverse.fk import FKMigration
from clnlos.inverse.lct import LCT
from clnlos.inverse.methods import method_class, split_rule
from clnlos.inverse.pipeline import reconstruct
from clnlos.io.capture import Capture
from clnlos.io.files import read_capture, write_capture
from clnlos.operators.spectral import multiply_spectrum
from clnlos.physics.grid import grid_offsets
from clnlos.physics.slab import CDT_SLAB
from clnlos.runtime.caches import PIPELINES
from clnlos.runtime.fft import RealFFT3
from clnlos.settings import ENV_FFT
from clnlos.study.findings.confocal_error import study_patch_scene
from clnlos.study.score.metrics import coverage_image, mip_iou, peak_depth_m


# ------------------------------------------------------------------ kernels
def bench_diffusion(b: Bench):
    slab = CDT_SLAB
    n, nt = {"tiny": (8, 64), "quick": (32, 256), "full": (64, 512)}[b.size]
    off = grid_offsets(n, 0.01)
    rho = np.sqrt(off[:, None] ** 2 + off[None, :] ** 2).ravel()
    t = np.arange(nt) * 16e-12
    ref_dt = b.dtypes[-1]
    ref = SlabTransmittance(slab, dtype=ref_dt, queue=b.q).outer_device(
        cla.to_device(b.q, rho.astype(ref_dt)), cla.to_device(b.q, t.astype(ref_dt))).get()
    for dt in b.dtypes:
        rg, tg = cla.to_device(b.q, rho.astype(dt)), cla.to_device(b.q, t.astype(dt))
        for n_dip in (1, 2, 3, 5, 10, 20, None):
            p = SlabTransmittance(slab, n_dipoles=n_dip, dtype=dt, queue=b.q)
            err = _rel(p.outer_device(rg, tg).get(), ref)
            b.add("diffusion", "n_dipoles", "auto" if n_dip is None else n_dip, dt,
                  lambda p=p, rg=rg, tg=tg: p.outer_device(rg, tg), err)
    R, T = rho[None, :], t[:, None]
    b.add("diffusion", "n_dipoles", 20, np.float64, lambda: numpy_transmittance(slab, R, T, 20),
          _rel(numpy_transmittance(slab, R, T, 20), ref), impl="numpy", sync=False)


def lightcone_reference(b: Bench):
    """(points, bins, sampling densities, reference transient) of the light-cone sections:
    'UT' sampled at 16 x the densest density, in the most precise dtype."""
    pts, bins = {"tiny": (8, 128), "quick": (32, 512), "full": (32, 512)}[b.size]
    dens = {"tiny": (2.5e3, 1e4, 4e4), "quick": (2.5e3, 1e4, 4e4, 1.6e5),
            "full": (2.5e3, 1e4, 4e4, 1.6e5, 6.4e5)}[b.size]
    ref_s = ut_scene(pts, bins, 16 * dens[-1])
    ref = LightCone(points=pts, width_m=0.6, bins=bins, bin_width_s=ref_s.bin_width_s,
                    start_s=0.0, retro=False, dtype=b.dtypes[-1], queue=b.q)(
        sample_scene(ref_s)).get()
    return pts, bins, dens, ref


def bench_lightcone(b: Bench):
    pts, bins, dens, ref = lightcone_reference(b)
    for dt in b.dtypes:
        for splat in (0, 1):
            for d in dens:
                s = ut_scene(pts, bins, d)
                smp = sample_scene(s)
                lc = LightCone(points=pts, width_m=0.6, bins=bins, bin_width_s=s.bin_width_s,
                               start_s=0.0, retro=False, splat_order=splat, dtype=dt,
                               queue=b.q)
                err = _rel(lc(smp).get(), ref)
                knob = "density_per_m2" if splat == 1 else "density_per_m2@splat0"
                b.add("lightcone", knob, d, dt, lambda lc=lc, smp=smp: lc(smp), err,
                      elements=len(smp.elements))
    s = ut_scene(pts, bins, dens[-1])
    smp = sample_scene(s)
    b.add("lightcone", "density_per_m2", dens[-1], np.float64, lambda: numpy_lightcone(s, smp),
          _rel(numpy_lightcone(s, smp), ref), impl="numpy", sync=False)


def bench_brdf(b: Bench):
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
    _peak_rows(b, a)


def mirror_angles(theta_i_deg=(10, 25, 40, 55, 70), offsets_deg=(-3, -1, -0.3, 0, 0.3, 1, 3)):
    """In-plane directions at and around the mirror direction of each incidence (radians)."""
    ti, off = np.meshgrid(np.radians(theta_i_deg), np.radians(offsets_deg), indexing="ij")
    ts = np.clip(ti + off, 0, np.pi / 2 - 1e-3)
    return np.column_stack([ti.ravel(), 0 * ti.ravel(), ts.ravel(), np.full(ti.size, np.pi)]), \
        (off.ravel() == 0)


def _peak_rows(b: Bench, a: np.ndarray):
    """Does the texture keep a specular peak? For lobes of GGX roughness alpha (0.2 broad,
    0.05 glossy, 0.01 near-mirror, about the Starlink panel's 0.3 degree lobe): error is the
    worst relative error at the exact mirror directions (the peak value), with the L2 error over
    +-3 degrees around them and the texture's size, against the time of a random lookup."""
    peak_dirs, at_peak = mirror_angles()
    sizes = (16, 32, 64) if b.size == "tiny" else (16, 32, 64, 128, 256)
    for alpha in (0.2, 0.05, 0.01):
        model = BRDFModel("microfacet", {"kd": 0.05, "ks": 1.0, "alpha": alpha, "f0": 0.9})
        truth = model(*peak_dirs.T)
        for res in sizes:
            tex = tabulate(model, res, res, 16)
            lk = TextureLookup(tex, path="buffer", queue=b.q)
            got = lk(peak_dirs)
            peak = float(np.max(np.abs(got[at_peak] / truth[at_peak] - 1)))
            b.add("brdf-peak", f"resolution@alpha={alpha}", res, np.float32,
                  lambda lk=lk: lk(a), peak, lobe_rel_error=_rel(got, truth),
                  texture_mb=round(tex.texture.nbytes / 2**20, 2))


def bench_model_level(b: Bench):
    """Forward model level: Lambertian confocal vs BRDF (glossy) confocal, same scene."""
    pts, bins = {"tiny": (8, 128), "quick": (32, 512), "full": (32, 512)}[b.size]
    ref = ForwardModel(ut_scene(pts, bins, 4e4, "painted steel plate"), queue=b.q,
                       dtype=b.dtypes[-1]).run()
    for level, mat in (("lambertian-confocal", "lambertian"),
                       ("brdf-confocal", "painted steel plate")):
        fm = ForwardModel(ut_scene(pts, bins, 4e4, mat), queue=b.q)
        out = fm.run()
        err = _rel(out / max(out.sum(), 1e-300), ref / max(ref.sum(), 1e-300))
        b.add("forward", "model_level", level, np.float32, fm.run, err)


def bench_bistatic(b: Bench):
    """Eq. 8 (the bistatic stage, kernels/bistatic.cl) beside Eq. 9 (confocal light cone +
    slab blur) on the study patch of a GGX lobe (alpha 0.1, F0 0.9: the issue's specular
    case, 0.5 m behind the CDT slab): face samples (rings x angles) and texture resolution
    against a float64 Eq. 8 at 8 x 16 samples and a 128^3 texture of the same scene. The
    ``transport`` row is the confocal model itself: its error is that of the approximation.
    Time grows with (rings x angles)^2 (pairs per element and scan point)."""
    # the study's 9.4 mm pitch (the confocal blur samples Phi on the scan grid: a coarser
    # pitch than the slab's few-cm footprint is a different error); full = the study scan
    pts, bins, bw = {"tiny": (2, 160, 48e-12), "quick": (8, 160, 48e-12),
                     "full": (32, 512, 16e-12)}[b.size]
    width = pts * 0.3 / 32
    faces = {"tiny": ((1, 1), (2, 4)), "quick": ((1, 1), (2, 4), (4, 8), (6, 12)),
             "full": ((1, 1), (2, 4), (4, 8), (6, 12))}[b.size]
    ref_face, ref_tex = {"tiny": ((4, 8), 64), "quick": ((8, 16), 128),
                         "full": ((8, 16), 128)}[b.size]
    textures = (16, 32) if b.size == "tiny" else (16, 32, 128)
    mat = {"model": "microfacet", "kd": 0.0, "ks": 1.0, "alpha": 0.1, "f0": 0.9}
    scene = study_patch_scene(mat, "bistatic", points=pts, bins=bins, bin_width_s=bw,
                              width_m=width)
    smp = sample_scene(scene)

    def plan(rings, angles, res, dt):
        t = scene.transport
        tex = scene_textures(scene, type(t)(model="bistatic", texture_theta=res,
                                            texture_dphi=res))
        return BistaticTransport(slab=scene.slab, points=pts, width_m=scene.width_m,
                                 bins=bins, bin_width_s=bw, textures=tex, rings=rings,
                                 angles=angles, dtype=dt, queue=b.q)

    ref = plan(*ref_face, ref_tex, b.dtypes[-1])(smp).get()
    grid = f"{pts}x{pts}x{bins}"
    settings = [("face_samples", (r, a, 64)) for r, a in faces]
    settings += [("texture", (FACE_RINGS, FACE_ANGLES, res)) for res in textures]
    for knob, (r, a, res) in settings:
        default = (r, a, res) == (FACE_RINGS, FACE_ANGLES, TEXTURE_THETA)
        for dt in b.dtypes if default else [np.float32]:
            bt = plan(r, a, res, dt)
            b.add("bistatic", knob, f"{r}x{a}" if knob == "face_samples" else res, dt,
                  lambda bt=bt: bt(smp), _rel(bt(smp).get(), ref), grid=grid,
                  elements=len(smp.elements), pairs=(r * a) ** 2, texture=res)
    conf = ForwardModel(study_patch_scene(mat, "confocal", points=pts, bins=bins,
                                          bin_width_s=bw, width_m=width), queue=b.q)
    b.add("bistatic", "transport", "confocal (Eq. 9)", np.float32, conf.run,
          _rel(conf.run(), ref), grid=grid, elements=len(smp.elements), pairs=1,
          sync=False)


def bench_reconstruction(b: Bench):
    sizes = {"tiny": [16], "quick": [32, 64], "full": [32, 64, 128]}[b.size]
    slab = CDT_SLAB
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
    w = ops["wiener"]
    spec = w.fft.forward(w.work_buffer)
    n = spec.size
    r = b.add("roofline", "wiener_multiply", grid, np.float32,
              lambda: multiply_spectrum(w.kernels, w.H, spec, h_scale=w.h_scale, adjoint=False,
                                        folded=w.folded, inv_snr=1e-4), None)
    r["bytes_moved"] = (2 * n + w.H.size) * spec.dtype.itemsize  # read H and X, write X
    r = b.add("roofline", "fft_r2c_pass", grid, np.float32,
              lambda: w.fft.forward(w.work_buffer, spec), None, fft_backend=w.fft.backend)
    r["bytes_moved"] = w.work_buffer.nbytes + spec.nbytes  # one read + one write: a single pass
    lct = ops["lct"]
    r = b.add("roofline", "resample_t_to_v", grid, np.float32, lambda: lct.to_v(xg), None)
    r["bytes_moved"] = 2 * xg.nbytes + lct.to_v.matrix.nnz * 8  # columns read, rows written


def end_to_end_scene(n: int, nt: int) -> Scene:
    """The end-to-end capture's scene: "UT" (0.3 m) 0.5 m behind the CDT slab, an n x n scan
    of 0.6 m, nt bins over 2.46 m of path."""
    return Scene.from_dict({
        "scan": {"width_m": 0.6, "points": n},
        "time": {"bin_width_s": 2.46 / (C0 * nt), "bins": nt, "start_s": 0.0},
        "objects": [{"shape": "letters", "text": "UT", "height_m": 0.3, "stroke_m": 0.06,
                     "translate_m": [0.0, 0.0, 0.5]}],
        "slab": slab_table(CDT_SLAB),
        "sampling": {"density_per_m2": 4e4}})


def end_to_end_config(nt: int) -> ReconstructionConfig:
    """The end-to-end rows' configuration: the defaults a user gets (SNRs "auto", as the
    CLI row) with the slab given, 2 m of path in nt bins (the photon-count rows' worker,
    :func:`clnlos.bench.cold_process.cold_run`, takes the same with each method). (A fixed
    SNR of 1e6 on 64 ps bins made LCT ring the peak to 0.68 m; the auto SNR, 1e4 there, does
    not.)"""
    return ReconstructionConfig(max_path_m=2.0, bins=nt, slab=CDT_SLAB).validate()


def photon_capture(tau: np.ndarray, scene: Scene, photons: float) -> Capture:
    """``tau`` as Poisson counts of ``photons`` in all (seed 0), no slab recorded."""
    rng = np.random.default_rng(0)
    lam = np.maximum(tau.astype(np.float64), 0) * (photons / float(tau.sum(dtype=np.float64)))
    return Capture(rng.poisson(lam).astype(np.float32), scene.bin_width_s, 0.0, scene.width_m)


def bench_end_to_end(b: Bench):
    grids = {"tiny": [(16, 64)], "quick": [(32, 128), (64, 256)],
             "full": [(32, 128), (64, 256), (128, 512)]}[b.size]
    for n, nt in grids:
        scene = end_to_end_scene(n, nt)
        fm = ForwardModel(scene, queue=b.q)
        cfg = end_to_end_config(nt)

        def run(fm=fm, cfg=cfg, scene=scene):
            tau = fm.run()
            return reconstruct(Capture(tau, scene.bin_width_s, 0.0, scene.width_m), cfg,
                               device=b.q).volume

        vol = run()
        depth = peak_depth_m(vol, 2.0 / nt / 2)
        err = abs(depth - 0.5) / 0.5
        b.add("end_to_end", "grid", f"{n}x{n}x{nt}", np.float32, run, err,
              error_kind="relative depth error")
        _cold_warm_rows(b, Capture(fm.run(), scene.bin_width_s, 0.0, scene.width_m), cfg, err,
                        f"{n}x{n}x{nt}")
        _photon_cold_rows(b, fm.run(), scene, cfg, f"{n}x{n}x{nt}")


# photons in the end-to-end capture made photon counts (issue 49's cold 128 x 128 x 512 case)
END_TO_END_PHOTONS = 1e9


def _photon_cold_rows(b: Bench, tau: np.ndarray, scene, cfg, grid: str) -> None:
    """The end-to-end capture as photon counts (END_TO_END_PHOTONS in all, Poisson, seed 0;
    no slab recorded: the default rules, GCV's slab SNR and the light cone's UPRE with its
    noise probe), reconstructed cold by LCT and f-k, each in a fresh process
    (:mod:`clnlos.bench.cold_process`) beside one r2c + c2r FFT pair of the padded grid
    timed in the same run: the time in FFT pairs, the process's CPU seconds, its peak
    resident memory during the run (VmHWM reset before it: on PoCL it includes the device
    buffers; ``peak_mem_bytes``, with the interpreter and the capture) and the peak per
    stage. Error: the relative depth error of the volume's peak."""
    cap = photon_capture(tau, scene, END_TO_END_PHOTONS)
    for row in cold_rows(cap, ("lct", "fk"), cfg.max_path_m, cfg.bins,
                         device=_device_spec(b.q.device)):
        wall = row["wall_s"]
        timing = {"median_s": wall, "min_s": wall, "max_s": wall, "repeats": 1}
        err = abs(row["peak_depth_m"] - 0.5) / 0.5
        r = b.record("end_to_end", f"reconstruct@cold,photons,{row['method']}", grid,
                     np.float32, timing, err, error_kind="relative depth error",
                     impl="process", photons=END_TO_END_PHOTONS,
                     **{k: v for k, v in row.items() if k not in ("wall_s", "peak_depth_m")})
        r["peak_mem_bytes"] = row["peak_rss_bytes"]


def _device_spec(device) -> str:
    """``P:D`` of a device, for a command run in another process."""
    for pi, plat in enumerate(cl.get_platforms()):
        for di, dev in enumerate(plat.get_devices()):
            if dev == device:
                return f"{pi}:{di}"
    return "0:0"


def _cold_warm_rows(b: Bench, cap, cfg, err, grid: str):
    """Reconstruction alone: cold (plans built: caches cleared first), warm (plans reused),
    and the CLI in a fresh process (start-up, plans, run, HDF5 + PNG), each beside one
    r2c + c2r FFT pair of the padded grid timed in the same run."""
    nt, ny, nx = cap.transient.shape
    pad = (2 * cfg.bins, 2 * ny, 2 * nx)
    fft = RealFFT3(pad, np.float32, b.q)
    xg = cla.zeros(b.q, pad, np.float32)
    pair = timeit(lambda xg=xg: fft.inverse(fft.forward(xg)), b.q,
                  repeat=b.repeat)["median_s"]
    del xg, fft  # the pair's buffers are not the reconstruction's

    def cold():
        PIPELINES.clear()
        return reconstruct(cap, cfg, device=b.q).volume

    for mode, fn in (("cold", cold), ("warm", lambda: reconstruct(cap, cfg, device=b.q).volume)):
        r = b.add("end_to_end", f"reconstruct@{mode}", grid, np.float32, fn, err,
                  error_kind="relative depth error", fft_pair_s=pair)
        r["fft_pairs"] = r["median_s"] / pair
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "c.h5"
        write_capture(path, cap.transient, bin_width_s=cap.bin_width_s, start_s=0.0,
                      scan_width_m=cap.scan_width_m)
        s = cfg.slab
        cmd = [sys.executable, "-m", "clnlos", "reconstruct", str(path), "-o",
               str(Path(d) / "v.h5"), "--bins", str(cfg.bins), "--max-path",
               str(cfg.max_path_m), "--slab-thickness", str(s.thickness_m), "--mu-a",
               str(s.mu_a), "--mu-s-prime", str(s.mu_s_prime), "--n", str(s.n)]
        cmd += ["--device", _device_spec(b.q.device)]

        def cli():
            subprocess.run(cmd, check=True, capture_output=True)

        t0 = time.perf_counter()
        cli()
        wall = time.perf_counter() - t0
    r = b.add("end_to_end", "cli@cold", grid, np.float32, lambda: None, err,
              impl="cli", sync=False, error_kind="relative depth error", fft_pair_s=pair)
    r.update(median_s=wall, min_s=wall, max_s=wall, fft_pairs=wall / pair)


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


def bench_iterative(b: Bench):
    """Reconstruction quality against time: LCT, f-k and the iterative method at several
    iteration counts, on a noisy and a noise-free capture of a 'T' of 4.5 cm bars 0.5 m behind
    the CDT slab (seed Table 1 scan, 0.3 m). The error is 1 - IoU of the Otsu-thresholded
    MIP with the true mask (extra fields: IoU, depth error, relative L2 error of the
    normalised MIP against the true coverage)."""
    points, bins, bw = {"tiny": (12, 96, 64e-12), "quick": (24, 256, 32e-12),
                        "full": (32, 512, 16e-12)}[b.size]
    iters = {"tiny": (5, 20), "quick": (25, 50, 100, 200),
             "full": (25, 50, 100, 200, 400)}[b.size]
    for noise in (False, True):
        d = {"seed": 0, "scan": {"width_m": 0.3, "points": points},
             "time": {"bin_width_s": bw, "bins": bins, "start_s": 0.0},
             "objects": [{"shape": "rectangle", "size_m": [0.16, 0.045],
                          "translate_m": [0.0, 0.0575, 0.5]},
                         {"shape": "rectangle", "size_m": [0.045, 0.115],
                          "translate_m": [0.0, -0.0225, 0.5]}],
             "slab": slab_table(CDT_SLAB),
             "laser": {"pulse_width_s": 35e-12}, "sampling": {"density_per_m2": 1e5}}
        if noise:
            d["detector"] = {"power_w": 0.4, "rep_rate_hz": 10e6, "exposure_s": 0.1,
                             "efficiency": 0.3, "etendue_m2_sr": 1e-9,
                             "dark_count_rate_hz": 1e3}
        scene = Scene.from_dict(d)
        fm = ForwardModel(scene, queue=b.q)
        cap = fm.capture()
        cover = np.clip(coverage_image(fm.samples.elements, scene.scan_centres()), 0, 1)
        mask = cover >= 0.5
        # the iterative method at each iteration count with the default slab model, and at
        # the largest with Wiener first (slab_model "none": the knob's accuracy and cost);
        # all at GCV's slab SNR, so that the rows differ by the knob alone (thinning is its
        # own row of auto_params_cost, and would deepen far at 5 iterations)
        settings = ([("lct", None, None), ("fk", None, None)]
                    + [("iterative", k, None) for k in iters] + [("iterative", iters[-1], "none")])
        for method, k, slab_model in settings:
            extra = {"iterations": k} if k else {}
            if slab_model:
                extra["slab_model"] = slab_model
            cfg = ReconstructionConfig(max_path_m=1.6, slab=CDT_SLAB, method=method,
                                       snr_rule="gcv", **extra).validate()

            def run(cfg=cfg, cap=cap):
                return reconstruct(cap, cfg, device=b.q)

            rec = run()
            iou = mip_iou(rec.volume, mask)[0]
            mip = rec.volume.max(axis=0)
            mip = mip / mip.max() if mip.max() > 0 else mip
            depth = peak_depth_m(rec.volume, rec.extents["voxel_depth_m"])
            b.add("inversion_quality", f"method@{'photon-noise' if noise else 'noise-free'}",
                  method if k is None else f"iterative@{k}" + (f"/{slab_model}"
                                                                  if slab_model else ""),
                  np.float32, run, 1.0 - iou,
                  error_kind="1 - IoU", iou=iou, depth_error_m=abs(depth - 0.5),
                  mip_rel_l2=_rel(mip, cover), iterations=k or 0,
                  grid=f"{points}x{points}x{rec.volume.shape[0]}")


def oracle_sample(b: Bench) -> tuple[tuple, int | None]:
    """(captures, the iterative method's iterations at most) of the sections that run the
    oracle captures: all of them at ``full`` (the config's iterations), BENCH_CASE on a
    16 x 16 x 128 grid otherwise (20 iterations at ``tiny``, 50 at ``quick``)."""
    small = (replace(case_named(BENCH_CASE), points=16, bins=128, bin_width_s=64e-12),)
    cases = {"tiny": small, "quick": small, "full": ORACLE_CASES}[b.size]
    return cases, {"tiny": 20, "quick": 50, "full": None}[b.size]


def bench_auto_params(b: Bench):
    """The "auto" SNRs against the oracle grid (:mod:`clnlos.bench.oracle`): per capture and
    method the time of the auto reconstruction, error = max(0, oracle IoU - auto IoU)
    (extra fields: the IoUs of auto, the oracle and the photon rule, the SNRs chosen)."""
    cases, iterations = oracle_sample(b)
    for case in cases:
        cap, mask = simulate_case(case, b.q)
        for method in ORACLE_METHODS:
            row = compare_method(cap, mask, method, iterations=iterations, queue=b.q)
            cfg = ReconstructionConfig(slab=cap.recorded_slab()[0], method=method,
                                       **({} if iterations is None else
                                          {"iterations": iterations})).validate()
            b.add("auto_params", f"gap@{case.name}", method, np.float32,
                  lambda cfg=cfg, cap=cap: reconstruct(cap, cfg, device=b.q),
                  max(0.0, row["gap"]), error_kind="oracle IoU - auto IoU",
                  **{k: v for k, v in row.items() if k != "method"})
            if row["auto_snr_rule"] != "gcv":  # the GCV rule beside a split search
                _bench_gcv_rule(b, case, cap, mask, cfg, row)


def _bench_gcv_rule(b: Bench, case, cap, mask, cfg, row: dict) -> None:
    """A method with ``snr_rule = "gcv"`` (GCV's slab SNR: the study's rule,
    :class:`clnlos.study.plan.scenes.StudyGrid`) on one capture where the default searched a
    split of the counts (reproducibility, :mod:`clnlos.inverse.reproducibility`): its time
    and its gap to the oracle of the default's ``row``."""
    cfg = cfg.replace(snr_rule="gcv").validate()
    rec = reconstruct(cap, cfg, device=b.q)
    iou = mip_iou(rec.volume, mask)[0]
    b.add("auto_params", f"gap@{case.name}", f"{cfg.method} snr_rule=gcv", np.float32,
          lambda: reconstruct(cap, cfg, device=b.q), max(0.0, row["oracle_iou"] - iou),
          error_kind="oracle IoU - auto IoU", auto_iou=iou, oracle_iou=row["oracle_iou"],
          auto_snr=rec.params.get("snr_used"), default_rule_iou=row["auto_iou"],
          thinning_factor=row.get("auto_thinning_factor"))


# the fixed SNRs the rules are priced against: examples/reconstruct_noisy.toml's (slab 1e4,
# light cone 1e3), numbers a user of the wide noisy example runs with
FIXED_SNRS = (1e4, 1e3)


def auto_params_rules(method: str) -> list[tuple[str, dict]]:
    """(rule, the config fields it sets) of :func:`bench_auto_params_cost` for ``method``:
    fixed SNRs; the slab SNR by GCV (the light cone's fixed); the light-cone SNR by UPRE
    with the noise probe (the slab's fixed; methods with a light-cone filter: LCT, the
    iterative method's warm start); both by the GCV rule (GCV, then UPRE); the method's
    split search (thinning, reproducibility); and "auto" (the default: one of these)."""
    slab, cone = FIXED_SNRS
    lc = method_class(method).lightcone_filter
    rules = [("fixed", {"snr": slab, "inversion_snr": cone}),
             ("gcv", {"snr_rule": "gcv", "inversion_snr": cone})]
    if lc:
        rules += [("upre", {"snr": slab}), ("gcv+upre", {"snr_rule": "gcv"})]
    rules += [(split_rule(method), {"snr_rule": split_rule(method)}), ("auto", {})]
    return rules


def extra_reconstructions(params: dict) -> int:
    """Reconstructions a split search ran besides the one returned (its halves per
    candidate: thinning's training half per factor, reproducibility's two halves per
    setting), from what the volume records."""
    if "thinning_tried" in params:
        return len(json.loads(params["thinning_tried"]))
    if "reproducibility_tried" in params:
        return 2 * len(json.loads(params["reproducibility_tried"]))
    return 0


def bench_auto_params_cost(b: Bench):
    """What each rule for the "auto" SNRs costs and earns (issue 38): per capture, method and
    rule (:func:`auto_params_rules`) the reconstruction's time (one run, plans built by a
    run before), the reconstructions it runs besides the one returned, the peak resident
    memory of the process during it (VmHWM reset before the run; on PoCL it includes the
    device buffers) and above its start, and the IoU gain over the fixed SNRs (FIXED_SNRS)
    on the same capture; error = 1 - IoU. On the oracle captures (``full``), a reduced
    one otherwise."""
    cases, iterations = oracle_sample(b)
    for case in cases:
        cap, mask = simulate_case(case, b.q)
        for method in ORACLE_METHODS:
            base = ReconstructionConfig(slab=cap.recorded_slab()[0], method=method,
                                        **({} if iterations is None else
                                           {"iterations": iterations}))
            fixed_iou = None
            for rule, fields in auto_params_rules(method):
                cfg = base.replace(**fields).validate()
                reconstruct(cap, cfg, device=b.q)  # plans built: the row times the rule
                start = reset_peak_rss()
                rec, timing = timed_once(lambda cfg=cfg, cap=cap: reconstruct(cap, cfg, device=b.q),
                                         b.q)
                peak = peak_rss_bytes()
                iou = mip_iou(rec.volume, mask)[0]
                fixed_iou = iou if rule == "fixed" else fixed_iou
                r = b.record("auto_params_cost", f"{method}@{case.name}", rule, np.float32,
                             timing, 1.0 - iou, error_kind="1 - IoU", method=method,
                             capture=case.name, rule=rule, iou=iou,
                             iou_gain=iou - fixed_iou,
                             extra_reconstructions=extra_reconstructions(rec.params),
                             snr_rule_used=rec.params.get("snr_rule_used"),
                             snr_used=rec.params.get("snr_used"),
                             inversion_snr_used=rec.params.get("inversion_snr_used"),
                             iterations=(rec.solver or {}).get("iterations"),
                             peak_above_start_bytes=max(0, peak - start))
                r["peak_mem_bytes"] = peak
    _released_capture_cost(b)


# the released S+U capture of the LCT paper (retroreflective letters around a corner, no
# slab, 64 x 64 x 2048 bins of 4 ps; README of the data folder), under --real-data DIR
RELEASED_LCT_CAPTURE = "lct/data_s_u.mat"


def _released_capture_cost(b: Bench) -> None:
    """The fixed and the default ("auto") light-cone SNR of LCT on the released capture
    (``b.options["real_data"]``: a folder holding RELEASED_LCT_CAPTURE; skipped with a note
    without it), as read by ``clnlos reconstruct`` (at ``tiny`` and ``quick`` rebinned to
    512 bins): the time of one run (plans built by a run before), the stages' times the
    volume records, and auto's pipeline time over the fixed one's (no ground truth: no
    error)."""
    data = b.options.get("real_data")
    path = None if data is None else Path(data) / RELEASED_LCT_CAPTURE
    if path is None or not path.is_file():
        where = "given" if data is None else f"at {path}"
        b.note(f"auto_params_cost: no released LCT capture {where}: its rows are skipped "
               f"(--real-data DIR with {RELEASED_LCT_CAPTURE})")
        return
    cap = read_capture(path)
    base = ReconstructionConfig(method="lct", **({} if b.size == "full" else {"bins": 512}))
    fixed_s = None
    for rule, fields in (("fixed", {"inversion_snr": FIXED_SNRS[1]}), ("auto", {})):
        cfg = base.replace(**fields).validate()
        reconstruct(cap, cfg, device=b.q)  # plans built: the row times the rule
        rec, timing = timed_once(lambda cfg=cfg: reconstruct(cap, cfg, device=b.q), b.q)
        stage_s = float(sum(rec.timings_s.values()))
        fixed_s = stage_s if rule == "fixed" else fixed_s
        b.record("auto_params_cost", f"lct@{Path(RELEASED_LCT_CAPTURE).name}", rule,
                 np.float32, timing, None, method="lct", capture=str(path.name), rule=rule,
                 released=True, grid="x".join(map(str, rec.volume.shape)),
                 stages_s=dict(rec.timings_s), pipeline_s=stage_s,
                 over_fixed=stage_s / fixed_s,
                 inversion_snr_used=rec.params.get("inversion_snr_used"),
                 inversion_snr_rule=rec.params.get("inversion_snr_rule"))


# ------------------------------------------------------------------ cost per grid and reach
def bench_lightcone_grid(b: Bench):
    """Light-cone throughput and the cost of a density with its sampling (the rows of the
    former per-kernel forward script). UT letters, no
    slab (:func:`ut_scene`): per grid, OpenCL (float32, float64) and numpy float64 (one cold
    run) with element-scan-point ``pairs_per_s``, errors against the float64 OpenCL run of the
    same grid; then knob ``density_per_m2@sampled``: sample_scene + light cone timed together,
    against the float64 reference of :func:`bench_lightcone` (16 x the densest density)."""
    grids, dens = {"tiny": ([(8, 128)], 4e4), "quick": ([(32, 512)], 4e5),
                   "full": ([(32, 512), (64, 1024)], 4e5)}[b.size]
    for points, bins in grids:
        s = ut_scene(points, bins, dens)
        smp = sample_scene(s)
        pairs = len(smp.elements) * points * points
        grid = f"{points}x{points}x{bins}"
        outs = {}
        for dt in reversed(b.dtypes):
            lc = LightCone(points=points, width_m=s.width_m, bins=bins,
                           bin_width_s=s.bin_width_s, start_s=0.0, retro=False, dtype=dt,
                           queue=b.q)
            outs[dt] = lc(smp).get()
            r = b.add("lightcone", "grid", grid, dt, lambda lc=lc, smp=smp: lc(smp),
                      _rel(outs[dt], outs[b.dtypes[-1]]), elements=len(smp.elements))
            r["pairs_per_s"] = pairs / r["median_s"]
        out, t = timed_once(lambda s=s, smp=smp: numpy_lightcone(s, smp))
        r = b.record("lightcone", "grid", grid, np.float64, t, _rel(out, outs[b.dtypes[-1]]),
                     impl="numpy", elements=len(smp.elements))
        r["pairs_per_s"] = pairs / r["median_s"]
    pts, bins, densities, ref = lightcone_reference(b)
    for d in densities:
        s = ut_scene(pts, bins, d)
        for dt in b.dtypes:
            lc = LightCone(points=pts, width_m=0.6, bins=bins, bin_width_s=s.bin_width_s,
                           start_s=0.0, retro=False, dtype=dt, queue=b.q)

            def run(s=s, lc=lc):
                return lc(sample_scene(s))

            b.add("lightcone", "density_per_m2@sampled", d, dt, run, _rel(run().get(), ref),
                  elements=len(sample_scene(s).elements))


def bench_blur_reach(b: Bench):
    """How far past the scan border the slab-blurred light cone is computed: the built-in
    demo scene (Table 1: UT 0.5 m behind the CDT slab, 0.3 m scan; at ``tiny`` an 8 x 8 x 128
    scan of it), each ``blur_reach_tol`` (1 = no margin) against tol 1e-5, timed as
    ForwardModel.run (light cone on the widened grid + blur + pulse). Formerly in the
    per-kernel forward script."""
    base = tomllib.loads(importlib.resources.files("clnlos").joinpath(
        "data/demo_scene.toml").read_text())
    if b.size == "tiny":
        base = {**base, "scan": {**base["scan"], "points": 8},
                "time": {**base["time"], "bins": 128, "bin_width_s": 64e-12},
                "sampling": {**base["sampling"], "density_per_m2": 4e4}}

    def model(tol):
        d = {**base, "sampling": {**base["sampling"], "blur_reach_tol": tol}}
        return ForwardModel(Scene.from_dict(d), queue=b.q)

    ref = model(1e-5).run()
    tols = (1.0, 1e-3) if b.size != "full" else (1.0, 1e-1, 1e-2, 1e-3, 1e-4)
    for tol in tols:
        fm = model(tol)
        b.add("forward(slab)", "blur_reach_tol", f"{tol:g} (margin {fm.margin})", np.float32,
              fm.run, _rel(fm.run(), ref), elements=len(fm.samples.elements))


# ------------------------------------------------------------------ measured BRDFs
MEASURED = ("nist_ptfe_white_532nm", "pbrt_cayman_550nm", "pbrt_krylon_blue_550nm",
            "starlink_chassis_532nm")


def bench_brdf_measured(b: Bench):
    """Neural BRDFs against the texture lookup and the analytic fit (the rows of the former
    BRDF script; its texture table is :func:`bench_brdf`).
    Needs torch for the MLP rows and the measured data (``--brdf-data DIR``, a folder
    of ``*_gonio.csv``) for the fits; each part absent is skipped with a note.

    * ``brdf``/``mlp-eval``: an MLP (improved recipe) trained on 500 samples of the
      microfacet model of :func:`bench_brdf`, evaluated on the same random queries (torch
      CPU); error against the model itself, beside the texture rows of that section;
    * ``brdf-measured``/``fit@<material>``: per material, the five-parameter fit and the MLP
      (seed and improved recipes), each timed once (training included); error = test-set
      relative error (extra: test and train agreement %, epochs).

    ``tiny`` (a smoke run): 20 epochs, one network instead of the improved recipe's five, one
    material, two starts of the five-parameter fit."""
    torch = importlib.util.find_spec("torch") is not None
    epochs = {"tiny": 20, "quick": 1000, "full": 3000}[b.size]
    members = {"members": 1} if b.size == "tiny" else {}  # the improved recipe's ensemble
    if torch:
        model = BRDFModel("microfacet", {"kd": 0.1, "ks": 1.0, "alpha": 0.2, "f0": 0.9})
        rng = np.random.default_rng(0)
        n = {"tiny": 20_000, "quick": 200_000, "full": 1_000_000}[b.size]
        a = np.column_stack([rng.uniform(0, 1.45, n), rng.uniform(-np.pi, np.pi, n),
                             rng.uniform(0, 1.45, n), rng.uniform(-np.pi, np.pi, n)])
        fake = np.column_stack([rng.uniform(0, 1.4, 500), np.zeros(500),
                                rng.uniform(0, 1.4, 500), rng.uniform(0, np.pi, 500)])
        mlp, _ = train_mlp(BRDFSamples(*fake.T, model(*fake.T)),
                           MLPConfig(epochs=min(epochs, 300), **members))
        b.add("brdf", "mlp-eval", "torch-cpu", np.float32, lambda: mlp(*a.T),
              _rel(mlp(*a.T), model(*a.T)), impl="torch", sync=False, queries=n)
    else:
        b.note("brdf_measured: torch not installed: the MLP rows are skipped")
    data = b.options.get("brdf_data")
    if data is None or not Path(data).is_dir():
        where = "given" if data is None else f"at {data}"
        b.note(f"brdf_measured: no measured data {where}: the measured-material rows are "
               "skipped (--brdf-data DIR)")
        return
    data = Path(data)
    materials = {"tiny": MEASURED[:1], "quick": MEASURED[:2], "full": MEASURED}[b.size]
    for mat in materials:
        tr = read_gonio_csv(data / f"{mat}_gonio.csv")
        te = read_gonio_csv(data / f"{mat}_test.csv")
        r, t = timed_once(lambda tr=tr, te=te: fit_analytic(
            "five-param", tr, te, **({"starts": 2} if b.size == "tiny" else {})))
        b.record("brdf-measured", f"fit@{mat}", "five-param", np.float64, t,
                 r.metrics["test_relative_error"], impl="host",
                 error_kind="test relative error", material=mat,
                 test_agreement_pct=r.metrics["test_agreement_pct"],
                 train_agreement_pct=r.metrics["train_agreement_pct"])
        for recipe in ("seed", "improved") if torch else ():
            (m, log), t = timed_once(lambda tr=tr, recipe=recipe: train_mlp(
                tr, MLPConfig(recipe=recipe, epochs=epochs, **members)))
            p = m(te.theta_i, te.phi_i, te.theta_s, te.phi_s)
            ptr = m(tr.theta_i, tr.phi_i, tr.theta_s, tr.phi_s)
            b.record("brdf-measured", f"fit@{mat}", f"mlp-{recipe}", np.float32, t,
                     relative_error(p, te.brdf), impl="torch",
                     error_kind="test relative error", material=mat,
                     test_agreement_pct=agreement(p, te.brdf),
                     train_agreement_pct=agreement(ptr, tr.brdf),
                     epochs=log["epochs_run"])


# ------------------------------------------------------------------ isolated processes
WORKER = "import sys; from clnlos.bench.isolated import main; main(sys.argv[1:])"


def bench_reconstruction_process(b: Bench):
    """Reconstruction speed and memory, one implementation per process (the rows of the former
    reconstruction script): per grid (4N x N x N)
    OpenCL (FFT backend auto), OpenCL with the host FFT (CLNLOS_FFT=host), torch
    CPU float32 (skipped with a note where torch is absent) and numpy float64, each run by
    :mod:`clnlos.bench.isolated` in a fresh process, so its ``peak_mem_bytes`` is its own:
    stages deconvolve, lct, fk and end_to_end (upload, deconvolve, LCT, download), with the
    plan time (``plan_s``). No errors: the same math is compared by ``reconstruction``."""
    sizes = {"tiny": [16], "quick": [32, 64], "full": [32, 64, 128]}[b.size]
    # tiny (seconds): one OpenCL worker (the host FFT, through the environment) and one
    # baseline worker; the others start in seconds each (torch: over ten on 2 cores)
    impls = ("opencl-hostfft", "numpy") if b.size == "tiny" else PROCESS_IMPLS
    impls = [i for i in impls if i != "torch" or importlib.util.find_spec("torch")]
    if "torch" not in impls and b.size != "tiny":
        b.note("reconstruction_process: torch not installed: the torch rows are skipped")
    for n in sizes:
        for impl in impls:
            cmd = [sys.executable, "-c", WORKER, impl, str(n), "--size", b.size,
                   "--device", _device_spec(b.q.device)]
            env = dict(os.environ)
            if impl == "opencl-hostfft":
                env[ENV_FFT] = "host"
            r = subprocess.run(cmd, capture_output=True, text=True, env=env)
            if r.returncode != 0:
                b.note(f"reconstruction_process: {impl} at N={n} failed: {r.stderr[-2000:]}")
                continue
            rows = json.loads(r.stdout.strip().splitlines()[-1])
            b.rows.extend(rows)
            end = next(x for x in rows if x["knob"] == "end_to_end@grid")
            print(f"  {impl} {end['value']}: end to end {end['median_s']:.3g} s", flush=True)
