"""Physics invariances (issue 42): what a capture or a volume says about a scene must not
depend on how finely it was sampled or in which file it arrived.

* the slab blur: energy per scan point and peak path independent of the scan pitch, equal to
  the bistatic transport's on a Lambertian plate and below the slab-free capture's;
* the slab SNR: the depth of a noise-free capture independent of the bins it is rebinned to
  and of columns moved by fractions of a bin (y-tal's first and last bounces);
* BRDF textures: what the transports read keeps the model's energy at any resolution;
* readers: a scan grid moved across the scene moves the reconstruction by the same amount
  in every format, and a non-square scan agrees with the square one on the shared cells.

Stated tolerances are measured margins, not fits: each test names what it measured.
"""

import json
import warnings

import h5py
import numpy as np
import pytest
import scipy.io
from hypothesis import given, settings
from hypothesis import strategies as st

from clnlos.io.formats.mat import lct_rect_data
from clnlos import C0
from clnlos.app.cli import main
from clnlos.app.simulate import simulate_to_file
from clnlos.brdf.mlp import directional_albedo
from clnlos.brdf.models import BRDFModel
from clnlos.brdf.texture import lookup_numpy
from clnlos.config import ReconstructionConfig, slab_table
from clnlos.forward.blur import confocal_psf
from clnlos.forward.model import ForwardModel
from clnlos.forward.scene import Scene
from clnlos.inverse.pipeline import reconstruct
from clnlos.io.files import read_capture
from clnlos.io.formats.tal import write_tal
from clnlos.physics.slab import CDT_SLAB

# a chrome-like lobe: the five-parameter fit of the shared chrome data (issue 42), whose
# normal-incidence spike point samples read as 1e4 / sr
CHROME = {"model": "five-param", "kb": 9923.285195509658, "kr": 1.0645694077655958,
          "b": -23.212968634243573, "a_exp": 0.10604816512397594,
          "kd": 0.00025655523816499304}


def _plate_scene(points, *, size=1.0, depth=0.4, width=0.3, bins=96, bin_width=64e-12,
                 slab=True, transport="confocal", density=2e4, material="lambertian"):
    table = {"seed": 0, "scan": {"width_m": width, "points": points},
             "time": {"bin_width_s": bin_width, "bins": bins},
             "objects": [{"shape": "rectangle", "size_m": [size, size],
                          "translate_m": [0.0, 0.0, depth], "material": material}],
             "sampling": {"density_per_m2": density},
             "transport": {"model": transport}}
    if slab:
        table["slab"] = slab_table(CDT_SLAB)
    return Scene.from_dict(table, text=json.dumps(table))


def _energy_and_peak(scene, queue):
    """(mean time-integrated signal per scan point, round-trip path of the centre point's
    peak, m)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tau = ForwardModel(scene, queue=queue).run().astype(np.float64)
    n = tau.shape[1]
    c = slice((n - 1) // 2, n // 2 + 1)
    centre = tau[:, c, c].mean(axis=(1, 2))
    return tau.sum(axis=0).mean(), (np.argmax(centre) + 0.5) * scene.bin_width_s * C0


# --------------------------------------------------------------------- item 1: the slab blur
@settings(max_examples=12, deadline=None)
@given(pitch=st.floats(0.004, 0.15), nt=st.integers(24, 48))
def test_blur_energy_per_lag_does_not_depend_on_the_pitch(queue, pitch, nt):
    """Phi * Phi summed over a grid wide enough to hold it: its energy per lag is the same at
    any scan pitch from 4 mm to 15 cm (the cell integral of the blur; point samples times
    pitch^2 put up to 60x the light in a cell narrower than the blur's core). Reference:
    a 5 mm grid; float32 within 2e-4, the grid's truncation within 1e-3."""
    dt = 48e-12
    ref = confocal_psf(CDT_SLAB, (nt, 40, 40), bin_width_s=dt, pitch_m=0.005,
                       queue=queue).get().astype(np.float64).sum(axis=(1, 2))
    n = max(2, int(np.ceil(0.2 / pitch)))  # the padded grid reaches >= 0.2 m each way
    got = confocal_psf(CDT_SLAB, (nt, n, n), bin_width_s=dt, pitch_m=pitch,
                       queue=queue).get().astype(np.float64).sum(axis=(1, 2))
    np.testing.assert_allclose(got, ref, rtol=2e-3, atol=1e-3 * ref.max())


@pytest.fixture(scope="module")
def pitch_sweep(queue):
    """The issue's plate (1 m, 0.4 m behind the CDT slab, 0.3 m scan): confocal at 1, 3, 5,
    10 cm pitch, bistatic at 5 and 10 cm, and the slab-free capture at 3 cm."""
    conf = {p: _energy_and_peak(_plate_scene(n), queue)
            for p, n in ((0.01, 30), (0.03, 10), (0.05, 6), (0.1, 3))}
    bist = {p: _energy_and_peak(_plate_scene(n, transport="bistatic"), queue)
            for p, n in ((0.05, 6), (0.1, 3))}
    free = _energy_and_peak(_plate_scene(10, slab=False), queue)
    return conf, bist, free


def test_energy_and_peak_path_do_not_depend_on_the_pitch(pitch_sweep):
    """Confocal transport: the mean signal per scan point within 1% of the 1 cm pitch's at
    3, 5 and 10 cm (measured 0.2%; main: 1.29x at 3 cm, 4.2x at 5 cm, 60x at 10 cm), the
    centre point's peak path within one bin of it (main: 6 bins short at 10 cm)."""
    conf, _, _ = pitch_sweep
    e0, p0 = conf[0.01]
    for pitch, (e, p) in conf.items():
        assert e == pytest.approx(e0, rel=0.01), (pitch, e, e0)
        assert abs(p - p0) <= 64e-12 * C0 + 1e-9, (pitch, p, p0)


def test_confocal_and_bistatic_agree_on_a_lambertian_plate(pitch_sweep):
    """The two transports of the same Lambertian plate: energy per scan point within 2%
    (measured 0.5%) at 5 and 10 cm pitch, the same peak bin; both below the slab-free
    capture's (the slab only loses light; main's confocal at 10 cm was 2.7x above it)."""
    conf, bist, free = pitch_sweep
    for pitch, (e, p) in bist.items():
        assert e == pytest.approx(conf[pitch][0], rel=0.02), (pitch, e, conf[pitch][0])
        assert abs(p - conf[pitch][1]) <= 64e-12 * C0 + 1e-9
    assert all(e < free[0] for e, _ in (*conf.values(), *bist.values()))


# ------------------------------------------------------------------ item 2: the slab SNR
@pytest.fixture(scope="module")
def plate_capture(tmp_path_factory, queue):
    """A 0.3 m Lambertian plate 0.30 m behind the CDT slab, 16 x 16 points over 0.3 m,
    256 bins of 32 ps, noise-free, slab recorded."""
    d = tmp_path_factory.mktemp("plate")
    scene = _plate_scene(16, size=0.3, depth=0.3, bins=256, bin_width=32e-12, density=4e5)
    simulate_to_file(scene, d / "c.h5", queue=queue)
    return read_capture(d / "c.h5"), d


def _depth(rec) -> float:
    v = rec.volume
    return (int(np.argmax(v.max(axis=(1, 2)))) + 0.5) * rec.extents["voxel_depth_m"]


@pytest.mark.parametrize("bins", [48, 77, 100, 200])
def test_depth_does_not_depend_on_the_bins(queue, plate_capture, bins):
    """The noise-free plate at 0.30 m rebinned to 48-200 bins: its depth within one voxel
    plus 1 cm (measured within one voxel; main, at the slab SNR cap 1e10: 0.422, 0.678,
    0.608, 0.611 m)."""
    cap, _ = plate_capture
    cfg = ReconstructionConfig(slab=cap.recorded_slab()[0], bins=bins).validate()
    rec = reconstruct(cap, cfg, device=queue)
    assert abs(_depth(rec) - 0.30) <= rec.extents["voxel_depth_m"] + 0.01, (bins, _depth(rec))


def _with_bounces(src, dst, origin):
    """A y-tal capture moved later by the flight 2 |origin - p| of each scan point (split
    between two bins, as a renderer binning it would) and flagged
    t_accounts_first_and_last_bounces."""
    with h5py.File(src) as f:
        H = f["H"][()].astype(np.float64)
        grid = f["sensor_grid_xyz"][()]
        dt = float(f["delta_t"][()])
    shift = 2 * np.linalg.norm(grid - origin, axis=-1) / dt
    k0 = np.floor(shift).astype(int)
    frac = shift - k0
    out = np.zeros((H.shape[0] + k0.max() + 2,) + H.shape[1:])
    t = np.arange(H.shape[0])
    for i, j in np.ndindex(H.shape[1:]):
        out[t + k0[i, j], i, j] += H[:, i, j] * (1 - frac[i, j])
        out[t + k0[i, j] + 1, i, j] += H[:, i, j] * frac[i, j]
    with h5py.File(src) as f, h5py.File(dst, "w") as g:
        for k in f:
            if k != "H":
                f.copy(k, g)
        g["H"] = out.astype(np.float32)
        for k in ("laser_xyz", "sensor_xyz", "t_accounts_first_and_last_bounces"):
            del g[k]
        g["laser_xyz"] = g["sensor_xyz"] = np.asarray(origin, np.float64)
        g["t_accounts_first_and_last_bounces"] = np.bool_(True)


@pytest.mark.parametrize("origin", [(1.0, 0.5, -0.3), (-0.8, 0.3, -0.5)])
def test_depth_does_not_depend_on_the_first_and_last_bounces(queue, plate_capture, origin):
    """The plate's y-tal capture with the flight from a laser/sensor at ``origin`` added and
    removed again by the reader (columns moved by different fractions of a bin): depth
    within one voxel plus 1 cm of the capture without it (main: 2.26 m from
    (1, 0.5, -0.3), 0.309 m from (-0.8, 0.3, -0.5))."""
    cap, d = plate_capture
    tal = d / "t.h5"
    write_tal(tal, cap.transient, bin_width_s=cap.bin_width_s, start_s=0.0,
              scan_width_m=cap.scan_width_m, scene_info={"clnlos": {"slab": cap.attrs["slab"]}})
    _with_bounces(tal, d / "b.h5", np.asarray(origin))
    moved = read_capture(d / "b.h5")
    cfg = ReconstructionConfig(slab=cap.recorded_slab()[0]).validate()
    ref = reconstruct(cap, cfg, device=queue)
    rec = reconstruct(moved, cfg, device=queue)
    assert abs(_depth(rec) - _depth(ref)) <= ref.extents["voxel_depth_m"] + 0.01, \
        (_depth(rec), _depth(ref))


# ------------------------------------------------------------------ item 3: BRDF textures
@pytest.fixture(scope="module")
def chrome_textures(tmp_path_factory):
    """`clnlos brdf texture` of the chrome-like fit at 2, 16 and 64 nodes per axis, and with
    a 2-node retro slice."""
    from clnlos.brdf.store import save_model

    d = tmp_path_factory.mktemp("tex")
    spec = dict(CHROME)
    model = BRDFModel(spec.pop("model"), spec)
    save_model(d / "m.h5", model, {}, {})
    for name, extra in (("t2", ["--resolution", "2"]), ("t16", ["--resolution", "16"]),
                        ("t64", ["--resolution", "64"]), ("r2", ["--retro", "2"])):
        assert main(["brdf", "texture", str(d / "m.h5"), "-o", str(d / f"{name}.h5"),
                     *extra]) == 0
    return model, d


def _obj(material):
    from clnlos.forward.scene import SceneObject

    return SceneObject(shape="rectangle", material=material)


@pytest.mark.parametrize("name", ["t2", "t16", "t64"])
def test_bistatic_texture_keeps_the_models_albedo(chrome_textures, name):
    """What the bistatic transport reads from a texture file of any resolution: its
    directional albedo within 5% of the model's at every incidence (measured 0.7% after
    the check; main: 413x at 64^3, 7,500x at 16^3, 2.4e8x at 2^3)."""
    from clnlos.forward.bistatic import material_texture

    model, d = chrome_textures
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tex = material_texture(_obj(f"{name}.h5"), d, 64, 64)

    def lookup(ti, pi_, ts, ps):
        return lookup_numpy(tex, np.column_stack([ti, pi_, ts, ps]))

    want = directional_albedo(model)
    np.testing.assert_allclose(directional_albedo(lookup), want, rtol=0,
                               atol=0.05 * want.max())


@pytest.mark.parametrize("name", ["t2", "t64", "r2"])
def test_confocal_retro_slice_keeps_the_models_energy(chrome_textures, name):
    """What the confocal transport reads (the retro slice on its 256 nodes) from any texture
    file: int f(t, t) sin t cos t dt within 2% of the model's (measured 0.3%; main: 50x
    from the 256-node slice, 1.9e6x from a 2-node one)."""
    from clnlos.forward.sampling import material_retro

    model, d = chrome_textures
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = material_retro(_obj(f"{name}.h5"), d)
    edges = np.concatenate([[0.0], np.geomspace(1e-6, np.pi / 2, 4096)])
    t = 0.5 * (edges[1:] + edges[:-1])
    w = np.sin(t) * np.cos(t) * np.diff(edges)
    f = np.nan_to_num(model(t, 0 * t, t, 0 * t))
    got = np.interp(t, np.linspace(0, np.pi / 2, len(r)), r)
    assert (got * w).sum() == pytest.approx((f * w).sum(), rel=0.02)


# -------------------------------------------------------- items 4, 5: readers and extents
@pytest.fixture(scope="module")
def wide_capture(tmp_path_factory, queue):
    """A 6 cm plate at (0.08, -0.04, 0.30), no slab, 24 x 24 points over 0.48 m (2 cm
    pitch), 256 bins of 16 ps."""
    d = tmp_path_factory.mktemp("wide")
    table = {"seed": 0, "scan": {"width_m": 0.48, "points": 24},
             "time": {"bin_width_s": 16e-12, "bins": 256},
             "objects": [{"shape": "rectangle", "size_m": [0.06, 0.06],
                          "translate_m": [0.08, -0.04, 0.3]}]}
    simulate_to_file(Scene.from_dict(table, text=json.dumps(table)), d / "w.h5",
                     queue=queue)
    return read_capture(d / "w.h5"), d


def _crop_files(cap, d, y0, x0, n=12):
    """The n x n window of the wide capture from cell (y0, x0), in every format: (path,
    the window's centre (x, y) that the format can carry, else None)."""
    sub = np.ascontiguousarray(cap.transient[:, y0:y0 + n, x0:x0 + n])
    p = 0.02
    cx, cy = (x0 + n / 2) * p - 0.24, (y0 + n / 2) * p - 0.24
    tag = f"{y0}_{x0}"
    out = {}
    with h5py.File(d / f"c{tag}.h5", "w") as f:  # the attributes as the format states them
        f["transient"] = sub
        f.attrs.update({"bin_width_s": 16e-12, "start_s": 0.0, "scan_width_m": n * p,
                        "format": "clnlos-capture-1", "scan_center_m": [cx, cy]})
    out["clnlos"] = (d / f"c{tag}.h5", (cx, cy))
    write_tal(d / f"t{tag}.h5", sub, bin_width_s=16e-12, start_s=0.0, scan_width_m=n * p)
    with h5py.File(d / f"t{tag}.h5", "r+") as f:  # the grid where it was on the wall
        for k in ("sensor_grid_xyz", "laser_grid_xyz"):
            g = f[k][()]
            g[..., 0] += cx
            g[..., 1] += cy
            f[k][...] = g
    out["y-tal"] = (d / f"t{tag}.h5", (cx, cy))
    scipy.io.savemat(d / f"m{tag}.mat", {"rect_data": lct_rect_data(sub),
                                         "width": n * p / 2, "bin_resolution": 16e-12})
    out["mat"] = (d / f"m{tag}.mat", None)
    np.save(d / f"n{tag}.npy", sub)
    out["npy"] = (d / f"n{tag}.npy", None)
    return out


def _peak_xy(rec):
    v, e = rec.volume, rec.extents
    k = np.unravel_index(int(np.argmax(v)), v.shape)
    return (e["x_min_m"] + (k[2] + 0.5) * e["voxel_lateral_m"],
            e["y_min_m"] + (k[1] + 0.5) * e["voxel_lateral_m"])


def test_moving_the_scan_moves_the_volume_alike_in_every_reader(queue, wide_capture):
    """Two 12 x 12 windows of one capture, 8 and 4 cells apart: in the formats that carry
    the grid's position (clnlos, y-tal) the plate is found at the same place on the wall
    (within one cell; main: y-tal at (0.03, -0.07) for (0.07, -0.03)); in those that do
    not (.mat, .npy: scan coordinates) it moves by the windows' offset; every reader gives
    the same depth."""
    cap, d = wide_capture
    a, b = _crop_files(cap, d, 4, 8), _crop_files(cap, d, 0, 4)
    cfg = ReconstructionConfig(scan_width_m=0.24, bin_width_s=16e-12).validate()
    depths = set()
    for fmt in a:
        ra, rb = (reconstruct(read_capture(f[fmt][0]), cfg, device=queue) for f in (a, b))
        (xa, ya), (xb, yb) = _peak_xy(ra), _peak_xy(rb)
        if a[fmt][1] is not None:  # world coordinates
            assert abs(xa - xb) < 0.021 and abs(ya - yb) < 0.021, (fmt, xa, ya, xb, yb)
            assert abs(xa - 0.08) < 0.021 and abs(ya + 0.04) < 0.021, (fmt, xa, ya)
        else:  # scan coordinates: the plate is 4 cells further right and down in window b
            assert abs((xb - xa) - 0.08) < 0.021 and abs((yb - ya) - 0.08) < 0.021, fmt
        depths.add(round(_depth(ra), 6))
    assert len(depths) == 1, depths


def test_non_square_scan_agrees_with_the_square_one(queue, wide_capture, tmp_path):
    """The square 12 x 12 window and the 12 x 8 part of it (columns 0-7, written by
    write_capture with its centre): the same pitch, the x and y of the shared cells, the
    same plate position and depth (main: a non-square capture's lone scan width read as
    the x side whatever it measured; no grid centre)."""
    from clnlos.io.files import write_capture

    cap, _ = wide_capture
    win = cap.transient[:, 10:22, 10:22]
    write_capture(tmp_path / "sq.h5", win, bin_width_s=16e-12, start_s=0.0,
                  scan_width_m=0.24, scan_center_m=(0.08, -0.04))
    write_capture(tmp_path / "ns.h5", win[:, :, :8], bin_width_s=16e-12, start_s=0.0,
                  scan_width_m=0.16, scan_center_m=(0.04, -0.04))
    cfg = ReconstructionConfig().validate()
    sq, ns = (reconstruct(read_capture(tmp_path / f), cfg, device=queue)
              for f in ("sq.h5", "ns.h5"))
    e1, e2 = sq.extents, ns.extents
    assert e2["voxel_lateral_m"] == pytest.approx(e1["voxel_lateral_m"])
    assert e2["x_min_m"] == pytest.approx(e1["x_min_m"])
    assert (e2["y_min_m"], e2["y_max_m"]) == pytest.approx((e1["y_min_m"], e1["y_max_m"]))
    assert np.allclose(_peak_xy(ns), _peak_xy(sq), atol=0.021), (_peak_xy(ns), _peak_xy(sq))
    assert abs(_depth(ns) - _depth(sq)) <= e1["voxel_depth_m"]
