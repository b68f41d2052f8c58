"""The BRDF-aware light-cone transport and inversion measured: the operator against
``clnlos simulate`` of the same scene (the section ``brdf_operator`` and
tools/brdf_operator_check.py) and the inversion's cost and reading against the Lambertian
one on the same captures (the section ``brdf_inversion``).

The operator check renders a glyph with the forward model (no pulse, no noise) and applies
the BRDF-aware transport (:mod:`clnlos.forward.transport`) to the scene's own surface,
voxelised: each surface element's albedo times its area over the cell area, in the depth bin
and scan cell of its centre. A tilted glyph of a lobe narrower than FOOT_LOBE_DEG is
voxelised where a confocal scan sees the lobe put it: each element moved along its normal to
the scan plane, (x + z tan(tilt), z / cos(tilt)) for a tilt about y (the inversion assumes
voxels facing the scan plane); a wider lobe where it is. Behind a slab the transport's
output, on a grid widened by the blur's reach, goes through the confocal slab blur Phi * Phi
(:mod:`clnlos.forward.blur`); against the bistatic transport (the seed's Eq. 8 in full) this
measures whether the slab footprint folded into the lobe (:mod:`clnlos.physics.lobe`) stands
in for the light leaving and entering the slab at different points. Errors: relative L2 of
the time-integrated image and of the transient, after the best common scale (the
voxelisation's albedo convention).
"""

from __future__ import annotations

import math
import time

import numpy as np
import pyopencl.array as cla

from clnlos.physics.constants import C0
from clnlos.bench.harness import timed_once
from clnlos.brdf.lobes import AUTO, LAMBERTIAN, ladder_lobe, retro_lobe
from clnlos.config import ReconstructionConfig
from clnlos.forward.bistatic import face_quadrature
from clnlos.forward.blur import blur_margin, slab_blur
from clnlos.forward.model import ForwardModel
from clnlos.forward.scene import Scene
from clnlos.forward.transport import LightConeTransport
from clnlos.inverse.iterative import IterativeInversion
from clnlos.inverse.pipeline import reconstruct
from clnlos.physics.slab import CDT_SLAB
from clnlos.runtime.device import has_fp64
from clnlos.runtime.fft import RealFFT3
from clnlos.study.score.metrics import mip_iou, truth_mask

CHECK_MATERIALS = ("quartz glass", "aluminium alloy sample", "gold-plated polyester film",
                   "standard white plate", LAMBERTIAN)
CHECK_TILTS_DEG = (0.0, 10.0)
FOOT_LOBE_DEG = 20.0  # a tilted target of a lobe narrower than this is voxelised at its foot


def glyph_scene(material: str, **kw) -> Scene:
    """A glyph of one material facing the scan (or tilted about y), no pulse, no noise
    (:func:`glyph_scene_dict`)."""
    return Scene.from_dict(glyph_scene_dict(material, **kw))


def glyph_scene_dict(material: str, *, tilt_deg: float = 0.0, slab: bool = False,
                     transport: str = "confocal", points: int = 32,
                     scan_width_m: float = 0.6, bin_width_s: float = 48e-12, bins: int = 256,
                     glyph: str = "E", height_m: float = 0.3, stroke_m: float = 0.08,
                     depth_m: float = 0.5, density_per_m2: float = 4e4) -> dict:
    """The scene table of :func:`glyph_scene`."""
    d = {"seed": 0, "scan": {"width_m": scan_width_m, "points": points},
         "time": {"bin_width_s": bin_width_s, "bins": bins, "start_s": 0.0},
         "objects": [{"shape": "letters", "text": glyph, "height_m": height_m,
                      "stroke_m": stroke_m, "translate_m": [0.0, 0.0, depth_m],
                      "rotate_deg": [0.0, float(tilt_deg), 0.0], "material": material,
                      "albedo": 1.0}],
         "sampling": {"density_per_m2": density_per_m2, "splat_order": 1},
         "transport": {"model": transport}}
    if slab:
        d["slab"] = {"thickness_m": CDT_SLAB.thickness_m, "mu_a": CDT_SLAB.mu_a,
                     "mu_s_prime": CDT_SLAB.mu_s_prime, "n": CDT_SLAB.n}
    return d


def voxelised(samples, scene: Scene, *, lobe_foot: bool) -> np.ndarray:
    """The scene's surface as albedo-weighted coverage [z, y, x] on the scan grid (depth bins
    of c dt / 2); with ``lobe_foot`` each element is placed at the scan point its normal
    meets, at its distance from it (where a sharp lobe puts its light)."""
    el = samples.elements
    pos, nrm = np.asarray(el.pos, float), np.asarray(el.normal, float)
    if lobe_foot:
        # the scan point the element's normal points at (normals face the scan plane: n_z < 0)
        s = -pos[:, 2] / nrm[:, 2]
        foot = pos + s[:, None] * nrm
        r = np.linalg.norm(pos - foot, axis=1)
        pos = np.column_stack([foot[:, 0], foot[:, 1], r])
    n = scene.points
    pitch = scene.width_m / n
    dz = C0 * scene.bin_width_s / 2
    ix = np.floor((pos[:, 0] + scene.width_m / 2) / pitch).astype(int)
    iy = np.floor((pos[:, 1] + scene.width_m / 2) / pitch).astype(int)
    iz = np.floor(pos[:, 2] / dz).astype(int)
    ok = (ix >= 0) & (ix < n) & (iy >= 0) & (iy < n) & (iz >= 0) & (iz < scene.bins)
    vol = np.zeros((scene.bins, n, n))
    np.add.at(vol, (iz[ok], iy[ok], ix[ok]), (samples.albedo * el.area)[ok] / pitch**2)
    return vol


def _scaled_errors(pred: np.ndarray, ref: np.ndarray) -> tuple[float, float]:
    """(relative L2 of the time-integrated images, of the transients) after the scale that
    fits the transient best."""
    p, r = pred.astype(np.float64), ref.astype(np.float64)
    a = float((p * r).sum() / max((p * p).sum(), 1e-300))
    ip, ir = a * p.sum(0), r.sum(0)
    return (float(np.linalg.norm(ip - ir) / max(np.linalg.norm(ir), 1e-300)),
            float(np.linalg.norm(a * p - r) / max(np.linalg.norm(r), 1e-300)))


def operator_check(material: str, *, tilt_deg: float, slab: bool, transport: str,
                   queue, points: int = 32) -> list[dict]:
    """Rows: the scene rendered by ``clnlos simulate``'s forward model against the transport
    with the Lambertian lobe and with the material's (and, behind a slab, the material's
    without the footprint), each on the voxelised scene, in the most precise dtype the
    device has (float64, else float32)."""
    scene = glyph_scene(material, tilt_deg=tilt_deg, slab=slab, transport=transport,
                        points=points)
    dtype = np.float64 if has_fp64(queue.device) else np.float32
    fm = ForwardModel(scene, queue=queue, dtype=dtype)
    ref = fm.run()
    pitch = scene.width_m / scene.points
    margin, blur = 0, None
    if slab:
        margin, _ = blur_margin(scene.slab, scene.bins * scene.bin_width_s, pitch,
                                scene.points, 1e-3, None, queue)
        nw = scene.points + 2 * margin
        blur = slab_blur(scene.slab, (scene.bins, nw, nw), bin_width_s=scene.bin_width_s,
                         pitch_m=pitch, mode="convolve", dtype=dtype, queue=queue)
    rms = (face_quadrature(scene.slab, bins=scene.bins, bin_width_s=scene.bin_width_s,
                           rings=1, angles=1, queue=queue).rms_m if slab else 0.0)
    lobe = retro_lobe(material)
    sharp = lobe.halfwidth_rad() < math.radians(FOOT_LOBE_DEG)
    vol = voxelised(fm.samples, scene, lobe_foot=tilt_deg != 0 and sharp)
    models = [(LAMBERTIAN, 0.0)]
    if material != LAMBERTIAN:
        models += [(material, rms)] + ([(material, 0.0)] if slab else [])
    rows = []
    for lobe_name, fp in models:
        t0 = time.perf_counter()
        op = LightConeTransport(vol.shape, bin_width_s=scene.bin_width_s,
                                scan_width_m=scene.width_m, margin=margin, depth_min_m=0.2,
                                dtype=dtype, queue=queue, lobe=retro_lobe(lobe_name),
                                footprint_rms_m=fp)
        build = time.perf_counter() - t0
        pred = op(np.asarray(vol, dtype))
        if blur is not None:
            pred = blur(pred)
        if margin:
            pred = pred[:, margin:-margin, margin:-margin]
        e_img, e_tr = _scaled_errors(pred, ref)
        rows.append({"material": material, "tilt_deg": tilt_deg,
                     "slab": "CDT" if slab else "none", "transport": transport,
                     "model_lobe": lobe_name, "footprint_rms_m": fp, "terms": op.lobe.terms,
                     "terms_error": op.lobe.errors[op.lobe.terms - 1],
                     "rel_l2_image": e_img, "rel_l2_transient": e_tr,
                     "build_s": build})
    return rows


def operator_check_rows(queue, *, materials=CHECK_MATERIALS, tilts=CHECK_TILTS_DEG,
                        points: int = 32, progress=None) -> list[dict]:
    """:func:`operator_check` for every material and tilt: without a slab (confocal
    transport), and behind the CDT slab under the confocal (Eq. 9) and the bistatic
    (Eq. 8) transports."""
    rows = []
    cases = [(m, t, s, tr) for m in materials for t in tilts
             for s, tr in ((False, "confocal"), (True, "confocal"), (True, "bistatic"))]
    for k, (m, t, s, tr) in enumerate(cases):
        if progress is not None:
            progress(k, len(cases), f"{m}, {t:g} deg, {tr}{' + slab' if s else ''}")
        rows += operator_check(m, tilt_deg=t, slab=s, transport=tr, queue=queue,
                               points=points)
    return rows





INVERSION_MATERIALS = ("quartz glass", "gold-plated polyester film", "standard white plate")
INVERSION_TERMS = (1, 2, 4, "auto")  # K of the known lobe's separable sum
INVERSION_EXPOSURE_S = 0.1           # the study's default exposure
INVERSION_MAX_PATH_M = 1.6           # the study's reconstruction window (round trip), m
INVERSION_BINS = 150                 # 2.16 m of path at 48 ps: the window and guard bins


def noisy_glyph_capture(material: str, points: int, queue, *, glyph: str = "E"):
    """(capture, true mask [y, x]) of a glyph at the study's legible geometry (0.6 m scan,
    30 cm tall, 8 cm strokes, 0.5 m deep) behind the CDT slab, with the study's 35 ps pulse,
    detector (etendue 1e-9 m^2 sr, 1 kHz dark counts) and photon noise."""
    d = glyph_scene_dict(material, slab=True, points=points, glyph=glyph,
                         bins=INVERSION_BINS)
    d["laser"] = {"pulse_width_s": 35e-12}
    d["detector"] = {"exposure_s": INVERSION_EXPOSURE_S, "etendue_m2_sr": 1e-9,
                     "dark_count_rate_hz": 1000.0}
    scene = Scene.from_dict(d)
    fm = ForwardModel(scene, queue=queue)
    return fm.capture(), truth_mask(fm.samples.elements, scene.scan_centres())


def inversion_rows(b) -> None:
    """Section ``brdf_inversion``: on the same noisy capture per material, the iterative
    method with the Lambertian lobe, the known lobe at K = INVERSION_TERMS separable terms
    and ``brdf = "auto"``: time (one run after a run that built the plans), 1 - IoU of the
    MIP against the truth, K and its relative error, the ratio to the Lambertian time."""
    points = {"tiny": 12, "quick": 24, "full": 32}[b.size]
    iterations = {"tiny": 10, "quick": 30, "full": None}[b.size]
    for material in INVERSION_MATERIALS[:1] if b.size == "tiny" else INVERSION_MATERIALS:
        cap, mask = noisy_glyph_capture(material, points, b.q)
        budget = {} if iterations is None else {"iterations": iterations}
        base = ReconstructionConfig(slab=cap.recorded_slab()[0], method="iterative",
                                    snr_rule="gcv", max_path_m=INVERSION_MAX_PATH_M, **budget)
        terms = ("auto",) if b.size == "tiny" else INVERSION_TERMS
        runs = [("lambertian", {})] + [(f"known K={k}", {"brdf": material, "brdf_terms": k})
                                       for k in terms] + [("auto", {"brdf": AUTO})]
        lam_s = None
        for name, fields in runs:
            cfg = base.replace(**fields).validate()
            if b.size != "tiny":  # plans built first: the row times the reconstruction
                reconstruct(cap, cfg, device=b.q)
            rec, timing = timed_once(lambda cfg=cfg, cap=cap: reconstruct(cap, cfg, device=b.q),
                                     b.q)
            lam_s = timing["median_s"] if lam_s is None else lam_s
            iou = mip_iou(rec.volume, mask)[0]
            b.record("brdf_inversion", f"iterative@{material}", name, np.float32, timing,
                     1.0 - iou, error_kind="1 - IoU", material=material, iou=iou,
                     brdf_used=rec.params.get("brdf_used"),
                     terms=rec.params.get("brdf_terms_used"),
                     terms_error=rec.params.get("brdf_terms_error"),
                     time_over_lambertian=timing["median_s"] / lam_s)


def operator_rows(b) -> None:
    """Section ``brdf_operator``: :func:`operator_check_rows` (the transport against
    ``clnlos simulate``), its error as the row's error, the transport's build as its time."""
    if b.size == "tiny":  # one case: quartz glass facing the scan behind the slab
        rows = operator_check("quartz glass", tilt_deg=0.0, slab=True, transport="confocal",
                              queue=b.q, points=12)
    else:
        rows = operator_check_rows(b.q, points={"quick": 24, "full": 32}[b.size])
    for r in rows:
        t = r.pop("build_s")
        b.record("brdf_operator", f"{r['material']}@{r['tilt_deg']:g}deg/{r['transport']}"
                 f"{'+slab' if r['slab'] != 'none' else ''}", r["model_lobe"], b.dtypes[-1],
                 {"median_s": t, "min_s": t, "max_s": t, "repeats": 1}, r["rel_l2_image"],
                 error_kind="rel L2 (time-integrated image)", **r)


ITERATION_LOBES = ("retroreflective", "glossy-paint", "quartz glass", "ggx alpha 0.1")
ITERATION_TERMS = (1, 2, 3, 4)  # K whose per-iteration cost and operator error are rows
REFERENCE_TERMS = 8             # the operator the terms' errors are measured against


def iteration_capture(queue, points: int, bins: int, bin_width_s: float):
    """A capture like the LCT release read by clnlos (no slab, photon counts, a 0.8 m scan,
    a glyph 0.6 m deep): the grid of the section ``brdf_iteration``."""
    d = glyph_scene_dict("lambertian", points=points, bins=bins, bin_width_s=bin_width_s,
                         scan_width_m=0.8, depth_m=0.6, glyph="S", height_m=0.4,
                         density_per_m2=1e4)
    d["detector"] = {"exposure_s": 0.5, "etendue_m2_sr": 1e-9, "dark_count_rate_hz": 1e3}
    return ForwardModel(Scene.from_dict(d), queue=queue).capture()


SOLVE_ROUNDS = 2  # interleaved rounds of the solves (the least of each kept): minutes each


def interleaved(fns: dict, queue, rounds: int) -> dict:
    """{name: timing} of each callable run once per round, all of them in turn each round
    (the machine's load falls on every one alike), warmed up first: the least time of the
    rounds as ``min_s``, their median as ``median_s``."""
    for fn in fns.values():
        fn()
    queue.finish()
    times: dict = {k: [] for k in fns}
    for _ in range(max(1, rounds)):
        for k, fn in fns.items():
            queue.finish()
            t0 = time.perf_counter()
            fn()
            queue.finish()
            times[k].append(time.perf_counter() - t0)
    return {k: {"median_s": float(np.median(v)), "min_s": min(v), "max_s": max(v),
                "repeats": len(v)} for k, v in times.items()}


def iteration_rows(b) -> None:
    """Section ``brdf_iteration`` (issue 59): per lobe, on one capture (64 x 64 x 512 at
    ``full``), the iterative method's cost against its Lambertian one and the FFT floor: one
    iteration's transforms (the operator and its adjoint, K the inversion takes) in time, x
    Lambertian and FFT pairs (one r2c + c2r of the operator's padded grid, unpruned), for K =
    ITERATION_TERMS too with what those terms buy (the relative L2 of L_K rho against
    REFERENCE_TERMS terms on the inversion's own volume rho); one solve (reconstruct, plans
    built: time, x Lambertian, iterations, K). The operators are timed interleaved
    (:func:`interleaved`: the least of ``b.repeat`` rounds), the solves likewise over
    SOLVE_ROUNDS rounds; ratios are of those least times."""
    points, bins, bw = {"tiny": (16, 128, 64e-12), "quick": (32, 256, 32e-12),
                        "full": (64, 512, 16e-12)}[b.size]
    cap = iteration_capture(b.q, points, bins, bw)
    grid = f"{points}x{points}x{bins}"
    names = (LAMBERTIAN,) + (ITERATION_LOBES[:1] if b.size == "tiny" else ITERATION_LOBES)
    configs = {n: ReconstructionConfig(method="iterative", brdf=n).validate()
               for n in names if not n.startswith("ggx")}  # a ladder lobe is no --brdf spec
    recs = {n: reconstruct(cap, c, device=b.q) for n, c in configs.items()}  # plans built
    base = recs[LAMBERTIAN]
    plan = IterativeInversion(base.volume.shape, bin_width_s=base.bin_width_s,
                              scan_width_m=base.scan_width_m, iterations=1, l1_weight=0.1,
                              tv_weight=0.0, queue=b.q, falloff=base.params["falloff_used"])
    depth_min = base.solver["depth_min_m"]
    fft = RealFFT3(plan.transport(depth_min).pad_shape, np.float32, b.q)
    buf, spec = cla.zeros(b.q, fft.shape, np.float32), fft.empty_spectrum()
    ops, errors, xs = {}, {}, {}
    for name in names:
        plan.set_lobe(ladder_lobe(0.1) if name.startswith("ggx") else retro_lobe(name))
        vol = recs.get(name, base).volume
        x = cla.to_device(b.q, (vol / plan.scale[:, None, None]).astype(np.float32))
        ops[name] = plan.transport(depth_min)
        xs[name] = x
        if name == LAMBERTIAN or b.size == "tiny":
            continue
        y_ref = plan.transport(depth_min, REFERENCE_TERMS).apply_device(x).get()
        for k in ITERATION_TERMS:
            opk = ops[f"{name} K={k}"] = plan.transport(depth_min, k)
            xs[f"{name} K={k}"] = x
            errors[f"{name} K={k}"] = float(np.linalg.norm(opk.apply_device(x).get() - y_ref)
                                            / max(float(np.linalg.norm(y_ref)), 1e-300))
    fns = {k: (lambda op=op, x=xs[k]: op.adjoint_device(op.apply_device(x)))
           for k, op in ops.items()}
    fns["fft pair"] = lambda: fft.inverse(fft.forward(buf, spec), buf)
    t = interleaved(fns, b.q, b.repeat)
    pair, lam = t.pop("fft pair")["min_s"], t[LAMBERTIAN]["min_s"]
    buf = spec = fft = None  # the FFT pair's buffers freed before the solves
    solves = interleaved({n: (lambda c=c: reconstruct(cap, c, device=b.q))
                          for n, c in configs.items()}, b.q,
                         1 if b.size == "tiny" else SOLVE_ROUNDS)
    for key, timing in t.items():
        op = ops[key]
        name, _, k = key.partition(" K=")
        row = dict(terms=op.lobe.terms, time_over_lambertian=timing["min_s"] / lam,
                   fft_pair_s=pair, fft_pairs=timing["min_s"] / pair)
        if k:
            b.record("brdf_iteration", f"terms@{grid}", key, np.float32, timing, errors[key],
                     error_kind=f"rel L2 of L_K rho against K={REFERENCE_TERMS}",
                     terms_error=op.lobe.errors[op.lobe.terms - 1], **row)
        else:
            b.record("brdf_iteration", f"iteration@{grid}", name, np.float32, timing,
                     op.lobe.errors[op.lobe.terms - 1], error_kind="separable terms' error",
                     **row)
    lam_solve = solves[LAMBERTIAN]["min_s"]
    for name, timing in solves.items():
        rec = recs[name]
        b.record("brdf_iteration", f"solve@{grid}", name, np.float32, timing, None,
                 terms=rec.params.get("brdf_terms_used"),
                 iterations=(rec.solver or {}).get("iterations"),
                 time_over_lambertian=timing["min_s"] / lam_solve, fft_pair_s=pair,
                 fft_pairs=timing["min_s"] / pair)
