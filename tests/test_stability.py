"""Numerical stability: hard cases of every kernel, in float32 and float64 on PoCL.

Each case asserts finite output, no negative values where the physics forbids them, and
agreement with the float64 reference (the same plan in float64, or the numpy reference)
within the stated tolerance. Diffusion hard cases live in test_diffusion.py
(t = 0, t -> 0, late times, 1 mm - 30 cm slabs, mu_s' 10 - 1e5, mu_a = 0, n 1 - 1.6).
"""

import numpy as np
import pytest
from helpers import rel_l2
from reference.lightcone_ref import lightcone_ref

from clnlos.brdf.models import BRDFModel, retro_slice
from clnlos.forward.blur import slab_blur
from clnlos.forward.geometry import Elements
from clnlos.forward.lightcone import LightCone
from clnlos.forward.sampling import N_THETA, SurfaceSamples
from clnlos.inverse.fk import FKMigration
from clnlos.inverse.lct import LCT
from clnlos.operators.spectral import SpectralFilter
from clnlos.physics.slab import CDT_SLAB

CDT = CDT_SLAB
# float32 tolerance relative to the float64 result of the same plan
F32_TOL = {"wiener": 1e-3, "lightcone": 1e-4, "inversion": 1e-3}


def _both(make, x, queue):
    """Run a plan factory in float32 and float64; return (f32, f64) outputs."""
    out = {}
    for dt in (np.float32, np.float64):
        out[dt] = np.asarray(make(dt)(np.asarray(x, dt)), np.float64)
    return out[np.float32], out[np.float64]


# ------------------------------------------------------------------ Wiener
WIENER_INPUTS = {
    "zeros": lambda s: np.zeros(s),
    "spike": lambda s: np.pad(np.ones((1, 1, 1)), [(3, s[0] - 4), (2, s[1] - 3), (1, s[2] - 2)]),
    "denormal": lambda s: np.full(s, 1e-310),
    "random": lambda s: np.random.default_rng(0).random(s),
}


@pytest.mark.parametrize("snr", [1e-3, 1.0, 1e4, 1e12])
@pytest.mark.parametrize("kind", sorted(WIENER_INPUTS))
@pytest.mark.fp64
def test_wiener_snr_and_inputs(queue, snr, kind):
    shape = (16, 5, 6)
    x = WIENER_INPUTS[kind](shape)

    def make(dt):
        return slab_blur(CDT, shape, bin_width_s=5e-11, pitch_m=0.03, mode="wiener", snr=snr,
                         dtype=dt, queue=queue)

    a32, a64 = _both(make, x, queue)
    assert np.all(np.isfinite(a32)) and np.all(np.isfinite(a64))
    if kind == "zeros":
        assert not a64.any() and not a32.any()
    elif kind != "denormal":
        # measured float32 vs float64: 1e-7..7e-6 up to SNR 1e4, 2.2e-5 at SNR 1e12 (the
        # regularised inverse keeps its gain bounded); one tolerance for every SNR
        assert rel_l2(a64, a32) < F32_TOL["wiener"], rel_l2(a64, a32)


def test_wiener_psf_with_exact_spectral_zeros(queue, dtype):
    """A box PSF has exact zeros in its spectrum: with 1/SNR = tiny the inverse must stay
    finite (the kernel returns 0 where |H|^2 + 1/SNR == 0)."""
    shape = (8, 4, 4)
    psf = np.zeros((16, 8, 8))
    psf[:4, 0, 0] = 1.0  # box of 4 lags on a 16 grid: zeros at k = 4, 8, 12
    x = np.random.default_rng(1).random(shape).astype(dtype)
    for snr in (1e30, 1e3):
        op = SpectralFilter(psf, shape, mode="wiener", snr=snr, dtype=dtype, queue=queue)
        y = op(x)
        assert np.all(np.isfinite(y))


# ------------------------------------------------------------------ light cone
def _lc(dt, queue, retro, points=4, bins=64, start=0.0, bw=2e-11):
    return LightCone(points=points, width_m=0.2, bins=bins, bin_width_s=bw, start_s=start,
                     retro=retro, dtype=dt, queue=queue)


LIGHTCONE_CASES = {
    # element at 1 mm from the scan plane, right under a scan point (r -> 0)
    "touching": (np.array([[0.025, 0.025, 1e-3]]), np.array([[0, 0, -1.0]]), 0.0, 64),
    # grazing: normal almost parallel to the plane (cos_obj -> 0)
    "grazing": (np.array([[0.0, 0.0, 0.3]]), np.array([[1.0, 0, -1e-6]]), 1.5e-9, 128),
    # outside the time window (far away)
    "outside": (np.array([[0.0, 0.0, 30.0]]), np.array([[0, 0, -1.0]]), 0.0, 64),
}


@pytest.mark.parametrize("case", sorted(LIGHTCONE_CASES))
@pytest.mark.fp64
def test_lightcone_hard_geometry(queue, case):
    pos, nrm, start, bins = LIGHTCONE_CASES[case]
    nrm = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
    el = Elements(pos, nrm, np.full(len(pos), 1e-6))
    smp = SurfaceSamples(el, np.ones(len(pos)), np.zeros(len(pos), np.int32), None)
    outs = {dt: _lc(dt, queue, False, bins=bins, start=start)(smp).get().astype(np.float64)
            for dt in (np.float32, np.float64)}
    ref = lightcone_ref(pos, nrm, el.area, np.ones(len(pos)), np.zeros(len(pos), int), None,
                        points=4, width=0.2, bins=bins, bin_width=2e-11, start=start)
    for dt, o in outs.items():
        assert np.all(np.isfinite(o)) and np.all(o >= 0)
        if ref.any():
            assert rel_l2(ref, o) < (F32_TOL["lightcone"] if dt == np.float32 else 1e-10)
        else:
            assert not o.any()
    if case == "touching":
        # the 1/r^4 value (1/pi / (1 mm)^4 x 1 mm^2 = 3.2e5) is kept, not clipped; it arrives
        # 6.7 ps after t = 0, so the part of its linear splat before bin 0's centre is cut
        w = 1 / np.pi / 1e-3**4 * 1e-6
        b = 2e-3 / 299_792_458.0 / 2e-11
        assert outs[np.float64].sum() == pytest.approx(w * (b + 0.5), rel=1e-6)


@pytest.mark.fp64
def test_lightcone_mirror_like_brdf(queue):
    """Microfacet roughness 0.001 sampled at its nodes (the hard case for the kernel:
    retro_slice averages them to 4.6e3): retro values above 1e4 1/sr stay finite and
    match."""
    th = np.minimum(np.linspace(0, np.pi / 2, N_THETA), np.pi / 2 - 1e-6)
    m = BRDFModel("microfacet", {"alpha": 0.001, "f0": 0.95})
    table = np.nan_to_num(np.maximum(m(th, 0 * th, th, 0 * th), 0))
    assert table.max() > 1e4 and np.all(np.isfinite(table))
    assert retro_slice(m, N_THETA).max() < table.max()
    c = (np.arange(4) + 0.5) * 0.05 - 0.1
    pos = np.array([[c[1], c[2], 0.3], [0.0, 0.0, 0.35]])
    nrm = np.array([[0, 0, -1.0], [0.3, 0, -1.0]])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    el = Elements(pos, nrm, np.full(2, 1e-4))
    smp = SurfaceSamples(el, np.ones(2), np.zeros(2, np.int32), table[None])
    ref = lightcone_ref(pos, nrm, el.area, np.ones(2), np.zeros(2, int), table[None], points=4,
                        width=0.2, bins=128, bin_width=2e-11, start=1.8e-9)
    for dt in (np.float32, np.float64):
        o = _lc(dt, queue, True, bins=128, start=1.8e-9)(smp).get()
        assert np.all(np.isfinite(o)) and np.all(o >= 0)
        assert rel_l2(ref, o) < (F32_TOL["lightcone"] if dt == np.float32 else 1e-10)


@pytest.mark.fp64
def test_lightcone_empty_scene_and_a_million_elements(queue):
    empty = SurfaceSamples(Elements(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)),
                           np.zeros(0), np.zeros(0, np.int32), None)
    assert not _lc(np.float32, queue, False)(empty).get().any()
    rng = np.random.default_rng(3)
    n = 1_000_000
    pos = np.column_stack([rng.uniform(-0.1, 0.1, n), rng.uniform(-0.1, 0.1, n),
                           rng.uniform(0.2, 0.4, n)])
    nrm = np.tile([0.0, 0.0, -1.0], (n, 1))
    smp = SurfaceSamples(Elements(pos, nrm, np.full(n, 1e-8)), np.ones(n),
                         np.zeros(n, np.int32), None)
    o32 = _lc(np.float32, queue, False, points=2, bins=96, start=1.2e-9)(smp).get()
    o64 = _lc(np.float64, queue, False, points=2, bins=96, start=1.2e-9)(smp).get()
    assert np.all(np.isfinite(o32)) and o64.sum() > 0
    assert rel_l2(o64, o32) < 1e-4  # a million float32 additions per column


# ------------------------------------------------------------------ LCT / f-k
@pytest.mark.parametrize("shape", [(1, 4, 4), (7, 5, 3), (33, 9, 11), (50, 6, 6)])
@pytest.mark.parametrize("method", ["lct", "fk"])
@pytest.mark.fp64
def test_inversions_odd_sizes_one_bin(queue, shape, method):
    x = np.random.default_rng(4).random(shape)

    def make(dt):
        if method == "lct":
            return LCT(shape, bin_width_s=4e-11, scan_width_m=0.3, snr=1e2, dtype=dt,
                       queue=queue)
        return FKMigration(shape, bin_width_s=4e-11, scan_width_m=0.3, dtype=dt, queue=queue)

    a32, a64 = _both(make, x, queue)
    assert a32.shape == shape
    assert np.all(np.isfinite(a32)) and np.all(a32 >= 0) and np.all(a64 >= 0)
    if np.linalg.norm(a64) > 0:
        assert rel_l2(a64, a32) < F32_TOL["inversion"]


def test_depth_range_larger_than_window(queue):
    """A target beyond the time window: nothing arrives, the volume is finite and ~empty."""
    from reference.scene_ref import points_transient

    tau = points_transient([(0.0, 0.0, 5.0)], [1.0], 64, 8, 0.3, 2e-11)
    assert not tau.any()
    for op in (LCT((64, 8, 8), bin_width_s=2e-11, scan_width_m=0.3, queue=queue),
               FKMigration((64, 8, 8), bin_width_s=2e-11, scan_width_m=0.3, queue=queue)):
        v = op(tau.astype(np.float32))
        assert np.all(np.isfinite(v)) and not v.any()


# ------------------------------------------------------------------ BRDF texture and MLP
# Angles at the edges of the domain: normal and grazing incidence exactly (and a hair past
# grazing, clamped), azimuths at +-180 degrees, just inside them, and several turns away.
_EDGE_THETA = [0.0, np.pi / 2, np.pi / 2 + 1e-7, 1e-9]
_EDGE_PHI = [-np.pi, np.pi, np.pi - 1e-6, -np.pi + 1e-6, 0.0, 3 * np.pi, -5 * np.pi]


def _edge_angles() -> np.ndarray:
    g = np.meshgrid(_EDGE_THETA, _EDGE_PHI, _EDGE_THETA, _EDGE_PHI, indexing="ij")
    return np.column_stack([a.ravel() for a in g])


@pytest.mark.parametrize("path", ["buffer", "image"])
def test_texture_lookup_at_domain_edges(queue, dtype, path):
    """kernels/brdf.cl at 0 and 90 degrees and across the +-180 degree azimuth wrap: finite,
    non-negative, equal to the float64 reference (f32 1e-5, f64 1e-12 of the texture's
    peak), and the same on both sides of the wrap."""
    from clnlos.brdf.texture import lookup_numpy, tabulate
    from clnlos.brdf.texture_lookup import TextureLookup

    if path == "image" and (dtype != np.float32 or not queue.device.image_support):
        pytest.skip("3D float images: float32 on devices with image support")
    tex = tabulate(BRDFModel("microfacet", {"kd": 0.2, "ks": 0.8, "alpha": 0.2, "f0": 0.5}),
                   16, 24, 8)
    a = _edge_angles()
    got = TextureLookup(tex, path=path, dtype=dtype, queue=queue)(a)
    ref = lookup_numpy(tex.texture, a)
    peak = float(tex.texture.max())
    assert np.all(np.isfinite(got)) and np.all(got >= 0)
    tol = 1e-5 if dtype == np.float32 else 1e-12
    if path == "image":
        tol = 2e-3  # the sampler's 8-bit fixed-point interpolation weights (OpenCL spec)
    assert np.max(np.abs(got - ref)) <= tol * peak
    # +-180 degrees is one azimuth: phi_s = pi and -pi (and 3 pi) give one value
    lut = TextureLookup(tex, path=path, dtype=dtype, queue=queue)
    rtol = 1e-4 if dtype == np.float32 else 1e-9
    b = np.array([[0.3, 0.0, 0.7, np.pi], [0.3, 0.0, 0.7, -np.pi], [0.3, 0.0, 0.7, 3 * np.pi],
                  [0.3, 2 * np.pi, 0.7, np.pi]])
    v = lut(b)
    np.testing.assert_allclose(v, v[0], rtol=rtol)
    # phi_i = -179.99..., phi_s = +179.99... degrees: 2e-6 rad apart across the wrap
    c = lut(np.array([[0.3, -np.pi + 1e-6, 0.7, np.pi - 1e-6], [0.3, 0.0, 0.7, 0.0]]))
    np.testing.assert_allclose(c[0], c[1], rtol=1e-4)


def test_mlp_at_domain_edges():
    """The neural BRDF (improved recipe) at 0 and 90 degrees and across the azimuth wrap:
    finite, non-negative, and continuous across +-180 degrees (the half/difference encoding
    has no seam there)."""
    from clnlos.brdf.data import BRDFSamples
    from clnlos.brdf.mlp import MLPConfig, train_mlp

    truth = BRDFModel("phong", {"kd": 0.3, "ks": 0.7, "shininess": 10.0})
    rng = np.random.default_rng(0)
    n = 300
    ti, ts = rng.uniform(0, 1.4, n), rng.uniform(0, 1.4, n)
    pi_, ps = np.zeros(n), rng.uniform(-np.pi, np.pi, n)
    samples = BRDFSamples(ti, pi_, ts, ps, truth(ti, pi_, ts, ps), {"material": "synthetic"})
    model, _ = train_mlp(samples, MLPConfig(recipe="improved", epochs=150, seed=1))
    a = _edge_angles()
    f = model(a[:, 0], a[:, 1], a[:, 2], a[:, 3])
    assert np.all(np.isfinite(f)) and np.all(f >= 0)
    left = model(np.full(3, 0.4), np.zeros(3), np.full(3, 0.6), np.array([np.pi - 1e-7,
                                                                        np.pi, 3 * np.pi]))
    right = model(np.full(3, 0.4), np.zeros(3), np.full(3, 0.6), np.array([-np.pi + 1e-7,
                                                                         -np.pi, -np.pi]))
    np.testing.assert_allclose(left, right, rtol=1e-5)
