"""Slab diffusion kernel (kernels/diffusion.cl) against the float64 reference, and hard cases."""

import numpy as np
import pyopencl.array as cla
import pytest
from helpers import TOL_DIFFUSION, rel_l2
from reference.diffusion_ref import (
    fluence_1d_images,
    fresnel_r_eff,
    slab_transmittance_mp,
    slab_transmittance_ref,
)

from clnlos.config import slab_table
from clnlos.diffusion import SlabTransmittance, diffusion_psf, slab_transmittance
from clnlos.errors import ParameterError
from clnlos.physics.grid import grid_offsets
from clnlos.physics.slab import CDT_SLAB, Slab

CDT = slab_table(CDT_SLAB)


def test_effective_reflection_matches_bruteforce():
    for n in (1.0, 1.12, 1.33, 1.4, 1.6):
        assert Slab(0.01, 0.0, 100.0, n).r_eff == pytest.approx(fresnel_r_eff(n), abs=2e-6)
    assert Slab(**CDT).r_eff == pytest.approx(0.178, abs=1e-3)
    assert Slab(**CDT).ze == pytest.approx(0.0036, abs=1e-4)


@pytest.mark.parametrize("n_dipoles", [None, 20])
def test_kernel_matches_reference(queue, dtype, n_dipoles):
    # physically relevant range for the CDT slab: 20 ps .. 6 ns, rho up to 10 cm
    t = np.linspace(2e-11, 6e-9, 300)
    rho = np.linspace(0.0, 0.1, 21)
    R, Tt = np.meshgrid(rho, t, indexing="ij")
    # ze passed explicitly: this compares the kernel, R_eff is checked on its own above
    ze = Slab(**CDT).ze
    ref = slab_transmittance_ref(R, Tt, **CDT, ze_m=ze)
    out = slab_transmittance(R, Tt, **CDT, ze_m=ze, n_dipoles=n_dipoles, dtype=dtype, device=queue)
    assert out.dtype == dtype and out.shape == R.shape
    err = rel_l2(ref, out)
    assert err <= TOL_DIFFUSION[dtype], f"{dtype} M={n_dipoles}: rel L2 {err:.2e}"


@pytest.mark.parametrize("slab", [
    dict(thickness_m=1e-3, mu_a=0.0, mu_s_prime=1e4, n=1.0),
    dict(thickness_m=0.3, mu_a=0.0, mu_s_prime=50.0, n=1.6),
    dict(thickness_m=0.05, mu_a=10.0, mu_s_prime=1e3, n=1.4, ze_m=0.0),
])
def test_kernel_matches_reference_other_slabs(queue, dtype, slab):
    s = Slab(**slab)
    tpeak = s.thickness_m**2 / (6 * s.D * s.v)  # time of the transmittance peak (order)
    t = np.linspace(0.05, 8, 400) * tpeak
    kw = dict(slab, ze_m=s.ze)
    ref = slab_transmittance_ref(0.0, t, **kw)
    out = slab_transmittance(0.0, t, **kw, dtype=dtype, device=queue)
    assert rel_l2(ref, out) <= TOL_DIFFUSION[dtype]


def test_late_times_and_pointwise_against_mpmath(queue, dtype):
    s = Slab(**CDT)
    ts = [1e-12, 5e-11, 3e-10, 2e-9, 1e-8, 3e-8]
    for t in ts:
        ref = slab_transmittance_mp(0.01, t, **CDT, ze_m=s.ze)
        out = float(slab_transmittance(0.01, t, **CDT, dtype=dtype, device=queue))
        tol = 2e-5 if dtype == np.float32 else 1e-11
        if ref < 1e-30:
            assert out == pytest.approx(ref, abs=1e-30)
        else:
            assert abs(out - ref) <= tol * ref, (t, out, ref)


@pytest.mark.fp64
def test_small_n_dipoles_is_wrong_late_but_never_negative(queue):
    t = np.linspace(1e-10, 8e-9, 200)
    exact = slab_transmittance(0.0, t, **CDT, dtype=np.float64, device=queue)
    errs = []
    for M in (0, 1, 2, 3, 5, 10):
        out = slab_transmittance(0.0, t, **CDT, n_dipoles=M, dtype=np.float64, device=queue)
        assert np.all(out >= 0) and np.all(np.isfinite(out))
        errs.append(rel_l2(exact, out))
    assert all(b <= a for a, b in zip(errs, errs[1:], strict=False)), errs
    assert errs[0] > 1e-2 and errs[-1] < 1e-10


@pytest.mark.fp64
def test_total_transmittance_lossless(queue):
    s = Slab(thickness_m=0.0254, mu_a=0.0, mu_s_prime=262.0, n=1.12)
    lt = np.linspace(np.log(1e-13), np.log(2e-6), 40000)
    t = np.exp(lt)
    T0 = slab_transmittance(0.0, t, thickness_m=s.thickness_m, mu_a=0.0, mu_s_prime=262.0,
                            n=1.12, dtype=np.float64, device=queue)
    # lateral integral of exp(-rho^2/(4Dvt)) over the plane is 4 pi D v t
    flux = T0 * 4 * np.pi * s.D * s.v * t
    total = np.trapezoid(flux * t, lt)
    assert total == pytest.approx(s.total_transmittance_lossless(), rel=1e-5)


def test_zero_fluence_at_extrapolated_boundaries():
    s = Slab(**CDT)
    for t in (1e-10, 1e-9, 5e-9):
        kw = dict(CDT, ze_m=s.ze)
        peak = max(abs(fluence_1d_images(z, t, **kw)) for z in np.linspace(0, s.thickness_m, 9))
        for z in (-s.ze, s.thickness_m + s.ze):
            assert abs(fluence_1d_images(z, t, **kw)) < 1e-10 * peak + 1e-14


@pytest.mark.parametrize("slab", [
    dict(thickness_m=1e-3, mu_a=0.0, mu_s_prime=10.0, n=1.0),
    dict(thickness_m=1e-3, mu_a=0.0, mu_s_prime=1e5, n=1.6),
    dict(thickness_m=0.3, mu_a=0.0, mu_s_prime=10.0, n=1.0),
    dict(thickness_m=0.3, mu_a=0.0, mu_s_prime=1e5, n=1.6),
    dict(thickness_m=0.0254, mu_a=0.53, mu_s_prime=262.0, n=1.12),
])
def test_hard_cases_finite_nonnegative(queue, dtype, slab):
    t = np.concatenate([[0.0, 1e-30, 1e-20, 4e-16, 1e-15, 1e-13],
                        np.geomspace(1e-12, 1e-4, 60), [-1e-9]])
    rho = np.array([0.0, 1e-3, 0.1, 1.0, 100.0])
    out = slab_transmittance(rho[:, None], t[None, :], **slab, dtype=dtype, device=queue)
    assert np.all(np.isfinite(out)), "NaN/Inf"
    assert np.all(out >= 0), "negative"
    assert np.all(out[:, 0] == 0) and np.all(out[:, -1] == 0)  # t = 0 and t < 0
    for M in (0, 3, 50):
        o2 = slab_transmittance(rho[:, None], t[None, :], **slab, n_dipoles=M, dtype=dtype,
                                device=queue)
        assert np.all(np.isfinite(o2)) and np.all(o2 >= 0)


def test_empty_input(queue):
    out = slab_transmittance(np.zeros(0), 1e-9, **CDT, device=queue)
    assert out.shape == (0,)


@pytest.mark.parametrize("field,value", [
    ("thickness_m", -1.0), ("thickness_m", float("nan")), ("mu_a", -0.1),
    ("mu_s_prime", 0.0), ("n", 0.9), ("n", float("nan")), ("ze_m", -1e-3),
])
def test_invalid_parameters_name_the_field(queue, field, value):
    kw = dict(CDT)
    kw[field] = value
    with pytest.raises(ValueError, match=field):
        slab_transmittance(0.0, 1e-9, **kw, device=queue)


def test_invalid_n_dipoles_and_nan_inputs(queue):
    with pytest.raises(ParameterError, match="n_dipoles"):
        slab_transmittance(0.0, 1e-9, **CDT, n_dipoles=-2, device=queue)
    with pytest.raises(ParameterError, match="t_s"):
        slab_transmittance(0.0, np.array([np.nan]), **CDT, device=queue)


@pytest.mark.fp64
def test_psf_grid_layout_and_normalisation(queue):
    s = Slab(**CDT)
    dt, pitch, nt, n = 16e-12, 0.01, 256, 16
    psf = diffusion_psf(s, nt=nt, bin_width_s=dt, ny=n, nx=n, pitch_m=pitch, dtype=np.float64,
                        queue=queue, time_nodes=1)
    assert psf.shape == (nt, n, n)
    assert np.all(psf[0] == 0)  # zero lag
    # wrap order: zero offset at index 0, symmetric in +-offset
    assert np.argmax(psf.sum(0)) == 0
    np.testing.assert_allclose(psf[:, 1, 0], psf[:, -1, 0], rtol=1e-12)
    off = grid_offsets(n, pitch)
    ref = slab_transmittance_ref(np.hypot(off[3], off[5]), np.arange(nt) * dt, **CDT, ze_m=s.ze)
    np.testing.assert_allclose(psf[:, 3, 5], ref * dt * pitch**2, rtol=1e-9, atol=1e-300)
    unit = diffusion_psf(s, nt=nt, bin_width_s=dt, ny=n, nx=n, pitch_m=pitch, queue=queue,
                         normalize="sum")
    assert unit.sum() == pytest.approx(1.0, rel=1e-5)
    # bin-averaged (default) against the reference integrated by the midpoint rule
    avg = diffusion_psf(s, nt=nt, bin_width_s=dt, ny=n, nx=n, pitch_m=pitch, dtype=np.float64,
                        queue=queue)
    fine = (np.arange(nt)[:, None] + (np.arange(64) + 0.5)[None, :] / 64 - 0.5) * dt
    ref_avg = slab_transmittance_ref(np.hypot(off[3], off[5]), fine, **CDT,
                                     ze_m=s.ze).mean(axis=1)
    np.testing.assert_allclose(avg[:, 3, 5], ref_avg * dt * pitch**2, rtol=2e-4,
                               atol=1e-4 * ref_avg.max() * dt * pitch**2)


def test_plan_reuses_program(queue):
    a = SlabTransmittance(Slab(**CDT), queue=queue)
    b = SlabTransmittance(Slab(**CDT), n_dipoles=3, queue=queue)
    assert a.kernels is b.kernels


@pytest.mark.fp64
def test_temporal_support_holds_all_but_tol_of_the_psf(queue):
    """The slab PSF is evaluated only over its temporal support: what is cut is below the
    stated tolerance of the full table's energy, and a slab whose response outlasts the
    window keeps every lag."""
    from clnlos.diffusion import diffusion_psf, diffusion_psf_device, temporal_support_lags

    slab = Slab(**CDT)
    nt, dt = 512, 32e-12
    lags = temporal_support_lags(slab, nt=nt, bin_width_s=dt, queue=queue)
    assert 16 < lags < nt // 2  # about 5 ns of a 16 ns window
    full = diffusion_psf(slab, nt=nt, bin_width_s=dt, ny=32, nx=32, pitch_m=0.005,
                         dtype=np.float64 if queue.device.double_fp_config else np.float32,
                         queue=queue).astype(np.float64)
    assert full[lags:].sum() < 1e-6 * full.sum()
    assert full[lags - 8:lags].sum() > 0  # the cut is not far past the support
    plan = SlabTransmittance(slab, dtype=np.float32, queue=queue)
    out = cla.zeros(queue, (nt, 32, 32), np.float32)
    diffusion_psf_device(plan, nt=nt, bin_width_s=dt, ny=32, nx=32, pitch_m=0.005, lags=lags,
                         out_g=out)
    got = out.get()
    assert not got[lags:].any()
    np.testing.assert_allclose(got[:lags], full[:lags], rtol=1e-4, atol=1e-6 * full.max())
    slow = Slab(thickness_m=0.3, mu_a=0.001, mu_s_prime=1000.0, n=1.4)
    assert temporal_support_lags(slow, nt=64, bin_width_s=dt, queue=queue) == 64
