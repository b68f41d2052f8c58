"""Issue 27 items 1-3: the bistatic transport through the slab (seed Eq. 8).

References: (a) an independent float64 numpy quadrature of Eq. 8 -- a regular Cartesian
face grid (13.3 mm cells over +-8 cm, Phi point-sampled from its own dipole code), the
BRDF evaluated from its own GGX formula on vectors (no texture), delays kept continuous
(Fourier shifts on a 2x window period, 6 GHz band, bins integrated exactly) -- against
which the kernel (rings of equal slab energy, exact annulus masses, BRDF texture, splatted
histograms) must agree within 3% in total signal and 4% in shape (relative L2 of the
normalised transient) per scan point (issue: 5% and 8%); measured 1.5% and 1.2% at the
defaults. The reference's own discretisation error, against 6.7 mm cells over +-10 cm and
a 12 GHz band: 0.2% in total, 0.2% in shape. (c) the Lambertian limit against
``clnlos simulate`` with model = "confocal" (4% total, 2% shape; measured 1.9%, 0.2%).
(b) Mitsuba 3 + mitransient is not installed here (no network): not run.
"""

import contextlib
import io
import json

import h5py
import numpy as np
import pytest

from clnlos import C0
from clnlos.app.cli import main
from clnlos.config import slab_table
from clnlos.diffusion import diffusion_psf
from clnlos.forward.bistatic import (
    BistaticTransport,
    face_quadrature,
    lobe_halfwidth_rad,
    scene_textures,
)
from clnlos.forward.model import ForwardModel
from clnlos.forward.sampling import sample_scene
from clnlos.forward.scene import Scene, TransportSettings
from clnlos.physics.slab import CDT_SLAB

BINS, DT = 128, 32e-12
DEPTH, TILT = 0.35, 5.0
GGX = {"kd": 0.0, "ks": 1.0, "alpha": 0.1, "f0": 0.9}
# patches are shifted so that the mirror direction of their centre meets the face at x = 0
SCAN_XY = [(0.0, 0.0), (0.03, 0.0), (0.06, 0.0)]  # on the mirror point, 3 and 6 cm off
COLUMNS = [2, 3, 4]
TOL_TOTAL, TOL_SHAPE = 0.03, 0.04


# ------------------------------------------------------------------ the reference (a)
def dipole_t(slab, rho, t, m_max=12):
    """T(rho, t) of the slab, 1/(m^2 s), float64 (Contini et al. 1997 image series)."""
    D, v, d, z0, ze = slab.D, slab.v, slab.thickness_m, slab.z0, slab.ze
    t = np.asarray(t, float)
    tp = np.where(t > 0, t, 1.0)
    a = 4 * D * v * tp
    s = 0.0
    for m in range(-m_max, m_max + 1):
        z1 = (1 - 2 * m) * d - 4 * m * ze - z0
        z2 = (1 - 2 * m) * d - (4 * m - 2) * ze + z0
        s = s + z1 * np.exp(-z1 * z1 / a) - z2 * np.exp(-z2 * z2 / a)
    T = (4 * np.pi * D * v) ** -1.5 * tp ** -2.5 * np.exp(-slab.mu_a * v * tp - rho**2 / a)
    return np.where(t > 0, 0.5 * T * s, 0.0)


def ggx_pairs(n, w, kd, ks, alpha, f0):
    """f(w1, w2) for all pairs of unit directions w [E, K, 3] at normals n [E, 3]: GGX
    Cook-Torrance with Schlick Fresnel and separable Smith G, on vectors."""
    c = np.clip(np.einsum("ekc,ec->ek", w, n), 1e-9, 1)
    h = w[:, :, None, :] + w[:, None, :, :]
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    ch = np.clip(np.einsum("eijc,ec->eij", h, n), 1e-9, 1)
    cih = np.clip(np.einsum("eijc,eic->eij", h, w), 0, 1)
    a2 = alpha * alpha
    D = a2 / (np.pi * (ch * ch * (a2 - 1) + 1) ** 2)
    g1 = 2 * c / (c + np.sqrt(a2 + (1 - a2) * c * c))
    F = f0 + (1 - f0) * (1 - cih) ** 5
    return kd / np.pi + ks * D * F * g1[:, :, None] * g1[:, None, :] / (
        4 * c[:, :, None] * c[:, None, :])


def reference_tau(slab, el, albedo, brdf, scan_xy, *, bins=BINS, dt=DT, face_pitch_m=0.0133,
                  face_half_m=0.08, fine=4, f_max_hz=6e9):
    """Eq. 8 by direct sums over a regular face grid, float64: tau [scan point, bin].

    ``brdf(n, w)`` -> f [E, K, K]. Time: the slab series are sampled ``fine`` times per
    bin over a period of two windows and Fourier transformed; each leg is shifted by its
    exact delay in the Fourier domain; the bins are integrals of the band-limited series."""
    h = face_pitch_m
    u = (np.arange(int(round(2 * face_half_m / h))) + 0.5) * h - face_half_m
    ox, oy = np.meshgrid(u, u, indexing="ij")
    off = np.column_stack([ox.ravel(), oy.ravel()])
    period = 2 * bins * dt
    tf = (np.arange(2 * bins * fine) + 0.5) * (dt / fine)
    omega = 2 * np.pi * np.arange(int(f_max_hz * period) + 1) / period
    phi_hat = (h * h * dt / fine) * dipole_t(slab, np.hypot(*off.T)[:, None], tf[None]) @ \
        np.exp(-1j * np.outer(tf, omega))
    tc = (np.arange(bins) + 0.5) * dt
    basis = np.exp(1j * np.outer(omega, tc)) * (dt / period) * np.sinc(omega * dt / 2 / np.pi)[
        :, None]
    basis[1:] *= 2
    out = np.zeros((len(scan_xy), bins))
    for s, (sx, sy) in enumerate(scan_xy):
        face = np.column_stack([sx + off[:, 0], sy + off[:, 1], np.zeros(len(off))])
        dvec = face[None] - el.pos[:, None]
        dist = np.linalg.norm(dvec, axis=2)
        w = dvec / dist[..., None]
        cos_face = el.pos[:, None, 2] / dist
        cos_x = np.einsum("ekc,ec->ek", w, el.normal)
        g = np.where((cos_face > 0) & (cos_x > 0), cos_face * cos_x / dist**2, 0.0)
        F = brdf(el.normal, w) * g[:, :, None] * g[:, None, :] * (albedo * el.area)[:, None,
                                                                                    None]
        E = phi_hat[None] * np.exp(-1j * dist[..., None] / C0 * omega)
        spec = (E * (F @ E.real + 1j * (F @ E.imag))).sum(axis=(0, 1))
        out[s] = np.real(spec @ basis)
    return out


def patch_scene(material, *, transport=None, points=5, width=0.15, depth=DEPTH, size=0.04,
                bins=BINS, dt=DT, **extra):
    shift = depth * np.tan(np.radians(TILT))
    d = {"scan": {"width_m": width, "points": points},
         "time": {"bin_width_s": dt, "bins": bins},
         "objects": [{"shape": "rectangle", "size_m": [size, size],
                      "translate_m": [shift, 0.0, depth], "rotate_deg": [0, TILT, 0],
                      "material": material}],
         "slab": slab_table(CDT_SLAB), "sampling": {"density_per_m2": 1.6e4}, **extra}
    if transport is not None:
        d["transport"] = transport
    return Scene.from_dict(d)


def _shape_err(a, b):
    a, b = np.asarray(a, float) / np.sum(a), np.asarray(b, float) / np.sum(b)
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


@pytest.fixture(scope="module")
def ggx_case():
    s = patch_scene({"model": "microfacet", **GGX})
    smp = sample_scene(s)
    ref = reference_tau(CDT_SLAB, smp.elements, smp.albedo,
                        lambda n, w: ggx_pairs(n, w, **GGX), SCAN_XY)
    return s, smp, ref


def _bistatic(scene, smp, queue, dtype=np.float32):
    t = scene.transport
    return BistaticTransport(slab=scene.slab, points=scene.points, width_m=scene.width_m,
                             bins=scene.bins, bin_width_s=scene.bin_width_s,
                             textures=scene_textures(scene, t), rings=t.face_rings,
                             angles=t.face_angles, dtype=dtype, queue=queue)(smp).get()


def test_bistatic_ggx_patch_matches_float64_quadrature(ggx_case, queue, dtype):
    """Tilted GGX patch (alpha 0.1, F0 0.9), scan points on and off the mirror direction:
    the forward model of ``clnlos simulate`` with model = "bistatic"."""
    scene, smp, ref = ggx_case
    bist = patch_scene({"model": "microfacet", **GGX}, transport={"model": "bistatic"})
    fm = ForwardModel(bist, dtype=dtype, queue=queue)
    assert np.array_equal(fm.samples.elements.pos, smp.elements.pos)
    tau = fm.run()
    for i, col in enumerate(COLUMNS):
        got = tau[:, 2, col]
        assert abs(got.sum() / ref[i].sum() - 1) < TOL_TOTAL, (i, got.sum(), ref[i].sum())
        assert _shape_err(got, ref[i]) < TOL_SHAPE, i


def test_confocal_model_misplaces_the_specular_return(ggx_case, queue):
    """What the bistatic stage fixes: the confocal model of the same scene (its slab blur
    integrated over the 3 cm scan cells) puts the specular return in the wrong place -- 36%
    too dark on the mirror point, 21% too dark 3 cm from it and 25% too bright 6 cm from it
    (the reference discriminates)."""
    scene, _, ref = ggx_case
    conf = ForwardModel(scene, queue=queue).run()
    ratios = [conf[:, 2, col].sum() / ref[i].sum() for i, col in enumerate(COLUMNS)]
    assert ratios[0] < 0.7 and ratios[1] < 1 - 3 * TOL_TOTAL and ratios[2] > 1.2, ratios


def test_bistatic_lambertian_patch_matches_float64_quadrature(queue):
    s = patch_scene("lambertian")
    smp = sample_scene(s)
    ref = reference_tau(CDT_SLAB, smp.elements, smp.albedo,
                        lambda n, w: np.full((len(n), w.shape[1], w.shape[1]), 1 / np.pi),
                        SCAN_XY[::2])
    tau = _bistatic(s, smp, queue)
    for i, col in enumerate(COLUMNS[::2]):
        assert abs(tau[:, 2, col].sum() / ref[i].sum() - 1) < TOL_TOTAL
        assert _shape_err(tau[:, 2, col], ref[i]) < TOL_SHAPE


@pytest.mark.fp64
def test_face_quadrature_carries_the_slab_energy(queue):
    """The samples' masses sum, lag by lag, to Phi summed over the face (a fine grid of
    :func:`clnlos.diffusion.diffusion_psf`); equal-energy rings; kernels m_i (x) m_j."""
    q = face_quadrature(CDT_SLAB, bins=BINS, bin_width_s=DT, rings=4, angles=8, queue=queue)
    total = q.mass.sum(axis=0) * q.angles
    psf = diffusion_psf(CDT_SLAB, nt=BINS, bin_width_s=DT, ny=96, nx=96, pitch_m=0.004,
                        dtype=np.float64, queue=queue).sum(axis=(1, 2))
    n = len(total)
    assert np.allclose(total, psf[:n], rtol=2e-3, atol=1e-6 * psf.max())
    ring_energy = q.mass.sum(axis=1)
    assert np.allclose(ring_energy, ring_energy.mean(), rtol=1e-2)
    assert np.all(np.diff(q.edges[:-1]) > 0) and np.all(np.diff(q.radius) > 0)
    i, j = q.classes[3]
    assert np.allclose(q.kernels[3], np.convolve(q.mass[i], q.mass[j])[:q.kernels.shape[1]])


@pytest.mark.slow
@pytest.mark.parametrize("material", ["ggx", "lambertian"])
def test_issue_geometry_matches_float64_quadrature(queue, material):
    """The issue's scenes: a 6 cm GGX patch (alpha 0.1, F0 0.9) tilted 5 deg and a 4 cm
    Lambertian patch, 0.5 m behind the CDT slab, 16 ps bins; scan points on the mirror
    point and 3, 6, 9 cm from it; the issue's tolerances (5% total, 8% shape)."""
    mat, size = ({"model": "microfacet", **GGX}, 0.06) if material == "ggx" else (
        "lambertian", 0.04)
    kw = {"points": 7, "width": 0.21, "depth": 0.5, "size": size, "bins": 384, "dt": 16e-12}
    fm = ForwardModel(patch_scene(mat, transport={"model": "bistatic"}, **kw), queue=queue)
    brdf = (lambda n, w: ggx_pairs(n, w, **GGX)) if material == "ggx" else (
        lambda n, w: np.full((len(n), w.shape[1], w.shape[1]), 1 / np.pi))
    xy = [(0.0, 0.0), (0.03, 0.0), (0.06, 0.0), (0.09, 0.0)]
    ref = reference_tau(CDT_SLAB, fm.samples.elements, fm.samples.albedo, brdf, xy,
                        bins=384, dt=16e-12)
    tau = fm.run()
    for i, col in enumerate((3, 4, 5, 6)):
        assert abs(tau[:, 3, col].sum() / ref[i].sum() - 1) < 0.05, i
        assert _shape_err(tau[:, 3, col], ref[i]) < 0.08, i


# ------------------------------------------------------------------ (c) Lambertian limit
def _write_scene(path, model, material="lambertian"):
    path.write_text(f"""
[scan]
width_m = 0.075
points = 8
[time]
bin_width_s = {DT}
bins = {BINS}
[[objects]]
shape = "rectangle"
size_m = [0.04, 0.04]
translate_m = [0.0, 0.0, {DEPTH}]
material = "{material}"
[slab]
thickness_m = 0.0254
mu_a = 0.53
mu_s_prime = 262.0
n = 1.12
[sampling]
density_per_m2 = 4e4
[transport]
model = "{model}"
""")
    return path


def test_simulate_records_the_bistatic_transport(tmp_path):
    """``clnlos simulate`` with model = "bistatic": the capture's stages and transport."""
    scene = _write_scene(tmp_path / "s.toml", "bistatic").read_text().replace(
        "points = 8", "points = 2")
    (tmp_path / "s.toml").write_text(scene)
    out = tmp_path / "b.h5"
    assert main(["simulate", str(tmp_path / "s.toml"), "-o", str(out)]) == 0
    with h5py.File(out) as f:
        assert json.loads(f.attrs["stages"]) == [
            "lightcone:bistatic(rings=4,angles=8,texture=lambertian)"]
        assert json.loads(f.attrs["transport"]) == {"model": "bistatic",
                                                    "reason": "requested"}
        assert f["transient"][()].sum() > 0


def test_lambertian_limit_agrees_with_confocal_simulate(tmp_path, queue):
    """The simulate forward model with model = "confocal" and "bistatic", Lambertian patch
    at 0.35 m, 8 x 8 points at the study's 9.4 mm pitch."""
    runs = {}
    for model in ("confocal", "bistatic"):
        scene = Scene.from_toml(_write_scene(tmp_path / f"{model}.toml", model))
        fm = ForwardModel(scene, queue=queue)
        runs[model] = (fm.capture().transient, fm.stages)
    (conf, st_c), (bist, st_b) = runs["confocal"], runs["bistatic"]
    assert st_c == ["lightcone:lambertian", "slab_blur"]
    assert st_b == ["lightcone:bistatic(rings=4,angles=8,texture=lambertian)"]
    for y, x in ((4, 4), (0, 0), (2, 6)):
        assert abs(bist[:, y, x].sum() / conf[:, y, x].sum() - 1) < 0.04
        assert _shape_err(bist[:, y, x], conf[:, y, x]) < 0.02


def test_default_transport_is_confocal_and_unchanged(queue):
    plain = patch_scene("lambertian", points=4)
    explicit = patch_scene("lambertian", points=4, transport={"model": "confocal"})
    assert plain.transport == TransportSettings()
    a, b = ForwardModel(plain, queue=queue), ForwardModel(explicit, queue=queue)
    assert a.stages == ["lightcone:lambertian", "slab_blur"] == b.stages
    np.testing.assert_array_equal(a.run(), b.run())


# ------------------------------------------------------------------ "auto"
def test_auto_picks_bistatic_for_narrow_lobes_only(queue):
    chosen = {}
    for mat in ("lambertian", "mirror-like", "matte-dark"):
        fm = ForwardModel(patch_scene(mat, points=2, transport={"model": "auto"}), queue=queue)
        chosen[mat] = fm.stages[0].split("(")[0]
        assert fm.transport_reason.startswith("auto: ")
    assert chosen == {"lambertian": "lightcone:lambertian",
                      "mirror-like": "lightcone:bistatic",
                      "matte-dark": "lightcone:brdf-table"}


def test_auto_keeps_confocal_for_a_retro_slice_material(tmp_path, queue):
    (tmp_path / "f.csv").write_text("theta_deg,brdf\n0,100.0\n1,0.1\n90,0.1\n")
    text = _write_scene(tmp_path / "s.toml", "auto").read_text().replace(
        'material = "lambertian"', 'brdf_retro_csv = "f.csv"').replace("points = 8",
                                                                        "points = 2")
    (tmp_path / "s.toml").write_text(text)
    fm = ForwardModel(Scene.from_toml(tmp_path / "s.toml"), queue=queue)
    assert fm.transport == "confocal" and "brdf_retro_csv" in fm.transport_reason


def test_lobe_halfwidth_of_a_ggx_lobe():
    """GGX D falls to half its peak where cos^2 th = (1 - sqrt(2) a^2) / (1 - a^2) (th the
    half-vector angle); the retro slice's 1/cos^2 and G^2 move that by under 5% for small
    alpha. The outgoing-direction half width is twice the half-vector one."""
    from clnlos.brdf.models import BRDFModel, retro_slice

    for alpha in (0.02, 0.1):
        m = BRDFModel("microfacet", {"kd": 0.0, "ks": 1.0, "alpha": alpha, "f0": 1.0})
        a2 = alpha * alpha
        th_d = np.arccos(np.sqrt((1 - np.sqrt(2) * a2) / (1 - a2)))
        half = lobe_halfwidth_rad(retro_slice(m, 4096))
        assert abs(half / (2 * th_d) - 1) < 0.05, (alpha, half, 2 * th_d)
    assert lobe_halfwidth_rad(None) == pytest.approx(np.pi / 2)
    assert lobe_halfwidth_rad(np.full(64, 1 / np.pi)) == pytest.approx(np.pi / 2)


# ------------------------------------------------------------------ bad input
def _run(args):
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        rc = main(args)
    return rc, err.getvalue()


@pytest.mark.parametrize("table, needle", [
    ('model = "bistatc"', "transport.model"),
    ("face_rings = 0", "transport.face_rings"),
    ("face_angles = 64", "transport.face_angles"),
    ('texture_theta = "64"', "transport.texture_theta"),
    ("rings = 4", "transport.rings"),
])
def test_bad_transport_table_is_one_line_error(tmp_path, table, needle):
    scene = tmp_path / "s.toml"
    scene.write_text(_write_scene(tmp_path / "t.toml", "confocal").read_text().replace(
        'model = "confocal"', table))
    out = tmp_path / "o.h5"
    rc, err = _run(["simulate", str(scene), "-o", str(out)])
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert rc == 2 and len(lines) == 1 and lines[0].startswith("clnlos: error:"), err
    assert needle in lines[0]
    assert not out.exists()


def test_bistatic_needs_a_slab_and_a_full_brdf(tmp_path):
    text = _write_scene(tmp_path / "t.toml", "bistatic").read_text()
    no_slab = text.split("[slab]")[0] + "[transport]\nmodel = \"bistatic\"\n"
    (tmp_path / "a.toml").write_text(no_slab)
    rc, err = _run(["simulate", str(tmp_path / "a.toml"), "-o", str(tmp_path / "a.h5")])
    assert rc == 2 and "transport.model" in err and "[slab]" in err, err
    (tmp_path / "f.csv").write_text("theta_deg,brdf\n0,1.0\n90,0.1\n")
    retro = text.replace('material = "lambertian"', 'brdf_retro_csv = "f.csv"')
    (tmp_path / "b.toml").write_text(retro)
    rc, err = _run(["simulate", str(tmp_path / "b.toml"), "-o", str(tmp_path / "b.h5")])
    assert rc == 2 and "brdf_retro_csv" in err and err.count("\n") == 1, err
    assert not (tmp_path / "b.h5").exists()


# ------------------------------------------------------------------ bench rows (item 4)
def test_bench_rows_for_the_bistatic_stage(queue):
    from clnlos.bench.harness import Bench
    from clnlos.bench.sections import bench_bistatic

    b = Bench(queue, "tiny")
    bench_bistatic(b)
    rows = {(r["knob"], r["value"]): r for r in b.rows if r["kernel"] == "bistatic"}
    assert {("face_samples", "1x1"), ("face_samples", "2x4"), ("texture", 16),
            ("texture", 32), ("transport", "confocal (Eq. 9)")} <= set(rows)
    assert rows[("face_samples", "2x4")]["error"] < 0.1 * rows[("face_samples", "1x1")]["error"]
    assert rows[("texture", 32)]["error"] < rows[("texture", 16)]["error"]
    # the confocal approximation is further from Eq. 8 than the coarse quadratures
    assert rows[("transport", "confocal (Eq. 9)")]["error"] > 10 * rows[
        ("face_samples", "2x4")]["error"]
    assert all(r["median_s"] > 0 and r["pairs"] >= 1 for r in rows.values())
