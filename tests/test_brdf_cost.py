"""The BRDF-aware inversion at the price of the Lambertian one: the lobe's terms split over the
axes (one transform over (y, x), one along t per term) against the whole 3D transform per term,
the row-weight kernel against numpy, and ``brdf = "auto"`` choosing on the search's grid."""

import json

import numpy as np
import pyopencl.array as cla
import pytest

import clnlos.inverse.brdf_choice as brdf_choice
import clnlos.runtime.fft as fft
from clnlos.brdf.lobes import retro_lobe
from clnlos.config import ReconstructionConfig
from clnlos.forward.transport import LightConeTransport
from clnlos.inverse.brdf_choice import search_factors
from clnlos.inverse.pipeline import ReconstructionPipeline, reconstruct
from clnlos.inverse.preprocessing import resolve_geometry
from clnlos.io.capture import Capture
from clnlos.operators.base import dot_test
from clnlos.operators.spectral import scale_rows
from clnlos.physics.grid import block_sums
from clnlos.runtime.programs import get_kernels, real_defines


@pytest.mark.parametrize("lobe,margin", [("retroreflective", 0), ("glossy-paint", 1),
                                         ("quartz glass", 0)])
def test_split_terms_are_the_whole_transform(queue, monkeypatch, lobe, margin):
    """float64: the operator and its adjoint with the terms split over the axes equal the
    same terms each transformed in 3D to 1e-12 (folded cone spectra without a margin, whole
    ones with it); the split operator passes the dot test."""
    kw = dict(bin_width_s=40e-12, scan_width_m=0.3, margin=margin, depth_min_m=0.2,
              dtype=np.float64, queue=queue, lobe=retro_lobe(lobe), lobe_terms=3)
    split = LightConeTransport((70, 6, 5), **kw)
    assert split.split and split.lobe.terms == 3 and split.folded == (margin == 0)
    monkeypatch.setattr(fft.RealFFT3, "split_axes", property(lambda self: False))
    whole = LightConeTransport((70, 6, 5), **kw)
    assert not whole.split
    rng = np.random.default_rng(7)
    x, y = rng.random(whole.in_shape), rng.random(whole.out_shape)
    for a, b in ((split(x), whole(x)), (split.adjoint(y), whole.adjoint(y))):
        assert np.linalg.norm(a - b) <= 1e-12 * np.linalg.norm(b)
    assert dot_test(split, rng) < 1e-12


@pytest.mark.parametrize("dtype,tol", [(np.float64, 1e-15), (np.float32, 1e-7)])
def test_scale_rows_against_numpy(queue, dtype, tol):
    """Y[w] = s[w] X[w] (and += it) on the weighted rows, zeros on the padding rows; hard
    cases: a zero and a negative weight, one row, padding rows that held data."""
    cd = np.complex64 if dtype == np.float32 else np.complex128
    k = get_kernels(queue, "wiener", real_defines(dtype))
    rng = np.random.default_rng(1)
    for rows, n_out, shape in ((5, 9, (3, 4)), (1, 1, (2, 3))):
        X = (rng.standard_normal((rows,) + shape) + 1j * rng.standard_normal((rows,) + shape))
        s = rng.standard_normal(rows)
        s[0] = 0.0
        Y0 = rng.standard_normal((n_out,) + shape) + 1j * rng.standard_normal((n_out,) + shape)
        Yg = cla.to_device(queue, Y0.astype(cd))
        scale_rows(k, cla.to_device(queue, X.astype(cd)), Yg, cla.to_device(
            queue, s.astype(dtype)), rows=rows, accumulate=False, zero_rows=n_out)
        want = np.zeros_like(Y0)
        want[:rows] = s[:, None, None] * X
        got = Yg.get()
        assert np.abs(got - want).max() <= tol * np.abs(want).max()
        scale_rows(k, cla.to_device(queue, X.astype(cd)), Yg, cla.to_device(
            queue, s.astype(dtype)), rows=rows, accumulate=True)
        want[:rows] *= 2
        assert np.abs(Yg.get() - want).max() <= 2 * tol * np.abs(want).max()


def test_search_factors_and_block_sums():
    assert search_factors((512, 64, 64)) == (2, 2)
    assert search_factors((150, 32, 32)) == (1, 1)
    assert search_factors((2048, 128, 96)) == (4, 8)
    assert search_factors((100, 33, 33)) == (3, 1)
    assert search_factors((100, 37, 37)) == (1, 1)  # a prime side: no block divides it
    y = np.arange(2 * 4 * 6, dtype=np.float32).reshape(2, 4, 6)
    s = block_sums(y, 2)
    assert s.shape == (2, 2, 3) and s[1, 1, 2] == y[1, 2:4, 4:6].sum()
    assert s.sum() == y.sum()


def test_auto_chooses_on_the_search_grid(queue, monkeypatch):
    """A capture larger than the search's grid: the lobe search reconstructs its halves on a
    pipeline of the block-summed, rebinned capture, the same search that pipeline runs on the
    summed capture itself (the same lobes tried, the same scores), and the full-size
    reconstruction records that grid, the scores and the choice's cost in its params and a
    note."""
    from clnlos.bench.brdf_inversion import glyph_scene_dict
    from clnlos.forward.model import ForwardModel
    from clnlos.forward.scene import Scene

    monkeypatch.setattr(brdf_choice, "LOBE_SEARCH_POINTS", 8)
    monkeypatch.setattr(brdf_choice, "LOBE_SEARCH_BINS", 32)
    d = glyph_scene_dict("lambertian", points=16, bins=64, bin_width_s=60e-12,
                         scan_width_m=0.5, density_per_m2=5e3)
    d["detector"] = {"exposure_s": 0.05, "etendue_m2_sr": 1e-9, "dark_count_rate_hz": 1e3}
    cap = ForwardModel(Scene.from_dict(d), queue=queue).capture()
    cfg = ReconstructionConfig(method="iterative", brdf="auto", iterations=5).validate()
    rec = reconstruct(cap, cfg, device=queue)
    p = rec.params
    assert p["brdf_search_grid"] == "32x8x8" and p["brdf_choice_s"] > 0
    note = next(n for n in rec.notes if n.startswith("brdf auto chose"))
    assert p["brdf_chosen"] in note and "32 x 8 x 8" in note
    small = Capture(block_sums(cap.transient, 2), cap.bin_width_s, cap.start_s,
                    cap.scan_width_m)
    c2 = cfg.replace(bins=32)
    bw, start, sw = resolve_geometry(small, c2)
    pipe = ReconstructionPipeline(small.transient.shape, bin_width_s=bw, start_s=start,
                                  scan_width_m=sw, config=c2, queue=queue)
    y = small.transient
    lobe, direct = pipe.brdf_lobe(y, pipe.raw_noise(y), np.inf)
    assert lobe.name == p["brdf_chosen"]
    got, want = json.loads(direct["brdf_tried"]), json.loads(p["brdf_tried"])
    assert [n for n, _ in got] == [n for n, _ in want]
    assert [v for _, v in got] == pytest.approx([v for _, v in want], rel=1e-6)


@pytest.mark.parametrize("slab", [False, True])
def test_lobe_search_candidates_are_the_runs_of_their_half(queue, monkeypatch, slab):
    """The lobe search prepares its training half once and reconstructs it per lobe: each
    candidate's volume is the one a full ``run`` of that half with the lobe and the search's
    iteration budget gives (with and without the slab's deconvolution)."""
    from clnlos.bench.brdf_inversion import glyph_scene_dict
    from clnlos.forward.model import ForwardModel
    from clnlos.forward.scene import Scene
    from clnlos.inverse.brdf_choice import LOBE_SEARCH_ITERATIONS

    d = glyph_scene_dict("lambertian", points=8, bins=96, bin_width_s=60e-12,
                         scan_width_m=0.5, density_per_m2=5e3, slab=slab)
    d["detector"] = {"exposure_s": 0.05, "etendue_m2_sr": 1e-9, "dark_count_rate_hz": 1e3}
    scene = Scene.from_dict(d)
    cap = ForwardModel(scene, queue=queue).capture()
    cfg = ReconstructionConfig(method="iterative", brdf="auto", iterations=8, snr_rule="gcv",
                               slab=scene.slab).validate()
    bw, start, sw = resolve_geometry(cap, cfg)
    pipe = ReconstructionPipeline(cap.transient.shape, bin_width_s=bw, start_s=start,
                                  scan_width_m=sw, config=cfg, queue=queue)
    assert (pipe.deconv is not None) == slab
    halves, volumes = [], []
    split, rebuild = pipe._split, pipe._reconstruct
    monkeypatch.setattr(pipe, "_split", lambda y: halves.append(split(y)) or halves[-1])

    def recorded(*a, **kw):
        rec = rebuild(*a, **kw)
        volumes.append((pipe.invert.solver.lobe, rec.volume.copy()))
        return rec

    monkeypatch.setattr(pipe, "_reconstruct", recorded)
    y = cap.transient
    pipe.brdf_lobe(y, pipe.raw_noise(y), 1e4)
    monkeypatch.setattr(pipe, "_reconstruct", rebuild)
    assert len(halves) == 1 and len(volumes) >= 3  # the Lambertian, a GGX lobe, the retro
    train = halves[0][0]
    for lobe, vol in volumes:
        with pipe.invert.iteration_budget(LOBE_SEARCH_ITERATIONS):
            ref = pipe.run(train, model_snr=1e4, slab_snr_factor=1.0, lobe=lobe).volume
        assert np.abs(vol - ref).max() <= 1e-5 * np.abs(ref).max(), lobe.name
