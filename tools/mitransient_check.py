"""Issue 27, item 3b: the bistatic transport against Mitsuba 3 + mitransient.

mitransient renders the hidden side alone -- light leaves the slab's hidden face (a diffuse
relay wall) at a laser point r1, meets the hidden patch, returns to a sensor pixel r2 --
exhaustively over a small laser x sensor grid of face cells (``transient_nlos_path``, laser
and hidden-geometry sampling, third bounce only, first and last legs not counted in time,
one render per laser cell: ``CaptureType.Single``). Numpy then adds the slab:

    tau(r0, t) = sum_{c1, c2} M(c1 - r0) (x)_t M(c2 - r0) (x)_t I(c1, c2, t),

M(c - r0) the slab's probability per lag of leaving the face in cell c (the Gaussian
lateral factor of the dipole series of :mod:`clnlos.diffusion` integrated exactly over the
cell). Three transients per scan point r0 and material:

- ``mitransient``: I rendered by mitransient (scaled by one constant K, fitted on the
  Lambertian patch over all pairs: the renderer's laser power and wall albedo are not
  clnlos' units; the GGX patch uses the same K);
- ``grid``: I from an independent numpy sum over the same surface elements on the same cell
  grid (the Eq. 8 integrand, GGX on vectors, linear splatting), with the same M;
- ``clnlos``: ``clnlos simulate`` with ``[transport] model = "bistatic"``.

mitransient against grid isolates the renderer (the same cells, the same slab); grid
against clnlos isolates the face quadrature (cells against rings of equal slab energy).
Patches: a 6 cm Lambertian patch and a 6 cm GGX patch (alpha 0.1, F0 0.9: Mitsuba's
``roughconductor`` with a perfect mirror's Fresnel scaled by 0.9), both tilted 5 degrees,
0.35 m behind the CDT slab and shifted so that the mirror direction of their centre meets
the face at x = 0; scan points on it and 3 and 6 cm off. Writes
tools/results/mitransient_check.{csv,json}.

Measured (tools/results/mitransient_check.csv, 2 cm cells, 512 samples per pixel, 88 renders
per patch in 7-12 s on 2 CPU cores): mitransient / grid 1.000-1.007 in total and 0.1-0.8% in
shape per scan point; mitransient / clnlos 0.993-1.003 and 0.2-1.1%. Per face pair before
the slab, the rendered and the element-sum transients differ by 18% (Lambertian) and 31%
(GGX) in binned shape and 4.5% in per-pair totals, unchanged from 512 to 4096 samples per
pixel (0.180 -> 0.174): the grid sums ~64 surface elements of 7.5 mm splatted into 32 ps
bins where the renderer integrates the continuous patch; summed over the face through the
slab the difference averages out.

Skips with one line when mitsuba or mitransient is absent (neither is a clnlos dependency:
``pip install mitsuba mitransient``) or when Dr.Jit's LLVM is older than 16 (Debian 12's
LLVM 14 and 15 abort on Dr.Jit 1.5's kernels: "LLVM ERROR: Cannot select: f32 = fminimum";
any libLLVM >= 16 works, e.g. a Rust toolchain's, given with --libllvm).

    PYTHONPATH=. .venv/bin/python tools/mitransient_check.py [--spp 512] [--cell 0.02]
        [--libllvm /path/to/libLLVM.so.N]
"""

from __future__ import annotations

import argparse
import itertools
import math
import os
import sys
import time
from pathlib import Path

import numpy as np
from scipy.special import erf

OUT = Path(__file__).resolve().parent / "results"
BINS, DT = 128, 32e-12
DEPTH, TILT, SIZE = 0.35, 5.0, 0.06
GGX = {"kd": 0.0, "ks": 1.0, "alpha": 0.1, "f0": 0.9}
SCAN_X = (0.0, 0.03, 0.06)            # scan points (m, y = 0): on the mirror point, off it
FACE_X, FACE_Y = (-0.08, 0.14), (-0.08, 0.08)  # the laser x sensor grid of face cells (m)
LASER_ORIGIN = (0.0, -0.6, 1.2)       # the laser and sensor origin (hidden side, far)
INTEGRATOR_EXTRA: dict = {"discard_direct_paths": True}  # (filter_bounces = 3 gives zeros)
MIN_LLVM = (16,)  # Dr.Jit 1.5 emits llvm.minimum: LLVM 14 and 15 abort on it on x86


def _import_mitsuba():
    """(mitsuba, mitransient) with an LLVM variant, or None with the reason."""
    try:
        import mitsuba as mi
    except ImportError as exc:
        return None, f"mitsuba not installed ({exc})"
    for v in ("llvm_ad_mono", "llvm_ad_rgb"):
        if v in mi.variants():
            try:
                mi.set_variant(v)
                break
            except Exception as exc:  # noqa: BLE001 (no LLVM library, ...)
                why = f"mitsuba variant {v} unusable ({type(exc).__name__}: {exc})"
    else:
        return None, locals().get("why", "no llvm_* variant of mitsuba")
    import drjit as dr

    llvm = tuple(dr.detail.llvm_version())
    if llvm < MIN_LLVM:
        return None, (f"Dr.Jit found LLVM {'.'.join(map(str, llvm))}, which cannot compile its "
                      "kernels on x86 ('LLVM ERROR: Cannot select: f32 = fminimum'); give a "
                      f"libLLVM >= {MIN_LLVM[0]} with --libllvm PATH (or DRJIT_LIBLLVM_PATH)")
    try:
        import mitransient as mitr
    except (ImportError, RuntimeError) as exc:
        return None, f"mitransient not importable ({type(exc).__name__}: {exc})"
    return (mi, mitr), None


# ------------------------------------------------------------------ the scene (clnlos side)
def patch_scene(material, transport=None, *, width_m=0.21, points=7):
    from clnlos.config import slab_table
    from clnlos.forward.scene import Scene
    from clnlos.physics.slab import CDT_SLAB

    shift = DEPTH * math.tan(math.radians(TILT))
    d = {"scan": {"width_m": width_m, "points": points},  # centres at 0, 3, 6 cm
         "time": {"bin_width_s": DT, "bins": BINS},
         "objects": [{"shape": "rectangle", "size_m": [SIZE, SIZE],
                      "translate_m": [shift, 0.0, DEPTH], "rotate_deg": [0, TILT, 0],
                      "material": material}],
         "slab": slab_table(CDT_SLAB), "sampling": {"density_per_m2": 1.6e4}}
    if transport is not None:
        d["transport"] = transport
    return Scene.from_dict(d)


def face_cells(cell: float):
    xs = np.arange(FACE_X[0] + cell / 2, FACE_X[1], cell)
    ys = np.arange(FACE_Y[0] + cell / 2, FACE_Y[1], cell)
    return xs, ys


def cell_masses(slab, xs, ys, cell: float, r0x: float, queue=None) -> np.ndarray:
    """M [cell (x-major), lag]: probability per lag of leaving the face in each cell."""
    from clnlos.forward.bistatic import node_weights

    base, a = node_weights(slab, BINS, DT, None, queue)   # [lag, node]
    s = np.sqrt(a)[None]

    def axis(c):  # (1/2)(erf(c1 / sqrt a) - erf(c0 / sqrt a)) per cell
        return 0.5 * (erf((c[:, None, None] + cell / 2) / s)
                      - erf((c[:, None, None] - cell / 2) / s))

    fx, fy = axis(xs - r0x), axis(ys)             # [n, lag, node]
    # base = dt w T(0,t) pi a; the lateral density exp(-rho^2/a) / (pi a) integrates to fx fy
    m = np.einsum("xln,yln,ln->xyl", fx, fy, base)
    return m.reshape(len(xs) * len(ys), -1)


def ggx_brdf(n, wi, wo, alpha, f0, kd=0.0, ks=1.0):
    """GGX Cook-Torrance, Schlick Fresnel, separable Smith G, on vectors (broadcast)."""
    ci = np.clip((wi * n).sum(-1), 1e-9, 1)
    co = np.clip((wo * n).sum(-1), 1e-9, 1)
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    ch = np.clip((h * n).sum(-1), 1e-9, 1)
    cih = np.clip((h * wi).sum(-1), 0, 1)
    a2 = alpha * alpha
    D = a2 / (np.pi * (ch * ch * (a2 - 1) + 1) ** 2)

    def g1(c):
        return 2 * c / (c + np.sqrt(a2 + (1 - a2) * c * c))

    F = f0 + (1 - f0) * (1 - cih) ** 5
    return kd / np.pi + ks * D * F * g1(ci) * g1(co) / (4 * ci * co)


def grid_hidden(el, albedo, cells, kind: str) -> np.ndarray:
    """I [cell1, cell2, bin] by direct sums over the elements (numpy float64)."""
    from clnlos import C0

    face = np.column_stack([cells, np.zeros(len(cells))])
    dvec = face[None] - el.pos[:, None]                # [E, C, 3]
    dist = np.linalg.norm(dvec, axis=2)
    w = dvec / dist[..., None]
    cos_face = el.pos[:, None, 2] / dist
    cos_x = np.einsum("ekc,ec->ek", w, el.normal)
    g = np.where((cos_face > 0) & (cos_x > 0), cos_face * cos_x / dist**2, 0.0)
    n_c = len(cells)
    out = np.zeros((n_c, n_c, BINS))
    for e in range(len(el)):
        if kind == "lambertian":
            f = np.full((n_c, n_c), 1 / np.pi)
        else:
            f = ggx_brdf(el.normal[e], w[e][:, None, :], w[e][None, :, :], GGX["alpha"],
                         GGX["f0"])
        wgt = f * g[e][:, None] * g[e][None, :] * albedo[e] * el.area[e]
        b = (dist[e][:, None] + dist[e][None, :]) / (C0 * DT) - 0.5  # linear splat
        k = np.floor(b).astype(int)
        fr = b - k
        for kk, ww in ((k, wgt * (1 - fr)), (k + 1, wgt * fr)):
            ok = (kk >= 0) & (kk < BINS)
            i1, i2 = np.nonzero(ok)
            np.add.at(out, (i1, i2, kk[ok]), ww[ok])
    return out


def add_slab(hidden: np.ndarray, masses: np.ndarray) -> np.ndarray:
    """sum_{c1, c2} M(c1) (x) M(c2) (x) I(c1, c2) over the window (FFT, zero-padded)."""
    n = 2 * BINS
    ih = np.fft.rfft(hidden, n, axis=2)                # [c, c, f]
    mh = np.fft.rfft(masses, n, axis=1)                # [c, f]
    return np.fft.irfft(np.einsum("af,abf,bf->f", mh, ih, mh), n)[:BINS]


# ------------------------------------------------------------------ mitransient
def render_hidden(mods, el_scene, cells_xy, xs, ys, cell: float, kind: str, spp: int,
                  log) -> np.ndarray:
    """I [laser cell, sensor cell, bin] rendered by mitransient (its own units)."""
    mi, mitr = mods
    from mitransient.integrators.transientnlospath import CaptureType

    from clnlos import C0

    T = mi.ScalarTransform4f
    obj = el_scene.objects[0]
    centre = [float(v) for v in obj.translate_m]
    from clnlos.forward.sampling import sample_scene

    smp = sample_scene(el_scene)
    normal = smp.elements.normal.mean(axis=0)
    normal = normal / np.linalg.norm(normal)
    bsdf = ({"type": "diffuse", "reflectance": 1.0} if kind == "lambertian" else
            {"type": "roughconductor", "distribution": "ggx", "alpha": GGX["alpha"],
             "material": "none", "specular_reflectance": GGX["f0"]})
    to_world = T().look_at(origin=centre, target=[c + n for c, n in zip(centre, normal,
                                                                          strict=True)],
                           up=[0, 1, 0]) @ T().scale([SIZE / 2, SIZE / 2, 1])
    wall_c = [(FACE_X[0] + FACE_X[1]) / 2, (FACE_Y[0] + FACE_Y[1]) / 2, 0.0]
    wall_h = [(FACE_X[1] - FACE_X[0]) / 2, (FACE_Y[1] - FACE_Y[0]) / 2, 1.0]
    nx, ny = len(xs), len(ys)
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "transient_nlos_path", "nlos_laser_sampling": True,
                       "nlos_hidden_geometry_sampling": True,
                       "nlos_hidden_geometry_sampling_do_rroulette": False,
                       "nlos_hidden_geometry_sampling_includes_relay_wall": False,
                       "account_first_and_last_bounces": False, **INTEGRATOR_EXTRA,
                       "capture_type": int(CaptureType.Single), "temporal_filter": "box"},
        "hidden": {"type": "rectangle", "to_world": to_world, "bsdf": bsdf},
        "laser": {"type": "projector", "irradiance": 100.0, "fov": 0.2,
                  "to_world": T().translate(list(LASER_ORIGIN))},
        "relay_wall": {
            "type": "rectangle", "to_world": T().translate(wall_c) @ T().scale(wall_h),
            "bsdf": {"type": "diffuse", "reflectance": 1.0},
            "nlos_sensor": {
                "type": "nlos_capture_meter", "sensor_origin": list(LASER_ORIGIN),
                "sampler": {"type": "independent", "sample_count": spp},
                "transient_film": {"type": "transient_hdr_film", "width": nx, "height": ny,
                                   "temporal_bins": BINS, "bin_width_opl": C0 * DT,
                                   "start_opl": 0.0, "rfilter": {"type": "box"}}}}})
    wall = next(s for s in scene.shapes() if s.id() == "relay_wall")
    laser = next(e for e in scene.emitters() if e.id() == "laser")
    out = np.zeros((len(cells_xy), nx, ny, BINS))
    t0 = time.perf_counter()
    for i, (cx, cy) in enumerate(cells_xy):
        mitr.nlos.focus_emitter_at_relay_wall_3dpoint(mi.Point3f(float(cx), float(cy), 0.0), wall,
                                                      laser)
        _, tr = mi.render(scene, seed=i)
        a = np.array(tr)                                   # [height, width, time, ch]
        out[i] = (a[..., 0] if a.ndim == 4 else a).transpose(1, 0, 2)
        if i == 0 or (i + 1) % 20 == 0:
            log(f"  {kind}: laser cell {i + 1}/{len(cells_xy)} "
                f"({time.perf_counter() - t0:.0f} s)")
    # the hidden side starts at 2 x 0.9 depth of path: earlier bins hold only the relay
    # wall's own light (the laser's pixel at zero path)
    out[..., :int(1.8 * DEPTH / (C0 * DT))] = 0.0
    return out


def orient(rendered: np.ndarray, ref: np.ndarray, nx: int, ny: int):
    """Sensor pixels [laser, x, y, t] as cells (x-major) in the orientation whose per-pair
    mean arrival bin best matches the numpy grid's (the film's x / y axes against uv):
    (I [laser, cell, t], the orientation, its rms arrival mismatch in bins)."""
    t = np.arange(BINS)

    def arrival(a):
        s = a.sum(-1)
        return np.where(s > 0, (a * t).sum(-1) / np.where(s > 0, s, 1), np.nan)

    ref_t = arrival(ref)
    best = None
    for flip_x, flip_y, swap in itertools.product((False, True), repeat=3):
        a = rendered
        if swap:
            if nx != ny:
                continue
            a = a.transpose(0, 2, 1, 3)
        a = a[:, ::-1] if flip_x else a
        a = a[:, :, ::-1] if flip_y else a
        a = a.reshape(len(a), nx * ny, BINS)
        mis = float(np.sqrt(np.nanmean((arrival(a) - ref_t) ** 2)))
        if best is None or mis < best[2]:
            best = (a, {"flip_x": flip_x, "flip_y": flip_y, "swap": swap}, mis)
    return best


def _shape(a, b) -> float:
    a, b = np.asarray(a, float) / np.sum(a), np.asarray(b, float) / np.sum(b)
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def main(argv=None) -> list[dict] | None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=512, help="samples per sensor pixel")
    ap.add_argument("--cell", type=float, default=0.02, help="face cell (m)")
    ap.add_argument("--libllvm", default=None, help="the libLLVM (>= 16) Dr.Jit should load "
                    "(sets DRJIT_LIBLLVM_PATH; default: the one it finds)")
    ap.add_argument("--device", default=None)
    args = ap.parse_args(argv)
    if args.libllvm:
        os.environ["DRJIT_LIBLLVM_PATH"] = args.libllvm
    mods, why = _import_mitsuba()
    if mods is None:
        print(f"mitransient_check: skipped: {why}")
        return None
    from clnlos.bench.harness import print_table, write_rows
    from clnlos.forward.model import ForwardModel
    from clnlos.forward.sampling import sample_scene
    from clnlos.runtime.device import get_queue

    q = get_queue(args.device)
    xs, ys = face_cells(args.cell)
    cells = np.array([(x, y) for x in xs for y in ys])
    materials = {"lambertian": "lambertian", "ggx": {"model": "microfacet", **GGX}}
    rows, K = [], None
    for kind, material in materials.items():
        scene = patch_scene(material)
        smp = sample_scene(scene)
        t0 = time.perf_counter()
        ref = grid_hidden(smp.elements, smp.albedo, cells, kind)
        t_grid = time.perf_counter() - t0
        t0 = time.perf_counter()
        rendered = render_hidden(mods, scene, cells, xs, ys, args.cell, kind, args.spp,
                                 print)
        t_mitr = time.perf_counter() - t0
        mit, orientation, mismatch = orient(rendered, ref, len(xs), len(ys))
        if K is None:  # the renderer's units -> clnlos', from the Lambertian patch
            K = float(ref.sum() / mit.sum())
        mit = mit * K
        hidden_total, hidden_shape = float(mit.sum() / ref.sum()), _shape(mit, ref)
        bis = ForwardModel(patch_scene(material, {"model": "bistatic"}), queue=q).run()
        # the confocal model at a 5 mm pitch (its slab blur runs on the scan grid)
        fine = patch_scene(material, width_m=0.205, points=41)
        conf = ForwardModel(fine, queue=q).run()
        fine_c = fine.scan_centres()
        pts = scene.points
        row_y = pts // 2
        centres = scene.scan_centres()
        for r0x in SCAN_X:
            col = int(np.argmin(np.abs(centres - r0x)))
            m = cell_masses(scene.slab, xs, ys, args.cell, r0x, q)
            tau_m, tau_g = add_slab(mit, m), add_slab(ref, m)
            tau_c = bis[:, row_y, col].astype(float)
            fc = int(np.argmin(np.abs(fine_c - r0x)))
            tau_conf = conf[:, fine.points // 2, fc].astype(float)
            rows.append({
                "material": kind, "scan_x_m": float(centres[col]),
                "mitransient_over_grid": float(tau_m.sum() / tau_g.sum()),
                "shape_mitransient_vs_grid": _shape(tau_m, tau_g),
                "mitransient_over_clnlos": float(tau_m.sum() / tau_c.sum()),
                "shape_mitransient_vs_clnlos": _shape(tau_m, tau_c),
                "grid_over_clnlos": float(tau_g.sum() / tau_c.sum()),
                "shape_grid_vs_clnlos": _shape(tau_g, tau_c),
                "confocal_over_clnlos": float(tau_conf.sum() / tau_c.sum()),
                "hidden_total_ratio": hidden_total, "hidden_shape": hidden_shape,
                "slab_mass_in_grid": float(m.sum() / cell_masses(
                    scene.slab, np.arange(-0.5, 0.5, args.cell) + args.cell / 2,
                    np.arange(-0.5, 0.5, args.cell) + args.cell / 2, args.cell, r0x,
                    q).sum()),
                "K": K, "orientation": str(orientation), "arrival_mismatch_bins": mismatch,
                "cells": len(cells), "spp": args.spp, "cell_m": args.cell,
                "seconds_mitransient": t_mitr, "seconds_grid": t_grid})
    cols = ["material", "scan_x_m", "mitransient_over_grid", "shape_mitransient_vs_grid",
            "mitransient_over_clnlos", "shape_mitransient_vs_clnlos", "grid_over_clnlos",
            "shape_grid_vs_clnlos", "confocal_over_clnlos", "hidden_shape"]
    print_table(rows, cols)
    csv_path, json_path = write_rows(rows, OUT, "mitransient_check")
    print(f"wrote {csv_path} and {json_path}")
    return rows


if __name__ == "__main__":
    sys.exit(0 if main() is not None or True else 1)
