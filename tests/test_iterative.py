"""Iterative reconstruction: prox kernels vs float64 numpy, the TV prox and FISTA vs
independent solvers (scipy L-BFGS-B), light-cone transport vs the forward light-cone kernel,
the noise estimate, and reconstructions through the slab."""

import math

import numpy as np
import pyopencl.array as cla
import pytest
import scipy.optimize as so
import scipy.sparse as sp
from helpers import rel_l2

from clnlos import C0
from clnlos.config import ReconstructionConfig, slab_table
from clnlos.errors import ParameterError
from clnlos.forward.blur import slab_blur
from clnlos.forward.geometry import Elements
from clnlos.forward.lightcone import LightCone
from clnlos.forward.model import ForwardModel
from clnlos.forward.sampling import SurfaceSamples
from clnlos.forward.scene import Scene
from clnlos.forward.transport import LightConeTransport
from clnlos.inverse.iterative import IterativeInversion
from clnlos.inverse.pipeline import reconstruct
from clnlos.inverse.snr import K_SNR, SNR_MAX, estimate_noise, is_counts
from clnlos.inverse.solvers import ProxKernels, fista, lipschitz
from clnlos.operators.base import dot_test
from clnlos.operators.resample import AxisResample
from clnlos.physics.slab import CDT_SLAB
from clnlos.study.score.metrics import mip_iou, truth_mask

TOL = {np.dtype(np.float32): 1e-6, np.dtype(np.float64): 1e-13}


def _dev(queue, a, dtype):
    return cla.to_device(queue, np.ascontiguousarray(a, dtype))


# ------------------------------------------------------------------ kernels vs numpy
def test_prox_kernels_vs_numpy(queue, dtype):
    rng = np.random.default_rng(0)
    shape = (7, 5, 6)
    z, g, x0 = (rng.standard_normal(shape) for _ in range(3))
    pk = ProxKernels(queue, shape, dtype)
    zg, gg, x0g = (_dev(queue, a, dtype) for a in (z, g, x0))
    x1, r = cla.empty_like(zg), cla.empty_like(zg)
    step, shift, row_min = 0.3, 0.05, 2
    pk.prox_step(zg, gg, x0g, x1, r, step, shift, row_min)
    ref = np.maximum(z - step * g - shift, 0)
    ref[:row_min] = 0
    assert rel_l2(ref, x1.get()) < TOL[dtype]
    assert rel_l2((z - ref) * (ref - x0), r.get()) < 10 * TOL[dtype]
    v = cla.empty_like(zg)
    pk.gradient_step(zg, gg, v, step, shift)
    assert rel_l2(z - step * g - shift, v.get()) < TOL[dtype]
    pk.restart_terms(zg, x1, x0g, r)
    assert rel_l2((z - ref) * (ref - x0), r.get()) < 10 * TOL[dtype]
    # the momentum sequence on the device: no restart (sum r <= 0) advances t, a restart
    # resets it; z = x1 + beta (x1 - x0) with beta read on the device
    state = pk.new_state()
    t, beta = 1.0, 0.0
    for restart in (False, False, True, False):
        rr = _dev(queue, np.full(shape, 1.0 if restart else -1.0), dtype)
        pk.momentum(rr, state, x1, x0g, zg)
        t1 = 1.0 if restart else (1 + np.sqrt(1 + 4 * t * t)) / 2
        beta = 0.0 if restart else (t - 1) / t1
        t = t1
        assert np.allclose(state.get()[:2], [t, beta], rtol=1e-6)
        assert rel_l2(ref + beta * (ref - x0), zg.get()) < TOL[dtype] or beta == 0
    assert state.get()[2] == 1  # one restart counted
    # the working set: support rows, x > 0 or a gradient that lifts the variable
    ws, old = cla.empty(queue, shape, np.uint8), cla.zeros(queue, shape, np.uint8)
    size, entering = pk.working_set(x1, gg, old, ws, shift, row_min)
    want = (ref > 0) | ((ref <= 0) & (g + shift < 0))
    want[:row_min] = False
    assert np.array_equal(ws.get().astype(bool), want) and size == want.sum()
    assert entering == ((ref <= 0) & (g + shift < 0))[row_min:].sum()
    assert np.array_equal(pk.masked(zg, ws).get(), np.where(want, zg.get(), 0))
    held = cla.empty_like(zg)
    pk.prox_step(zg, gg, x0g, held, r, step, shift, row_min, ws)
    assert not held.get()[~want].any()
    w = rng.random(shape)
    out = cla.empty_like(zg)
    pk.weighted_residual(x1, x0g, _dev(queue, w, dtype), out)
    assert rel_l2(w * (ref - x0), out.get()) < TOL[dtype]
    pk.weighted_residual(x1, x0g, None, out)
    assert rel_l2(ref - x0, out.get()) < TOL[dtype]


def _grad(x, wz):
    g = np.zeros((3,) + x.shape)
    g[0, :-1] = wz * np.diff(x, axis=0)
    g[1, :, :-1] = np.diff(x, axis=1)
    g[2, :, :, :-1] = np.diff(x, axis=2)
    return g


def _tv(x, wz):
    return float(np.sqrt((_grad(x, wz) ** 2).sum(0)).sum())


@pytest.mark.fp64
def test_tv_prox_1d_matches_independent_solver(queue):
    """On a (n, 1, 1) volume TV is 1D: the FGP prox equals the solution of the box-constrained
    dual min_p 1/2 ||v - lam D^T p||^2, |p| <= 1, by L-BFGS-B (x = v - lam D^T p)."""
    rng = np.random.default_rng(1)
    v = 3.0 + np.cumsum(rng.standard_normal(40))  # positive: the x >= 0 bound stays inactive
    v -= v.min() - 3.0
    lam = 1.5
    D = np.diff(np.eye(40), axis=0)  # (39, 40) forward differences

    def f(p):
        x = v - lam * D.T @ p
        return 0.5 * x @ x, -lam * D @ x

    p = so.minimize(f, np.zeros(39), jac=True, method="L-BFGS-B", bounds=[(-1, 1)] * 39,
                    options={"ftol": 1e-15, "gtol": 1e-12, "maxiter": 10000}).x
    ref = v - lam * D.T @ p
    pk = ProxKernels(queue, (40, 1, 1), np.float64)
    out = cla.empty(queue, (40, 1, 1), np.float64)
    pk.tv_prox(_dev(queue, v.reshape(40, 1, 1), np.float64), lam, 1.0, 0,
               cla.zeros(queue, (3, 40, 1, 1), np.float64), out, iterations=3000)
    assert rel_l2(ref, out.get().ravel()) < 1e-6


def test_tv_prox_3d_lowers_objective_and_keeps_constraints(queue, dtype):
    rng = np.random.default_rng(2)
    v = rng.standard_normal((6, 7, 5)) + 0.3
    pk = ProxKernels(queue, v.shape, dtype)
    out = cla.empty(queue, v.shape, dtype)
    lam, wz = 0.4, 0.5
    pk.tv_prox(_dev(queue, v, dtype), lam, wz, 2, cla.zeros(queue, (3,) + v.shape, dtype), out,
               iterations=200)
    x = out.get().astype(np.float64)
    assert x.min() >= 0 and not x[:2].any()
    obj = 0.5 * ((x - v) ** 2).sum() + lam * _tv(x, wz)
    naive = np.maximum(v, 0)
    naive[:2] = 0
    assert obj < 0.5 * ((naive - v) ** 2).sum() + lam * _tv(naive, wz)
    # optimality against random feasible perturbations
    for _ in range(20):
        y = np.maximum(x + 0.01 * rng.standard_normal(x.shape), 0)
        y[:2] = 0
        assert obj <= 0.5 * ((y - v) ** 2).sum() + lam * _tv(y, wz) + 1e-5


def _matrix_operator(queue, M, dtype):
    """A dense matrix as a LinearOperator on (n, 1, 1) device arrays."""
    return AxisResample(sp.csr_matrix(M), (1, 1), dtype=dtype, queue=queue)


def test_fista_matches_lbfgsb(queue, dtype):
    """min 1/2||Ax - y||^2 + l1 sum(x), x >= 0 (smooth on the orthant) vs L-BFGS-B."""
    rng = np.random.default_rng(3)
    A = rng.standard_normal((60, 30)) / 8
    x_true = np.maximum(rng.standard_normal(30), 0)
    y = A @ x_true + 0.01 * rng.standard_normal(60)
    l1 = 0.05

    def f(x):
        r = A @ x - y
        return 0.5 * r @ r + l1 * x.sum(), A.T @ r + l1

    ref = so.minimize(f, np.zeros(30), jac=True, method="L-BFGS-B", bounds=[(0, None)] * 30,
                      options={"ftol": 1e-15, "gtol": 1e-12}).x
    op = _matrix_operator(queue, A, dtype)
    res = fista(op, _dev(queue, y.reshape(60, 1, 1), dtype),
                cla.zeros(queue, (30, 1, 1), dtype), l1=l1, iterations=3000, tol=1e-9)
    assert rel_l2(ref, res.x.get().ravel()) < (1e-4 if dtype == np.float32 else 1e-7)
    x = res.x.get().ravel().astype(np.float64)
    assert f(x)[0] <= f(np.zeros(30))[0] and res.objective and res.change


@pytest.mark.fp64
def test_lipschitz_is_largest_eigenvalue(queue):
    A = np.random.default_rng(4).standard_normal((40, 25))
    L = lipschitz(_matrix_operator(queue, A, np.float64), iterations=200)
    top = np.linalg.eigvalsh(A.T @ A).max()
    assert top <= L <= 1.06 * top


def test_lipschitz_past_float32_range(queue):
    """||A^T A|| ~ 4e38, past float32's 3.4e38, while ||A|| ~ 2e19 fits: the estimate is
    finite and is the largest eigenvalue (the light cone's long windows whose support
    reaches the scan plane give such operators)."""
    A = np.random.default_rng(5).standard_normal((40, 25))
    A[:, 3] *= 30.0
    scale = 1e17
    L = lipschitz(_matrix_operator(queue, A * scale, np.float32), iterations=200)
    top = np.linalg.eigvalsh(A.T @ A).max() * scale**2
    assert math.isfinite(L) and 0.999 * top <= L <= 1.06 * top


# ------------------------------------------------------------------ light-cone transport
@pytest.mark.parametrize("case", [(96, 8, 40e-12, 0.4, 0), (120, 6, 30e-12, 0.3, 3)])
@pytest.mark.fp64
def test_transport_matches_lightcone_kernel(queue, case):
    """Voxels facing the scan plane rendered by the forward light-cone kernel (an independent
    element-wise method): per scan point, the time-integrated signal within 2% and the time
    centroid within 0.25 bins (the operator splats in v = r^2, the kernel in t)."""
    nt, n, bw, w, margin = case
    dz = C0 * bw / 2
    rng = np.random.default_rng(1)
    vol = np.zeros((nt, n, n))
    k, j, i = (rng.integers(int(0.5 * nt), int(0.8 * nt), 12), rng.integers(0, n, 12),
               rng.integers(0, n, 12))
    vol[k, j, i] = rng.uniform(0.2, 1, 12)
    op = LightConeTransport((nt, n, n), bin_width_s=bw, scan_width_m=w, margin=margin,
                            depth_min_m=0.2, dtype=np.float64, queue=queue)
    out = op(vol)
    pitch = w / n
    kk, jj, ii = np.nonzero(vol)
    pos = np.column_stack([(ii + 0.5) * pitch - w / 2, (jj + 0.5) * pitch - w / 2,
                           (kk + 0.5) * dz])
    el = Elements(pos, np.tile([0, 0, -1.0], (len(pos), 1)), np.full(len(pos), pitch**2))
    nw = n + 2 * margin
    lc = LightCone(points=nw, width_m=nw * pitch, bins=nt, bin_width_s=bw, start_s=0.0,
                   retro=False, dtype=np.float64, queue=queue)
    ref = lc(SurfaceSamples(el, vol[kk, jj, ii], np.zeros(len(pos), np.int32), None)).get()
    t = np.arange(nt) + 0.5
    s_ref, s_out = ref.sum(0), out.sum(0)
    assert np.abs(s_out / s_ref - 1).max() < 0.02
    c_ref = (ref * t[:, None, None]).sum(0) / s_ref
    c_out = (out * t[:, None, None]).sum(0) / s_out
    assert np.abs(c_out - c_ref).max() < 0.25


@pytest.mark.fp64
def test_transport_support_rows_are_zero(queue):
    op = LightConeTransport((80, 4, 4), bin_width_s=40e-12, scan_width_m=0.2,
                            depth_min_m=0.25, dtype=np.float64, queue=queue)
    rng = np.random.default_rng(5)
    out = op(rng.random((80, 4, 4)))
    assert op.k_min == int(0.25 / (C0 * 40e-12 / 2))
    assert not out[:op.k_min].any() and out[op.k_min:].any()
    back = op.apply_adjoint(rng.random((80, 4, 4)))
    assert not back[:op.k_min].any()


# ------------------------------------------------------------------ noise
def test_noise_estimate_poisson_and_first_arrival():
    rng = np.random.default_rng(6)
    lam = np.full((200, 8, 8), 0.01)  # background
    lam[120:140] += 50.0 * np.exp(-0.5 * ((np.arange(20) - 5) / 3.0) ** 2)[:, None, None]
    y = rng.poisson(lam).astype(np.float32)
    ne = estimate_noise(y, 16e-12)
    assert ne.photon_counts and is_counts(y)
    assert ne.signal == pytest.approx(y.sum() - 0.01 * y.size, rel=0.02)
    assert ne.snr == pytest.approx(ne.signal / K_SNR, rel=1e-9)
    assert 118 * 16e-12 <= ne.first_arrival_s <= 124 * 16e-12
    assert ne.nearest_depth_m == pytest.approx(C0 * ne.first_arrival_s / 2)
    clean = lam.astype(np.float32) * 0.37  # not counts: noise from the data, capped SNR
    ne2 = estimate_noise(clean, 16e-12)
    assert not ne2.photon_counts and ne2.snr == SNR_MAX
    noisy = clean + rng.normal(0, 0.2, clean.shape).astype(np.float32)
    ne3 = estimate_noise(noisy, 16e-12)
    assert ne3.sigma == pytest.approx(0.2, rel=0.1)


# ------------------------------------------------------------------ reconstructions
def _rect_scene(noise: bool, depth=0.5, seed=0) -> Scene:
    objs = [{"shape": "rectangle", "size_m": [0.16, 0.045], "translate_m": [0.0, 0.0575, depth]},
            {"shape": "rectangle", "size_m": [0.045, 0.115],
             "translate_m": [0.0, -0.0225, depth]}]
    d = {"seed": seed, "scan": {"width_m": 0.3, "points": 24},
         "time": {"bin_width_s": 32e-12, "bins": 256, "start_s": 0.0}, "objects": objs,
         "slab": slab_table(CDT_SLAB),
         "laser": {"pulse_width_s": 35e-12}, "sampling": {"density_per_m2": 1e5}}
    if noise:
        d["detector"] = {"power_w": 0.4, "rep_rate_hz": 10e6, "exposure_s": 0.1,
                         "efficiency": 0.3, "etendue_m2_sr": 1e-9, "dark_count_rate_hz": 1e3}
    return Scene.from_dict(d)


@pytest.mark.slow
@pytest.mark.parametrize("noise", [False, True])
def test_iterative_beats_lct_and_fk_through_slab(queue, noise):
    """A 'T' of 4.5 cm bars 0.5 m behind the CDT slab (24 x 24 scan, 32 ps bins): the
    iterative method with default parameters is at least 0.1 IoU above LCT and f-k."""
    scene = _rect_scene(noise)
    fm = ForwardModel(scene, queue=queue)
    cap = fm.capture()
    mask = truth_mask(fm.samples.elements, scene.scan_centres())
    iou = {}
    for method in ("lct", "fk", "iterative"):
        cfg = ReconstructionConfig(max_path_m=1.6, slab=CDT_SLAB, method=method).validate()
        rec = reconstruct(cap, cfg, device=queue)
        iou[method] = mip_iou(rec.volume, mask)[0]
        if method == "iterative":
            assert rec.solver["iterations"] >= 1 and rec.params["snr_used"] > 0
            depth = (np.argmax(rec.volume.max(axis=(1, 2))) + 0.5) * C0 * rec.bin_width_s / 2
            assert depth == pytest.approx(0.5, abs=0.01)
    assert iou["iterative"] >= max(iou["lct"], iou["fk"]) + 0.1, iou
    assert iou["iterative"] >= (0.75 if not noise else 0.6), iou


def test_iterative_plan_rejects_bad_weights(queue):
    from clnlos.errors import ParameterError

    with pytest.raises(ParameterError, match="l1_weight"):
        IterativeInversion((32, 4, 4), bin_width_s=4e-11, scan_width_m=0.2, iterations=3,
                           l1_weight=-1.0, tv_weight=0.0, queue=queue)
    with pytest.raises(ParameterError, match="iterations"):
        IterativeInversion((32, 4, 4), bin_width_s=4e-11, scan_width_m=0.2, iterations=2.5,
                           l1_weight=0.1, tv_weight=0.0, queue=queue)


def test_transport_adjoint(queue, dtype):
    op = LightConeTransport((40, 5, 4), bin_width_s=40e-12, scan_width_m=0.2, margin=2,
                            depth_min_m=0.1, depth_weight=np.linspace(0.5, 1, 40),
                            dtype=dtype, queue=queue)
    assert dot_test(op, np.random.default_rng(7)) < (1e-5 if dtype == np.float32 else 1e-12)


@pytest.mark.slow
def test_cli_iterative_uses_recorded_slab(tmp_path, capsys, queue):
    """clnlos simulate -> clnlos reconstruct --method iterative with no slab flags: the slab
    the capture recorded is used (named in the note and in the output's stages), the noise
    estimate and the solver's report are stored; --no-slab opts out."""
    import h5py

    from clnlos.app.cli import main

    scene = tmp_path / "s.toml"
    scene.write_text("""seed = 2
[scan]
width_m = 0.3
points = 12
[time]
bin_width_s = 48e-12
bins = 80
[[objects]]
shape = "rectangle"
size_m = [0.1, 0.05]
translate_m = [0.0, 0.0, 0.45]
[slab]
thickness_m = 0.0254
mu_a = 0.53
mu_s_prime = 262.0
n = 1.12
[detector]
exposure_s = 0.1
etendue_m2_sr = 1e-9
""")
    cap = tmp_path / "c.h5"
    assert main(["simulate", str(scene), "-o", str(cap)]) == 0
    out = tmp_path / "v.h5"
    capsys.readouterr()
    assert main(["reconstruct", str(cap), "-o", str(out), "--method", "iterative",
                 "--iterations", "30"]) == 0
    err = capsys.readouterr().err
    assert "slab recorded in the capture" in err and "mu_s' = 262" in err
    with h5py.File(out) as f:
        import json

        assert "deconvolve:slab(d = 0.0254 m" in f.attrs["stages"]
        assert json.loads(f.attrs["noise"])["photon_counts"] is True
        solver = json.loads(f.attrs["solver"])
        assert 1 <= solver["iterations"] <= 30 and solver["depth_min_m"] > 0.2
        params = json.loads(f.attrs["params"])
        assert params["model_snr_used"] == "inf" or params["model_snr_used"] == float("inf")
        v = f["volume"][()]
    assert v.min() >= 0 and v.max() > 0
    out2 = tmp_path / "v2.h5"
    assert main(["reconstruct", str(cap), "-o", str(out2), "--no-slab"]) == 0
    with h5py.File(out2) as f:
        assert "deconvolve" not in f.attrs["stages"]


@pytest.mark.parametrize("snr", [1e2, 1e5])
def test_slab_influence_is_the_wiener_filter_after_the_blur(queue, snr):
    """Phi of SpectralFilter.influence against the two filters it stands for: for a
    transient whose blur stays inside the grid (a 4 x 4 patch of early arrivals in the
    middle of 0.56 m), W (B x) = B's DC gain * Phi x (float32 pair, within the blur's
    0.1% left outside); Phi is self-adjoint, of norm < 1, and on fewer rows equals the
    full one with those rows zero."""
    shape, kw = (160, 28, 28), dict(bin_width_s=48e-12, pitch_m=0.02, queue=queue)
    W = slab_blur(CDT_SLAB, shape, mode="wiener", snr=snr, **kw)
    B = slab_blur(CDT_SLAB, shape, **kw)
    phi = W.influence()
    rng = np.random.default_rng(1)
    x = np.zeros(shape, np.float32)
    x[:16, 12:16, 12:16] = rng.random((16, 4, 4))
    ref = W(B(x)) / B.dc_gain
    assert rel_l2(phi(x), ref) < 5e-3
    assert abs(dot_test(phi)) < 1e-5
    noise = rng.random(shape).astype(np.float32)
    assert np.linalg.norm(phi(noise)) < np.linalg.norm(noise)
    short = W.influence(in_shape=(64,) + shape[1:])
    xs = noise.copy()
    xs[64:] = 0
    np.testing.assert_allclose(short(noise[:64]), phi(xs)[:64], rtol=1e-4,
                               atol=1e-5 * float(np.abs(phi(xs)).max()))
    with pytest.raises(ParameterError, match="mode"):
        B.influence()
    # cut where its kernel holds all but 1e-5 of its energy: the same operator within
    # sqrt(1e-5) (an amplitude), on a smaller grid, self-adjoint, in_shape kept
    cut = W.influence(energy_tol=1e-5)
    assert np.prod(cut.pad_shape) < np.prod(W.pad_shape) and cut.in_shape == shape
    assert all(p >= n for p, n in zip(cut.pad_shape, shape, strict=True))
    for v in (x, noise):
        assert rel_l2(cut(v), phi(v)) < 1e-2
    assert abs(dot_test(cut)) < 1e-5


def test_kernel_support_and_fast_lengths():
    """kernel_support: the smallest |lag| per axis holding all but the tolerance of the
    energy, lags in wrap order (an independent count on a kernel built to have it);
    fast_length / padded_length: 5-smooth lengths, the padded one even and >= 2 n."""
    from clnlos.operators.spectral import kernel_support
    from clnlos.physics.grid import fast_length, padded_length, row_blocks

    k = np.zeros((40, 12, 10))
    k[0, 0, 0] = 1.0
    k[3, 0, 0] = k[-3, 0, 0] = 0.1     # time lags +-3
    k[0, 2, 0] = k[0, -2, 0] = 0.1     # y lags +-2
    k[0, 0, 1] = 1e-4                  # x lag 1, 1e-8 of the energy
    assert kernel_support(k, 1e-6) == (3, 2, 0)
    assert kernel_support(k, 1e-9) == (3, 2, 1)
    for n in (1, 7, 97, 139, 709, 1000):
        m, p = fast_length(n), padded_length(n)
        assert m >= n and p >= 2 * n and p % 2 == 0
        for q in (m, p):
            for f in (2, 3, 5):
                while q % f == 0:
                    q //= f
            assert q == 1
    assert fast_length(97) == 100 and padded_length(709) == 1440 and padded_length(139) == 288
    assert row_blocks((10, 3, 4), 25) == [(0, 2), (2, 4), (4, 6), (6, 8), (8, 10)]
    assert row_blocks((3, 100), 10) == [(0, 1), (1, 2), (2, 3)]


def _sparse_blur_problem(n: int = 60):
    """(A, x_true): a Gaussian blur of 3 samples (coherent columns) and three spikes."""
    t = np.arange(n)
    A = np.exp(-0.5 * ((t[:, None] - t[None, :]) / 3.0) ** 2)
    x_true = np.zeros(n)
    x_true[[12, 30, 44]] = [1.0, 0.6, 0.8]
    return A, x_true


@pytest.mark.fp64
def test_working_set_solves_a_sparse_problem_in_fewer_steps(queue):
    """A sparse non-negative problem with coherent columns (a Gaussian blur, an L1
    weight): the working-set solver reaches L-BFGS-B's minimiser as plain FISTA does, in
    fewer iterations; both stop by the objective's relative decrease."""
    A, x_true = _sparse_blur_problem()
    n = A.shape[0]
    y = A @ x_true + 0.001 * np.random.default_rng(7).standard_normal(n)
    l1 = 0.01

    def f(x):
        r = A @ x - y
        return 0.5 * r @ r + l1 * x.sum(), A.T @ r + l1

    ref = so.minimize(f, np.zeros(n), jac=True, method="L-BFGS-B", bounds=[(0, None)] * n,
                      options={"ftol": 1e-15, "gtol": 1e-12}).x
    op = _matrix_operator(queue, A, np.float64)
    runs = {ws: fista(op, _dev(queue, y.reshape(n, 1, 1), np.float64),
                      cla.zeros(queue, (n, 1, 1), np.float64), l1=l1, iterations=20000,
                      tol=1e-12, working_set=ws) for ws in (False, True)}
    for r in runs.values():
        assert f(r.x.get().ravel())[0] <= f(ref)[0] + 1e-9
    assert runs[True].rounds and runs[True].iterations < runs[False].iterations
    assert all(0 < fr < 1 for _, fr, _, _ in runs[True].rounds)


@pytest.mark.fp64
def test_no_working_set_update_after_the_last_iteration(queue):
    """A solve capped where a working-set round would end (CHECK_EVERY + WORKING_SET_ROUND
    iterations) records no round there: no gradient or power iteration after the last step."""
    from clnlos.inverse.solvers import CHECK_EVERY, WORKING_SET_ROUND
    A, x_true = _sparse_blur_problem()
    n = A.shape[0]
    y = A @ x_true
    op = _matrix_operator(queue, A, np.float64)
    cap = CHECK_EVERY + WORKING_SET_ROUND
    applied = []
    apply = op.apply_device
    op.apply_device = lambda x: applied.append(1) or apply(x)
    res = fista(op, _dev(queue, y.reshape(n, 1, 1), np.float64),
                cla.zeros(queue, (n, 1, 1), np.float64), l1=1e-4, iterations=cap, tol=0.0,
                lipschitz_const=float(np.linalg.norm(A, 2) ** 2), working_set=True)
    assert res.iterations == cap and [k for k, *_ in res.rounds] == [CHECK_EVERY]
    # the solve's own applications, the first round's gradient and its power iterations
    from clnlos.inverse.solvers import WORKING_SET_POWER_ITERATIONS
    assert len(applied) == cap + 1 + WORKING_SET_POWER_ITERATIONS


def test_slab_model_is_a_checked_choice():
    assert ReconstructionConfig().validate().slab_model == "influence"
    with pytest.raises(ParameterError, match="slab_model"):
        ReconstructionConfig(slab_model="exact").validate()
