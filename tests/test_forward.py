"""Forward simulation: light-cone kernel vs float64 reference, analytic checks, convergence,
stage composition, the simulate CLI, and a simulate -> reconstruct round trip."""

import h5py
import numpy as np
import pytest
from helpers import rel_l2
from reference.lightcone_ref import lightcone_ref

from clnlos import C0
from clnlos.app.cli import main
from clnlos.brdf.models import BRDFModel, retro_slice
from clnlos.config import ReconstructionConfig, slab_table
from clnlos.errors import ParameterError
from clnlos.forward.geometry import (
    Elements,
    read_mesh,
    sample_mesh,
    sample_rectangle,
    sample_sphere,
)
from clnlos.forward.lightcone import LightCone
from clnlos.forward.model import ForwardModel
from clnlos.forward.pulse import pulse_taps
from clnlos.forward.sampling import N_THETA, SurfaceSamples
from clnlos.forward.scene import Scene
from clnlos.inverse.pipeline import reconstruct
from clnlos.io.files import read_capture
from clnlos.physics.slab import CDT_SLAB
from clnlos.study.score.metrics import letters_truth_mask, mip_iou, peak_depth_m

# float32: the sub-bin position r * 2/(c dt) ~ 300 bins carries ~2e-5 bins of rounding
TOL = {np.float32: 1e-4, np.float64: 1e-12}


def _scene(**over):
    d = {"scan": {"width_m": 0.4, "points": 8},
         "time": {"bin_width_s": 20e-12, "bins": 256, "start_s": 2e-9},
         "objects": [{"shape": "rectangle", "size_m": [0.1, 0.1],
                      "translate_m": [0.02, -0.03, 0.45], "rotate_deg": [10.0, 20.0, 0.0]}]}
    d.update(over)
    return Scene.from_dict(d)


def _samples(el, albedo=None, tables=None, material=None):
    n = len(el)
    return SurfaceSamples(el, np.ones(n) if albedo is None else albedo,
                          np.zeros(n, np.int32) if material is None else material, tables)


@pytest.mark.parametrize("variant", ["item", "group"])
@pytest.mark.parametrize("splat", [0, 1])
@pytest.mark.parametrize("brdf", [False, True])
def test_kernel_vs_reference(queue, dtype, splat, brdf, variant):
    """Both kernel shapes (work-item per scan point for CPUs, work-group per scan point with
    a local histogram for GPUs) against the float64 reference."""
    from clnlos.forward.lightcone import choose_lightcone_variant

    if variant == "group":
        try:
            choose_lightcone_variant(queue.device, "group", 128, dtype)
        except Exception as exc:  # noqa: BLE001 -- DeviceCapabilityError: skip with the reason
            pytest.skip(str(exc))
    rng = np.random.default_rng(0)
    n = 300
    pos = np.column_stack([rng.uniform(-0.2, 0.2, n), rng.uniform(-0.2, 0.2, n),
                           rng.uniform(0.3, 0.6, n)])
    nrm = rng.normal(size=(n, 3))
    # about 80% face the relay wall (n_z < 0), the rest are back faces the kernel must skip
    nrm[:, 2] = np.where(rng.random(n) < 0.8, -1.0, 1.0) * np.abs(nrm[:, 2])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    assert 0.1 < np.mean(nrm[:, 2] > 0) < 0.3
    area = rng.uniform(1e-5, 1e-4, n)
    alb = rng.uniform(0.2, 1.0, n)
    tables = mat = None
    if brdf:
        tables = np.stack([retro_slice(BRDFModel("phong", {"kd": 0.2, "ks": 0.8,
                                                           "shininess": 20.0}), N_THETA),
                           retro_slice(BRDFModel("microfacet", {"alpha": 0.3}), N_THETA)])
        mat = rng.integers(0, 2, n).astype(np.int32)
    kw = dict(points=6, width=0.3, bins=128, bin_width=16e-12, start=1.5e-9)
    ref = lightcone_ref(pos, nrm, area, alb, mat if brdf else np.zeros(n, int), tables,
                        splat_order=splat, **kw)
    lc = LightCone(points=6, width_m=0.3, bins=128, bin_width_s=16e-12, start_s=1.5e-9,
                   retro=brdf, splat_order=splat, dtype=dtype, queue=queue, variant=variant)
    assert lc.variant == variant
    out = lc(_samples(Elements(pos, nrm, area), alb, tables, mat)).get()
    assert ref.sum() > 0
    assert rel_l2(ref, out) < TOL[np.dtype(dtype).type] * (20 if splat == 0 else 1)


@pytest.mark.fp64
def test_single_patch_hyperbola_and_amplitude(queue):
    x0, y0, z0, dA = 0.03, -0.05, 0.4, 1e-6
    el = Elements(np.array([[x0, y0, z0]]), np.array([[0.0, 0.0, -1.0]]), np.array([dA]))
    dt, start = 10e-12, 2.4e-9
    lc = LightCone(points=9, width_m=0.4, bins=200, bin_width_s=dt, start_s=start,
                   retro=False, dtype=np.float64, queue=queue)
    out = lc(_samples(el)).get()
    c = (np.arange(9) + 0.5) * 0.4 / 9 - 0.2
    k = np.arange(200)
    for iy in range(9):
        for ix in range(9):
            r = np.sqrt((c[ix] - x0) ** 2 + (c[iy] - y0) ** 2 + z0**2)
            col = out[:, iy, ix]
            t_centroid = start + ((k + 0.5) * col).sum() / col.sum() * dt
            assert t_centroid == pytest.approx(2 * r / C0, abs=1e-3 * dt)
            cos = z0 / r
            assert col.sum() == pytest.approx(cos**4 / r**4 * dA / np.pi, rel=1e-12)


@pytest.mark.fp64
def test_lambertian_square_matches_quadrature(queue):
    """Time-integrated I of a fronto-parallel square = (1/pi) int cos^2 cos^2 / r^4 dA."""
    from scipy.integrate import dblquad

    side, z0 = 0.1, 0.5
    el = sample_rectangle(side, side, 4e6)
    el = Elements(el.pos + [0, 0, z0], el.normal, el.area)
    lc = LightCone(points=3, width_m=0.3, bins=400, bin_width_s=10e-12, start_s=3e-9,
                   retro=False, dtype=np.float64, queue=queue)
    out = lc(_samples(el)).get().sum(axis=0)
    c = (np.arange(3) + 0.5) * 0.1 - 0.15
    for iy in range(3):
        for ix in range(3):
            def f(y, x, cx=c[ix], cy=c[iy]):
                return z0**4 / ((x - cx) ** 2 + (y - cy) ** 2 + z0**2) ** 4 / np.pi

            ref = dblquad(f, -side / 2, side / 2, -side / 2, side / 2, epsabs=0, epsrel=1e-10)[0]
            assert out[iy, ix] == pytest.approx(ref, rel=1e-4)


@pytest.mark.fp64
def test_sampling_density_convergence(queue):
    dense = ForwardModel(Scene.from_dict({**_raw(), "sampling": {"density_per_m2": 4e6}}),
                         queue=queue, dtype=np.float64).run()
    errs = []
    for dens in (2.5e3, 1e4, 4e4, 1.6e5):
        sc = Scene.from_dict({**_raw(), "sampling": {"density_per_m2": dens}})
        errs.append(rel_l2(dense, ForwardModel(sc, queue=queue, dtype=np.float64).run()))
    assert all(b < a for a, b in zip(errs, errs[1:], strict=False)), errs
    assert errs[-1] < 0.05


def _raw():
    return {"scan": {"width_m": 0.4, "points": 8},
            "time": {"bin_width_s": 20e-12, "bins": 256, "start_s": 2e-9},
            "objects": [{"shape": "rectangle", "size_m": [0.1, 0.1],
                         "translate_m": [0.02, -0.03, 0.45], "rotate_deg": [10.0, 20.0, 0.0]}]}


def test_only_requested_stages_are_built(queue):
    fm = ForwardModel(_scene(), queue=queue)
    assert fm.stages == ["lightcone:lambertian"]
    assert fm.blur is None and fm.pulse is None
    assert "RETRO_TABLE" not in fm.lightcone.defines
    a = fm.run()
    assert np.array_equal(a, fm.run())  # deterministic without a detector
    raw = _raw()
    raw["time"]["start_s"] = 0.0
    raw["objects"][0]["material"] = "glossy-paint"
    full = {**raw, "slab": {"thickness_m": 0.0254, "mu_a": 0.53, "mu_s_prime": 262.0,
                            "n": 1.12},
            "laser": {"pulse_width_s": 35e-12},
            "detector": {"exposure_s": 0.01, "etendue_m2_sr": 1e-9}, "seed": 3}
    fm2 = ForwardModel(Scene.from_dict(full), queue=queue)
    assert fm2.stages == ["lightcone:brdf-table", "slab_blur", "pulse_blur", "photon_noise"]
    assert fm2.lightcone.defines.get("RETRO_TABLE")
    n1, n2 = fm2.run(), fm2.run()
    assert np.array_equal(n1, n2) and np.all(n1 == np.round(n1)) and n1.sum() > 0
    fm3 = ForwardModel(Scene.from_dict({**full, "seed": 4}), queue=queue)
    assert not np.array_equal(n1, fm3.run())


def test_pulse_taps():
    taps = pulse_taps(35e-12, 16e-12)
    assert taps.sum() == pytest.approx(1.0)
    k = np.arange(len(taps)) - (len(taps) - 1) / 2
    sigma = 35e-12 / 2.3548 / 16e-12
    assert np.sqrt((taps * k**2).sum()) == pytest.approx(np.sqrt(sigma**2 + 1 / 12), rel=1e-3)


def test_geometry_samplers(tmp_path):
    s = sample_sphere(0.1, 1e5)
    assert s.area.sum() == pytest.approx(4 * np.pi * 0.01)
    assert np.allclose(np.linalg.norm(s.normal, axis=1), 1)
    (tmp_path / "t.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n")
    V, F = read_mesh(tmp_path / "t.obj")
    el = sample_mesh(V, F, 1000)
    assert el.area.sum() == pytest.approx(1.0) and np.allclose(el.normal, [0, 0, 1])
    (tmp_path / "t.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
        "end_header\n0 0 0\n0 2 0\n2 0 0\n3 0 1 2\n")
    V, F = read_mesh(tmp_path / "t.ply")
    assert sample_mesh(V, F, 50).area.sum() == pytest.approx(2.0)


@pytest.mark.parametrize("mutate,field", [
    (lambda d: d["scan"].update(points=0), "scan.points"),
    (lambda d: d["time"].update(bin_width_s=-1), "time.bin_width_s"),
    (lambda d: d["objects"][0].update(shape="cube"), "objects[0].shape"),
    (lambda d: d["objects"][0].update(translate_m=[0, 0]), "objects[0].translate_m"),
    (lambda d: d["objects"][0].update(material="unobtainium"), "objects[0].material"),
    (lambda d: d.update(slab={"thickness_m": 0.01}), "slab.mu_a"),
    (lambda d: d.update(detector={"efficiency": 2.0}), "detector.efficiency"),
    (lambda d: d.update(colour="red"), "colour"),
])
def test_scene_validation_names_field(queue, mutate, field):
    d = _raw()
    mutate(d)
    with pytest.raises(ParameterError, match=field.replace("[", r"\[").replace("]", r"\]")):
        ForwardModel(Scene.from_dict(d), queue=queue)


def test_simulate_cli_writes_capture(tmp_path, queue):
    toml = tmp_path / "scene.toml"
    toml.write_text("""seed = 1
[scan]
width_m = 0.3
points = 8
[time]
bin_width_s = 20e-12
bins = 200
start_s = 2e-9
[[objects]]
shape = "letters"
text = "T"
height_m = 0.1
stroke_m = 0.02
translate_m = [0.0, 0.0, 0.4]
""")
    out = tmp_path / "cap.h5"
    assert main(["simulate", str(toml), "-o", str(out)]) == 0
    cap = read_capture(out)
    assert cap.transient.shape == (200, 8, 8) and cap.transient.sum() > 0
    assert cap.bin_width_s == 20e-12 and cap.start_s == 2e-9 and cap.scan_width_m == 0.3
    with h5py.File(out) as f:
        assert "lightcone:lambertian" in f.attrs["stages"] and "seed = 1" in f.attrs["scene"]
    assert out.with_suffix(".png").stat().st_size > 1000
    toml.write_text(toml.read_text().replace("points = 8", "points = -3"))
    assert main(["simulate", str(toml), "-o", str(tmp_path / "bad.h5")]) == 2
    assert not (tmp_path / "bad.h5").exists()


@pytest.fixture(scope="module")
def demo_capture(queue):
    """The built-in demo scene (seed Table 1: "UT" 0.5 m behind the 2.54 cm slab, 0.3 m x
    0.3 m scan, 35 ps pulse, Lambertian, noise-free), simulated once."""
    import importlib.resources
    import tomllib


    data = importlib.resources.files("clnlos").joinpath("data")
    scene = Scene.from_dict(tomllib.loads(data.joinpath("demo_scene.toml").read_text()))
    assert scene.width_m ** 2 == pytest.approx(0.09) and scene.detector is None
    fm = ForwardModel(scene, queue=queue)
    assert fm.margin >= 10  # the ~11 cm reach of the CDT slab's blur at a 9.4 mm pitch
    o = scene.objects[0]
    truth = letters_truth_mask(o.text, o.height_m, o.stroke_m, o.translate_m[:2],
                               scene.scan_centres())
    cfg = ReconstructionConfig.from_dict(tomllib.loads(
        data.joinpath("demo_reconstruct.toml").read_text()))
    return fm.capture(), truth, cfg.replace(
        slab=scene.slab)


@pytest.mark.slow
@pytest.mark.parametrize("method,min_iou", [("lct", 0.6), ("fk", 0.6), ("iterative", 0.8)])
def test_round_trip_letters_through_slab(queue, demo_capture, method, min_iou):
    """The demo capture reconstructed with the built-in demo parameters: letters at the right
    depth and the Otsu-thresholded MIP overlapping the true letter mask (measured: LCT 0.70,
    f-k 0.64, iterative 0.86)."""
    cap, truth, cfg = demo_capture
    rec = reconstruct(cap, cfg.replace(method=method).validate(), device=queue)
    depth = peak_depth_m(rec.volume, rec.extents["voxel_depth_m"])
    assert abs(depth - 0.5) <= 0.01  # 1 cm: 4 voxels of 2.4 mm (f-k lands 7 mm short)
    score, _ = mip_iou(rec.volume, truth)
    assert score >= min_iou, score


def test_forward_blur_sees_light_from_outside_the_scan(queue):
    """With a slab, I is computed past the scan border as far as the blur reaches: a patch
    just outside the scanned square still puts light into the capture, and the margin
    follows the slab (a thicker slab reaches further)."""
    base = {"scan": {"width_m": 0.2, "points": 8},
            "time": {"bin_width_s": 32e-12, "bins": 160, "start_s": 0.0},
            "objects": [{"shape": "rectangle", "size_m": [0.04, 0.04],
                         "translate_m": [0.16, 0.0, 0.3]}],
            "slab": slab_table(CDT_SLAB)}
    fm = ForwardModel(Scene.from_dict(base), queue=queue)
    assert fm.margin >= 4 and fm.run().sum() > 0
    no_slab = dict(base)
    no_slab.pop("slab")
    fm0 = ForwardModel(Scene.from_dict(no_slab), queue=queue)
    assert fm0.margin == 0
    thick = {**base, "slab": {**base["slab"], "thickness_m": 0.05}}
    assert ForwardModel(Scene.from_dict(thick), queue=queue).margin > fm.margin
    # a blur reaching past twice the scan: margin capped, zero-padded (non-wrapping) blur
    wide = {**base, "slab": {"thickness_m": 0.3, "mu_a": 0.0, "mu_s_prime": 10.0, "n": 1.0}}
    fw = ForwardModel(Scene.from_dict(wide), queue=queue)
    assert fm.reach_covered and not fw.reach_covered and fw.margin >= 16
    assert fw.blur.pad_shape[1] == 2 * (8 + 2 * fw.margin)
    tau = fw.run()
    assert np.all(np.isfinite(tau)) and tau.sum() > 0


def test_pulse_blur_kernel_vs_numpy(queue, dtype):
    """kernels/temporal.cl (time_convolve) against numpy's convolution, float64 reference."""
    import pyopencl.array as cla

    from clnlos.forward.pulse import PulseBlur

    rng = np.random.default_rng(7)
    x = rng.random((90, 3, 4))
    x[:, 0, 0] = 0  # an empty column stays empty
    op = PulseBlur(x.shape, 35e-12, 16e-12, dtype=dtype, queue=queue)
    out = op(cla.to_device(queue, x.astype(dtype))).get()
    taps = pulse_taps(35e-12, 16e-12)
    K = (len(taps) - 1) // 2
    ref = np.apply_along_axis(lambda c: np.convolve(c, taps)[K:K + len(c)], 0, x)
    assert rel_l2(ref, out) < TOL[np.dtype(dtype).type]
    assert np.all(out[:, 0, 0] == 0)
    assert out.sum() == pytest.approx(ref.sum(), rel=1e-5)


def test_mask_shape_is_the_shape_it_cuts_out(tmp_path, queue):
    """A mask of a filled square is that square: the same elements and the same capture as a
    rectangle of its size; a depth map moves each element along the normal; the image's top
    row is the shape's top (+y); an all-dark mask, a wrong depth map and a mask without its
    size are errors naming the file or the field."""
    from PIL import Image

    from clnlos.errors import InputFileError
    from clnlos.forward.geometry import read_mask, sample_mask

    square = np.zeros((40, 40), np.uint8)
    square[10:30, 10:30] = 255
    Image.fromarray(square).save(tmp_path / "sq.png")
    m = read_mask(tmp_path / "sq.png")
    assert m.sum() == 400
    el = sample_mask(m, 0.4, 0.4, 1e4)            # the square is the middle half: 0.2 m
    ref = sample_rectangle(0.2, 0.2, 1e4)
    assert el.area.sum() == pytest.approx(ref.area.sum()) and len(el) == len(ref)
    np.testing.assert_allclose(np.sort(el.pos, axis=0), np.sort(ref.pos, axis=0), atol=1e-12)
    top = np.zeros((20, 20), bool)
    top[:5] = True                                 # the image's top rows: y > 0
    assert np.all(sample_mask(top, 1.0, 1.0, 1e3).pos[:, 1] > 0.2)
    depth = np.where(np.arange(40)[None, :] < 20, 0.0, 0.1) * np.ones((40, 1))
    np.save(tmp_path / "d.npy", depth)
    moved = sample_mask(m, 0.4, 0.4, 1e4, depth)
    assert set(np.round(moved.pos[:, 2], 9)) == {0.0, 0.1}
    assert np.all((moved.pos[:, 2] > 0) == (moved.pos[:, 0] > 0))
    base = {"scan": {"width_m": 0.4, "points": 8},
            "time": {"bin_width_s": 20e-12, "bins": 256, "start_s": 2e-9},
            "sampling": {"density_per_m2": 1e4}}  # 1 cm cells: both grids on one lattice
    rect = {"shape": "rectangle", "size_m": [0.2, 0.2], "translate_m": [0.0, 0.0, 0.45]}
    mask = {"shape": "mask", "path": "sq.png", "size_m": [0.4, 0.4],
            "translate_m": [0.0, 0.0, 0.45]}
    a = ForwardModel(Scene.from_dict({**base, "objects": [rect]}), queue=queue).run()
    b = ForwardModel(Scene.from_dict({**base, "objects": [mask]}, base_dir=tmp_path),
                     queue=queue).run()
    assert rel_l2(b, a) < 1e-5
    Image.fromarray(np.zeros((8, 8), np.uint8)).save(tmp_path / "dark.png")
    with pytest.raises(InputFileError, match="dark.png: the mask holds no shape"):
        read_mask(tmp_path / "dark.png")
    np.save(tmp_path / "bad.npy", np.zeros((3, 3)))
    with pytest.raises(InputFileError, match="bad.npy: a depth map of the mask's shape"):
        ForwardModel(Scene.from_dict({**base, "objects": [{**mask, "depth_path": "bad.npy"}]},
                                     base_dir=tmp_path), queue=queue)
    with pytest.raises(ParameterError, match=r"objects\[0\].size_m"):
        Scene.from_dict({**base, "objects": [{"shape": "mask", "path": "sq.png"}]})
