"""The BRDF-aware light-cone transport: the lobe physics (:mod:`clnlos.physics.lobe`) against
closed forms and brute-force quadrature, its separable terms, the operator against the
forward light-cone kernel (an independent element-wise renderer), its adjoint, and the
``brdf`` spec of a reconstruction."""

import dataclasses
import json
import math

import numpy as np
import pytest

from clnlos import C0
from clnlos.brdf.catalog import check_brdf_spec
from clnlos.brdf.lobes import auto_ladder, retro_lobe
from clnlos.brdf.models import BRDFModel, retro_slice
from clnlos.brdf.texture import tabulate, write_texture
from clnlos.config import ReconstructionConfig
from clnlos.errors import InputFileError, ParameterError
from clnlos.forward.geometry import Elements
from clnlos.forward.lightcone import LightCone
from clnlos.forward.sampling import N_THETA, SurfaceSamples
from clnlos.forward.transport import LightConeTransport
from clnlos.inverse.brdf_choice import both_margins, choose_lobe, score_margin, surface_of
from clnlos.operators.base import dot_test
from clnlos.physics.lobe import (
    THETA_NODES,
    RetroLobe,
    cell_average,
    footprint_average,
    lobe_weight_table,
    separable_terms,
)

GOLD = BRDFModel("microfacet", {"kd": 0.018, "ks": 0.16, "alpha": 0.135, "f0": 1.0})
ALLOY = BRDFModel("microfacet", {"kd": 0.009, "ks": 0.10, "alpha": 0.035, "f0": 1.0})


def _lobe(model, name="test"):
    return RetroLobe.from_samples(retro_slice(model, THETA_NODES), name)


# ------------------------------------------------------------------ the lobe physics
@pytest.mark.parametrize("a_deg,s_deg", [(0.5, 2.0), (2.0, 2.0), (4.0, 1.0)])
def test_footprint_average_of_a_gaussian_lobe_is_the_closed_form(a_deg, s_deg):
    """A Gaussian lobe exp(-theta^2 / (2 a^2)) averaged over a 2D Gaussian of per-axis
    variance s^2 (rms angle sigma = sqrt(2) s) is a^2 / (a^2 + s^2) exp(-theta^2 /
    (2 (a^2 + s^2))) on the tangent plane: within 1e-3 of the peak (float64)."""
    a, s = math.radians(a_deg), math.radians(s_deg)
    th = np.linspace(0, np.pi / 2, THETA_NODES)
    f = np.exp(-th**2 / (2 * a * a))
    got = footprint_average(f, math.sqrt(2) * s)
    want = a * a / (a * a + s * s) * np.exp(-th**2 / (2 * (a * a + s * s)))
    near = th < math.radians(20)  # the tangent plane holds near the lobe
    assert np.abs(got - want)[near].max() < 1e-3


def test_footprint_average_keeps_a_flat_lobe():
    f = np.full(THETA_NODES, 1 / np.pi)
    assert np.allclose(footprint_average(f, 0.05)[: THETA_NODES // 2], 1 / np.pi, rtol=1e-9)


def test_cell_average_matches_dense_quadrature():
    """Eq. (1) on a cell in front of the scan point and one beside it, for a lobe narrower
    than the cell, against a dense 400 x 400 midpoint rule: within 0.5%."""
    lobe = _lobe(ALLOY)
    th, f = lobe.theta, lobe.f
    z, p = 0.5, 0.02
    for oy, ox in ((0.0, 0.0), (0.0, p)):
        got = cell_average(th, f, np.array([oy]), np.array([ox]), z, p, 24)[0]
        u = ((np.arange(400) + 0.5) / 400 - 0.5) * p
        Y, X = np.meshgrid(oy + u, ox + u, indexing="ij")
        r2 = X * X + Y * Y + z * z
        w = 1 / r2**4
        ref = np.pi * np.sum(np.interp(np.arctan(np.sqrt(X * X + Y * Y) / z), th, f) * w) \
            / np.sum(w)
        assert got == pytest.approx(ref, rel=5e-3)


def test_weight_table_lambertian_is_one_and_a_lobe_peaks_in_front():
    z = np.linspace(0.3, 0.8, 20)
    assert np.array_equal(lobe_weight_table(RetroLobe.lambert(), z, 0.02, (5, 5)),
                          np.ones((20, 5, 5)))
    G = lobe_weight_table(_lobe(GOLD), z, 0.02, (8, 8), footprint_rms_m=0.025)
    assert np.all(G[:, 0, 0] > G[:, 0, 4]) and np.all(G[:, 0, 0] > G[:, 4, 4])
    assert np.all(np.isfinite(G)) and G.min() >= 0
    # the footprint widens the lobe: a lower peak, a larger second moment over the offsets
    G0 = lobe_weight_table(_lobe(GOLD), z, 0.02, (8, 8))
    d2 = np.add.outer(np.arange(8) ** 2, np.arange(8) ** 2)
    assert np.all(G[:, 0, 0] < G0[:, 0, 0])
    assert np.all((G * d2).sum((1, 2)) / G.sum((1, 2)) > (G0 * d2).sum((1, 2)) / G0.sum((1, 2)))


def test_separable_terms_converge_and_a_lambertian_needs_one():
    z = (np.arange(40, 120) + 0.5) * 0.0072
    G = lobe_weight_table(_lobe(GOLD), z, 0.0187, (17, 17), footprint_rms_m=0.025)
    sep = separable_terms(G, z, 0.0187)
    err = np.asarray(sep.errors)
    assert np.all(np.diff(err[:6]) < 0)  # each term lowers the error
    assert sep.errors[sep.terms - 1] <= 1e-3 and sep.terms <= 6
    approx = np.einsum("kz,kyx->zyx", sep.a, sep.b)
    assert np.abs(approx - G).max() < 0.02 * G.max()
    one = separable_terms(np.full((10, 4, 4), 0.35), np.linspace(0.3, 0.7, 10), 0.02)
    assert one.terms == 1 and np.allclose(np.einsum("kz,kyx->zyx", one.a, one.b), 0.35)


def test_leading_svd_is_the_full_svd_truncated():
    """The truncated SVD of the separable terms against numpy's full SVD: the leading
    singular values and the rank-k reconstructions agree (a smooth table like the lobes' and
    a random one); a k near the smaller side takes the full SVD."""
    from clnlos.physics.lobe import leading_svd
    rng = np.random.default_rng(3)
    z = np.linspace(0.2, 2.0, 300)[:, None]
    d = np.linspace(0.0, 1.0, 400)[None, :]
    smooth = (z / np.hypot(z, d)) ** 8 * (1 + 0.3 * np.cos(7 * d * z))
    for A in (smooth, rng.standard_normal((300, 400))):
        U0, S0, V0 = np.linalg.svd(A, full_matrices=False)
        U, S, Vt = leading_svd(A, 12)
        assert U.shape == (300, 12) and Vt.shape == (12, 400)
        assert np.allclose(S, S0[:12], rtol=1e-9, atol=1e-12 * S0[0])
        for k in (1, 5, 12):
            ref = (U0[:, :k] * S0[:k]) @ V0[:k]
            assert np.abs((U[:, :k] * S[:k]) @ Vt[:k] - ref).max() < 1e-8 * np.abs(A).max()
    U, S, Vt = leading_svd(rng.standard_normal((6, 9)), 12)
    assert S.size == 6 and np.all(np.diff(S) <= 0)
    U, S, Vt = leading_svd(np.zeros((300, 400)), 12)  # ARPACK cannot start: the full SVD
    assert U.shape == (300, 12) and np.all(S == 0)


def test_leading_svd_falls_back_where_arpack_does_not_converge(monkeypatch):
    import clnlos.physics.lobe as lobe_mod
    from scipy.sparse.linalg import ArpackNoConvergence

    def fails(*a, **kw):
        raise ArpackNoConvergence("no convergence", np.zeros(0), np.zeros((0, 0)))

    A = np.random.default_rng(5).standard_normal((200, 300))
    monkeypatch.setattr(lobe_mod, "svds", fails)
    U, S, Vt = lobe_mod.leading_svd(A, 12)
    assert np.allclose(S, np.linalg.svd(A, compute_uv=False)[:12])


def test_auto_ladder_builds_a_lobe_only_when_reached(monkeypatch):
    import clnlos.brdf.lobes as lobes
    built = []
    monkeypatch.setattr(lobes, "ladder_lobe",
                        lambda a: built.append(a) or RetroLobe.lambert())
    ladder = lobes.auto_ladder()
    assert len(ladder) == 1 + len(lobes.AUTO_ALPHAS) and built == []
    assert ladder[0] is ladder[0] and ladder[0].lambertian and built == []
    ladder[1]
    assert built == [max(lobes.AUTO_ALPHAS)]
    assert len(ladder[:2]) == 2 and len(ladder + [ladder[0]]) == len(ladder) + 1
    with pytest.raises(IndexError):
        ladder[len(ladder)]


# ------------------------------------------------------------------ the operator
def _scene(nt=120, n=8, seed=1):
    rng = np.random.default_rng(seed)
    vol = np.zeros((nt, n, n))
    k, j, i = (rng.integers(int(0.5 * nt), int(0.8 * nt), 12), rng.integers(0, n, 12),
               rng.integers(0, n, 12))
    vol[k, j, i] = rng.uniform(0.2, 1, 12)
    return vol


def _render(queue, vol, model, *, bw, w, margin, sub=16):
    """Voxels as sub x sub surface elements facing the scan plane through the forward
    light-cone kernel with the model's retro table (the element-wise renderer of
    ``clnlos simulate``)."""
    nt, n, _ = vol.shape
    dz, pitch = C0 * bw / 2, w / n
    kk, jj, ii = np.nonzero(vol)
    u = ((np.arange(sub) + 0.5) / sub - 0.5) * pitch
    uy, ux = (a.ravel() for a in np.meshgrid(u, u, indexing="ij"))
    pos = np.concatenate([np.column_stack([(ii + 0.5) * pitch - w / 2 + dx,
                                           (jj + 0.5) * pitch - w / 2 + dy, (kk + 0.5) * dz])
                          for dy, dx in zip(uy, ux, strict=True)])
    el = Elements(pos, np.tile([0, 0, -1.0], (len(pos), 1)), np.full(len(pos), (pitch / sub) ** 2))
    nw = n + 2 * margin
    lc = LightCone(points=nw, width_m=nw * pitch, bins=nt, bin_width_s=bw, start_s=0.0,
                   retro=True, dtype=np.float64, queue=queue)
    table = retro_slice(model, N_THETA)[None, :]
    return lc(SurfaceSamples(el, np.tile(vol[kk, jj, ii], sub * sub),
                             np.zeros(len(pos), np.int32), table)).get()


@pytest.mark.parametrize("model", [GOLD, ALLOY], ids=["gold", "alloy"])
@pytest.mark.fp64
def test_lobe_transport_matches_the_forward_kernel(queue, model):
    """Per scan point the time-integrated signal within 2% of the peak and the time centroid
    within 0.25 bins of the element-wise renderer (the operator splats in v = r^2, the
    renderer in t), with the lobe in K separable terms."""
    bw, w, margin = 30e-12, 0.3, 2
    vol = _scene()
    op = LightConeTransport(vol.shape, bin_width_s=bw, scan_width_m=w, margin=margin,
                            depth_min_m=0.2, dtype=np.float64, queue=queue,
                            lobe=_lobe(model))
    assert 2 <= op.lobe.terms <= 6
    out = op(vol)
    ref = _render(queue, vol, model, bw=bw, w=w, margin=margin)
    s_ref, s_out = ref.sum(0), out.sum(0)
    assert np.abs(s_out - s_ref).max() < 0.02 * s_ref.max()
    t = np.arange(vol.shape[0]) + 0.5
    lit = s_ref > 0.05 * s_ref.max()
    c_ref = (ref * t[:, None, None]).sum(0)[lit] / s_ref[lit]
    c_out = (out * t[:, None, None]).sum(0)[lit] / s_out[lit]
    assert np.abs(c_out - c_ref).max() < 0.25


@pytest.mark.parametrize("dtype,tol", [pytest.param(np.float64, 1e-12, marks=pytest.mark.fp64),
                                       (np.float32, 1e-5)])
def test_lobe_transport_adjoint(queue, dtype, tol):
    op = LightConeTransport((60, 5, 4), bin_width_s=40e-12, scan_width_m=0.2, margin=1,
                            depth_min_m=0.15, dtype=dtype, queue=queue, lobe=_lobe(GOLD),
                            footprint_rms_m=0.025)
    assert op.lobe.terms > 1
    assert dot_test(op, np.random.default_rng(3)) < tol


@pytest.mark.fp64
def test_lambertian_lobe_is_the_lambertian_operator(queue):
    vol = _scene(nt=80, n=6)
    kw = dict(bin_width_s=40e-12, scan_width_m=0.25, margin=1, depth_min_m=0.2,
              dtype=np.float64, queue=queue)
    a = LightConeTransport(vol.shape, **kw)(vol)
    b = LightConeTransport(vol.shape, lobe=RetroLobe.lambert(), footprint_rms_m=0.03,
                           **kw)(vol)
    assert np.array_equal(a, b)


@pytest.mark.fp64
def test_more_terms_approach_the_full_lobe(queue):
    """The operator's error against its own K = 10 form falls with K (the bench reports it)."""
    vol = _scene(nt=100, n=8, seed=4)
    kw = dict(bin_width_s=30e-12, scan_width_m=0.3, depth_min_m=0.2, dtype=np.float64,
              queue=queue, lobe=_lobe(GOLD), footprint_rms_m=0.025)
    ref = LightConeTransport(vol.shape, lobe_terms=10, **kw)(vol)
    errs = [np.linalg.norm(LightConeTransport(vol.shape, lobe_terms=k, **kw)(vol) - ref)
            / np.linalg.norm(ref) for k in (1, 2, 4)]
    assert errs[0] > errs[1] > errs[2] and errs[2] < 0.01


# ------------------------------------------------------------------ the spec and "auto"
def test_brdf_spec_checks(tmp_path):
    assert check_brdf_spec("Quartz Glass") == "quartz glass"
    assert check_brdf_spec("auto") == "auto"
    with pytest.raises(ParameterError, match="quartz glass"):
        check_brdf_spec("quartz glas", "--brdf")
    with pytest.raises(InputFileError):
        check_brdf_spec(str(tmp_path / "missing.h5"))
    bad = tmp_path / "bad.h5"
    import h5py

    with h5py.File(bad, "w") as f:
        f.attrs["format"] = "something-else"
    with pytest.raises(InputFileError, match="neither a BRDF texture"):
        check_brdf_spec(str(bad))
    tex = tmp_path / "alloy.h5"
    write_texture(tex, tabulate(ALLOY, 8, 8, 256))
    lobe = retro_lobe(check_brdf_spec(str(tex)))
    ref = _lobe(ALLOY)
    assert lobe.halfwidth_rad() == pytest.approx(ref.halfwidth_rad(), rel=0.5)
    with pytest.raises(ParameterError, match="iterative"):
        ReconstructionConfig(method="lct", brdf="quartz glass").validate()
    assert ReconstructionConfig(method="iterative", brdf="auto").validate().brdf == "auto"


def test_auto_ladder_runs_from_lambertian_to_sharp():
    from clnlos.brdf.lobes import AUTO_ALPHAS
    ladder = auto_ladder()
    assert ladder[0].lambertian
    assert [lb.name for lb in ladder] == ["lambertian"] + [
        f"ggx alpha {a:g}" for a in sorted(AUTO_ALPHAS, reverse=True)]
    widths = [lobe.halfwidth_rad() for lobe in ladder]
    assert all(a > b for a, b in zip(widths, widths[1:], strict=False))


def test_choose_lobe_walks_while_the_score_falls():
    ladder = auto_ladder()
    scores = {lb.name: s for lb, s in zip(ladder, (0.6, 0.45, 0.26, 0.30, 0.58), strict=True)}
    chosen, tried = choose_lobe(ladder, lambda lb: scores[lb.name])
    assert chosen.name == ladder[2].name
    assert [n for n, _ in tried] == [lb.name for lb in ladder[:4]]  # one past the best
    flat = {lb.name: s for lb, s in zip(ladder, (0.05, 0.06, 0.051, 0.07, 0.08), strict=True)}
    chosen, tried = choose_lobe(ladder, lambda lb: flat[lb.name])
    assert chosen.lambertian and len(tried) == 2
    chosen, tried = choose_lobe(ladder, lambda lb: flat[lb.name], patience=2)
    assert chosen.lambertian and len(tried) == 3
    # a gain within the margin is not taken
    chosen, _ = choose_lobe(ladder, lambda lb: scores[lb.name], lambda a, b: 1.0)
    assert chosen.lambertian


def test_score_margin_is_the_noise_part_of_the_difference():
    rng = np.random.default_rng(0)
    held = rng.random(500)
    a, b = rng.random(500), rng.random(500)
    runs = [rng.standard_normal(500) * 0.1 for _ in range(200)]
    got = score_margin(a, b, held, runs)
    d = a - b
    sd = 2 * 0.1 * np.linalg.norm(d) / np.sum(held**2)
    assert got == pytest.approx(2.0 * sd, rel=0.15)


# ------------------------------------------------------------------ the inversion
def _glyph_capture(queue, material, *, points=16, exposure_s=0.1, glyph="E"):
    from clnlos.forward.model import ForwardModel
    from clnlos.forward.scene import Scene
    from clnlos.study.file.spec import StudyGrid, Target
    from clnlos.study.plan.entries import MaterialKeys, target_sample
    from clnlos.study.plan.scenes import scene_dict

    grid = StudyGrid(points=points, bin_width_s=64e-12, iterations=30, density_per_m2=2e4)
    target = Target("glyph", "glyphs", 0.5, glyphs=(glyph,), height_m=0.3, stroke_m=0.1)
    s = target_sample(target, glyph, MaterialKeys(material, {"material": material}, material),
                      exposure_s=exposure_s, seed=3, method="iterative", brdf={},
                      scan_width_m=0.6)
    scene = Scene.from_dict(scene_dict(s, grid))
    fm = ForwardModel(scene, queue=queue)
    return fm.capture(), scene, fm, grid


def _read(rec, scene, fm, glyph="E"):
    from clnlos.study.score.legibility import GLYPHS, glyph_templates, identify

    tpl = glyph_templates(0.3, 0.1, (0.0, 0.0), scene.scan_centres(), 0.05, GLYPHS)
    return identify(rec.volume.max(axis=0), tpl)[0] == glyph


@pytest.mark.slow
def test_known_brdf_reads_a_specular_glyph_the_lambertian_inversion_does_not(queue):
    """A glyph of the seed's aluminium alloy (a 1.3 deg lobe) behind the CDT slab: the
    iterative inversion with its BRDF identifies it, the Lambertian one does not; the volume
    records the lobe and its separable terms."""
    from clnlos.config import ReconstructionConfig
    from clnlos.inverse.pipeline import reconstruct

    cap, scene, fm, grid = _glyph_capture(queue, "aluminium alloy sample")
    read = {}
    for brdf in ("lambertian", "aluminium alloy sample"):
        cfg = ReconstructionConfig(method="iterative", iterations=grid.iterations,
                                   snr_rule="gcv", slab=scene.slab, brdf=brdf,
                                   max_path_m=1.6).validate()
        rec = reconstruct(cap, cfg, device=queue)
        read[brdf] = _read(rec, scene, fm)
        assert rec.params["brdf_used"] == brdf
        assert rec.params["brdf_terms_used"] == (1 if brdf == "lambertian" else
                                                 rec.solver["lobe_terms"]) >= 1
    assert read == {"lambertian": False, "aluminium alloy sample": True}


@pytest.mark.slow
def test_brdf_auto_takes_a_lobe_for_a_mirror_and_keeps_lambertian_for_paint(queue):
    """``brdf = "auto"`` on counts: a sharp lobe for the seed's quartz glass, the Lambertian
    one for its white plate; never told the material. Not counts: Lambertian and a note."""
    from clnlos.config import ReconstructionConfig
    from clnlos.inverse.pipeline import reconstruct
    chosen = {}
    for mat in ("quartz glass", "standard white plate"):
        cap, scene, fm, grid = _glyph_capture(queue, mat)
        cfg = ReconstructionConfig(method="iterative", iterations=grid.iterations,
                                   snr_rule="gcv", slab=scene.slab, brdf="auto",
                                   max_path_m=1.6).validate()
        rec = reconstruct(cap, cfg, device=queue)
        chosen[mat] = rec.params["brdf_chosen"]
        assert rec.params["brdf_rule_used"] == "thinning" and json.loads(rec.params["brdf_tried"])
    assert chosen["standard white plate"] == "lambertian"
    assert chosen["quartz glass"] != "lambertian"
    smooth = dataclasses.replace(cap, transient=cap.transient.astype(np.float32) + 0.25)
    rec = reconstruct(smooth, cfg, device=queue)
    assert rec.params["brdf_rule_used"] == "lambertian (not searched)"
    assert any("brdf auto" in n for n in rec.notes)


def test_held_out_half_is_compared_without_its_floor(queue):
    """``brdf = "auto"`` without a slab scores predictions of the floor-free reconstructed
    half against the held-out half: the held-out half loses its floor of dark counts and
    ambient light too (a constant floor added to the counts leaves the target unchanged),
    as the reconstructed half does (:func:`clnlos.inverse.snr.background_subtracted`)."""
    from clnlos.inverse.pipeline import ReconstructionPipeline
    from clnlos.inverse.preprocessing import resolve_geometry
    from clnlos.io.capture import Capture

    rng = np.random.default_rng(5)
    nt, n, floor = 96, 8, 4
    lam = np.zeros((nt, n, n))
    lam[40:46, 2:6, 3:7] = 60.0                       # a target's return
    signal = rng.poisson(lam).astype(np.float32)
    cap = Capture(signal, 32e-12, 0.0, 0.4, "test")
    cfg = ReconstructionConfig(method="iterative", iterations=5, brdf="auto").validate()
    bw, start, sw = resolve_geometry(cap, cfg)
    pipe = ReconstructionPipeline(cap.transient.shape, bin_width_s=bw, start_s=start,
                                  scan_width_m=sw, config=cfg, queue=queue)
    held, phi, _ = pipe._held_out_prediction_target(signal)
    with_floor, _, _ = pipe._held_out_prediction_target(signal + np.float32(floor))
    assert phi is None and np.abs(held).max() > 0
    np.testing.assert_allclose(with_floor, held, atol=1e-4 * np.abs(held).max())


# ------------------------------------------------------------------ the surface criterion
def test_surface_of_keeps_one_voxel_per_scan_point_and_zeroes_the_rest():
    v = np.random.default_rng(3).random((20, 4, 5)).astype(np.float32)
    s = surface_of(v)
    assert s.dtype == v.dtype and s.shape == v.shape
    assert np.count_nonzero(s) == 20  # as many as the 4 x 5 scan points
    kept = np.sort(v.ravel())[-20:]
    np.testing.assert_array_equal(np.sort(s[s > 0]), kept)
    sparse = np.zeros_like(v)
    sparse[3, 1, 2] = 1.0  # fewer bright voxels than scan points: kept as they are
    np.testing.assert_array_equal(surface_of(sparse), sparse)


def test_a_lobe_is_taken_only_where_its_surface_predicts_better_too():
    """choose_lobe with the searches' margin: a sharp lobe that wins on the whole volume
    (the unfocused data, a bowl per target point) but not on its surface is not taken."""
    ladder = auto_ladder()[:3]
    volume_scores = {ladder[0].name: 0.20, ladder[1].name: 0.15, ladder[2].name: 0.10}

    def walk(surface_scores):
        def margin(new, best):
            gain = surface_scores[best.name] - surface_scores[new.name]
            return both_margins(gain, 0.01, 0.01)
        return choose_lobe(ladder, lambda c: volume_scores[c.name], margin)[0].name

    focused = {ladder[0].name: 0.30, ladder[1].name: 0.25, ladder[2].name: 0.20}
    bowl = {ladder[0].name: 0.30, ladder[1].name: 0.35, ladder[2].name: 0.45}
    assert walk(focused) == ladder[2].name
    assert walk(bowl) == ladder[0].name
    assert both_margins(0.005, 0.01, 0.01) == float("inf")
