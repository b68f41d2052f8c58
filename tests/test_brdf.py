"""BRDF: readers, analytic models, fitting, the MLP, textures and kernels/brdf.cl lookups."""

import json

import numpy as np
import pytest

from clnlos.app.cli import main
from clnlos.brdf.data import (
    MerlBRDF,
    agreement,
    half_diff,
    read_gonio_csv,
    read_pbrt_brdf,
    write_merl_binary,
)
from clnlos.brdf.fit import fit_analytic
from clnlos.brdf.mlp import MLPConfig, train_mlp
from clnlos.brdf.models import BRDFModel, retro_slice
from clnlos.brdf.store import load_model
from clnlos.brdf.texture import lookup_numpy, read_texture, tabulate, write_texture
from clnlos.brdf.texture_lookup import TextureLookup
from clnlos.errors import InputFileError, ParameterError

HEADER = "theta_i_deg,phi_i_deg,theta_s_deg,phi_s_deg,brdf\n"


def _synthetic_csv(path, model, n=600, seed=0):
    rng = np.random.default_rng(seed)
    ti = rng.choice([30.0, 45.0, 60.0], n)
    ts = rng.uniform(0, 85, n)
    ps = rng.uniform(0, 360, n)
    f = model(np.radians(ti), 0 * ti, np.radians(ts), np.radians(ps))
    rows = "".join(f"{a},0,{b},{c},{d}\n" for a, b, c, d in zip(ti, ts, ps, f, strict=True))
    path.write_text("# material: synthetic\n" + HEADER + rows)
    return path


def test_models_reciprocal_and_nonnegative():
    rng = np.random.default_rng(1)
    ti, ts = rng.uniform(0, 1.5, 500), rng.uniform(0, 1.5, 500)
    pi_, ps = rng.uniform(-np.pi, np.pi, 500), rng.uniform(-np.pi, np.pi, 500)
    for m in (BRDFModel("lambert", {"kd": 0.8}), BRDFModel("phong", {"shininess": 30.0}),
              BRDFModel("minnaert", {"k": 1.4}), BRDFModel("microfacet", {"alpha": 0.1}),
              BRDFModel("microfacet", {"alpha": 0.2, "distribution": "beckmann"}),
              BRDFModel("five-param", {})):
        a, b = m(ti, pi_, ts, ps), m(ts, ps, ti, pi_)
        assert np.all(a >= 0) and np.all(np.isfinite(a))
        np.testing.assert_allclose(a, b, rtol=1e-9, err_msg=m.name)


def test_lambert_albedo_by_quadrature():
    m = BRDFModel("lambert", {"kd": 0.7})
    th = (np.arange(400) + 0.5) / 400 * np.pi / 2
    # albedo = int f cos(ts) dw = 2 pi int f cos sin dtheta
    assert 2 * np.pi * np.sum(m(0.3, 0, th, 0) * np.cos(th) * np.sin(th)) * (np.pi / 800) == \
        pytest.approx(0.7, rel=1e-4)


def test_mirror_like_retro_slice_is_finite_and_peaked():
    """A lobe far narrower than a node (alpha 0.001: 0.06 deg against 0.35 deg nodes): the
    slice is peaked at normal incidence and, read linearly between its nodes, keeps the
    model's energy int f(t, t) sin t cos t dt within 1% at 256 nodes and 2% at 16 (point
    samples: 3.2e5 at the first node, 40x the energy at 256 nodes)."""
    from clnlos.brdf.texture import retro_errors

    m = BRDFModel("microfacet", {"alpha": 0.001, "f0": 0.95})
    r = retro_slice(m, 256)
    assert np.all(np.isfinite(r)) and r[0] > 1e3 and r[-1] < 1e-3 * r[0]
    assert retro_errors(r, m)[0] < 0.01 and retro_errors(retro_slice(m, 16), m)[0] < 0.02


@pytest.mark.parametrize("content,needle", [
    ("theta_i,phi_i,theta_s,phi_s,brdf\n30,0,30,180,0.1\n", "columns"),
    (HEADER + "30,0,30,180,nan\n", "NaN"),
    (HEADER + "30,0,30,180,-0.1\n", "negative"),
    (HEADER + "95,0,30,180,0.1\n", "zenith"),
    (HEADER + "30,0,30\n", "5 values"),
    (HEADER, "no data"),
])
def test_bad_csv_files(tmp_path, content, needle):
    p = tmp_path / "bad.csv"
    p.write_text(content)
    with pytest.raises(InputFileError, match=needle):
        read_gonio_csv(p)


def test_pbrt_reader(tmp_path):
    p = tmp_path / "x.brdf"
    p.write_text("# comment\n3\n500 550 600\n0.5 0 0.5 3.14159 1 2 3\n0.2 0 0.4 1.0 4 6 8\n")
    s = read_pbrt_brdf(p, 575.0)
    np.testing.assert_allclose(s.brdf, [2.5, 7.0])
    assert s.theta_i[0] == 0.5
    with pytest.raises(InputFileError, match="wavelength"):
        read_pbrt_brdf(p, 800.0)


def test_merl_round_trip(tmp_path):
    th, td, pd = np.meshgrid((np.arange(90) + 0.5) / 90, (np.arange(90) + 0.5) / 90,
                             (np.arange(180) + 0.5) / 180, indexing="ij")
    g = 0.1 + th + 2 * td + 3 * pd
    rgb = np.stack([g, 2 * g, 3 * g])
    write_merl_binary(tmp_path / "m.binary", rgb)
    m = MerlBRDF(tmp_path / "m.binary", channel=1)
    # a direction pair whose half/difference angles are known
    ti, ts = np.radians(40.0), np.radians(40.0)
    val = m(ti, 0.0, ts, np.pi)  # mirror pair: theta_h = 0, theta_d = 40 deg
    h, d, _ = half_diff(ti, 0.0, ts, np.pi)
    assert h == pytest.approx(0, abs=1e-7) and d == pytest.approx(ti)
    idd = int(ti / (np.pi / 2) * 90)
    assert val == pytest.approx(2 * g[0, idd, int(np.mod(_, np.pi) / np.pi * 180)], rel=1e-12)
    (tmp_path / "short.binary").write_bytes(b"\x00" * 20)
    with pytest.raises(InputFileError, match="MERL"):
        MerlBRDF(tmp_path / "short.binary")


def test_fit_recovers_synthetic_phong(tmp_path):
    truth = BRDFModel("phong", {"kd": 0.2, "ks": 0.8, "shininess": 40.0})
    s = read_gonio_csv(_synthetic_csv(tmp_path / "p.csv", truth))
    r = fit_analytic("phong", s)
    assert r.metrics["train_agreement_pct"] > 99.0
    assert r.model.params["shininess"] == pytest.approx(40.0, rel=0.05)
    with pytest.raises(ParameterError, match="model"):
        fit_analytic("cubic", s)


def test_mlp_is_deterministic_positive_and_reciprocal(tmp_path):
    truth = BRDFModel("phong", {"kd": 0.3, "ks": 0.7, "shininess": 10.0})
    s = read_gonio_csv(_synthetic_csv(tmp_path / "p.csv", truth, n=300))
    cfg = MLPConfig(recipe="improved", epochs=400, seed=3, members=2)
    m1, _ = train_mlp(s, cfg)
    m2, _ = train_mlp(s, cfg)
    a = m1(s.theta_i, s.phi_i, s.theta_s, s.phi_s)
    np.testing.assert_array_equal(a, m2(s.theta_i, s.phi_i, s.theta_s, s.phi_s))
    assert np.all(a > 0) and agreement(a, s.brdf) > 80
    # reciprocity is built into the improved encoding, for any directions
    rng = np.random.default_rng(9)
    ti, ts = rng.uniform(0, 1.55, 500), rng.uniform(0, 1.55, 500)
    pi_, ps = rng.uniform(-np.pi, np.pi, 500), rng.uniform(-np.pi, np.pi, 500)
    np.testing.assert_allclose(m1(ti, pi_, ts, ps), m1(ts, ps, ti, pi_), rtol=1e-5)
    # and it survives saving and loading
    from clnlos.brdf.store import save_model

    save_model(tmp_path / "m.h5", m1, {}, {})
    m3, _ = load_model(tmp_path / "m.h5")
    np.testing.assert_array_equal(m3(ti, pi_, ts, ps), m1(ti, pi_, ts, ps))


def _hemisphere_albedo(model, theta_i, n=400):
    """Independent check of a(theta_i): midpoint rule on a (theta_o, phi_o) grid."""
    to = (np.arange(n) + 0.5) / n * np.pi / 2
    po = (np.arange(2 * n) + 0.5) / (2 * n) * 2 * np.pi
    T, P = np.meshgrid(to, po, indexing="ij")
    f = model(np.full(T.size, theta_i), np.zeros(T.size), T.ravel(), P.ravel()).reshape(T.shape)
    return float(np.sum(f * np.cos(T) * np.sin(T)) * (np.pi / 2 / n) * (2 * np.pi / (2 * n)))


def test_albedo_quadrature_integrates_broad_and_narrow_lobes():
    from clnlos.brdf.mlp import directional_albedo

    lam = BRDFModel("lambert", {"kd": 0.7})
    np.testing.assert_allclose(directional_albedo(lam), 0.7, rtol=2e-3)
    broad = BRDFModel("microfacet", {"alpha": 0.3, "f0": 0.9, "kd": 0.0})
    a = directional_albedo(broad, theta_i_deg=(10, 40))
    np.testing.assert_allclose(a, [_hemisphere_albedo(broad, np.radians(t)) for t in (10, 40)],
                               rtol=0.01)
    # a 0.3 degree wide lobe (the Starlink panel's) is resolved: the same albedo as a broad one
    narrow = BRDFModel("microfacet", {"alpha": 0.005, "f0": 0.9, "kd": 0.0})
    an = directional_albedo(narrow, theta_i_deg=(10, 40))
    ab = directional_albedo(BRDFModel("microfacet", {"alpha": 0.05, "f0": 0.9, "kd": 0.0}),
                            theta_i_deg=(10, 40))
    np.testing.assert_allclose(an, ab, rtol=0.03)


@pytest.mark.slow
def test_mlp_albedo_never_exceeds_one_even_when_the_data_do(tmp_path):
    """Data with albedo 1.3 (a miscalibrated measurement): the fit keeps a <= 1."""
    truth = BRDFModel("lambert", {"kd": 1.3})
    s = read_gonio_csv(_synthetic_csv(tmp_path / "l.csv", truth, n=300))
    model, log = train_mlp(s, MLPConfig(epochs=300, members=1, seed=0))
    assert log["max_albedo_before_cap"] > 1.05
    for t in (0.0, 0.6, 1.2):
        assert _hemisphere_albedo(model, t) <= 1.0 + 5e-3


@pytest.mark.slow
def test_mlp_keeps_a_specular_peak_that_the_seed_recipe_flattens(tmp_path):
    truth = BRDFModel("microfacet", {"alpha": 0.08, "f0": 0.9, "kd": 0.05})
    rng = np.random.default_rng(4)
    n = 900
    ti = rng.choice([20.0, 40.0, 60.0], n)
    # half the samples near the mirror direction, as a goniometer scan of a glossy sample does
    ts = np.where(rng.random(n) < 0.5, ti + rng.normal(0, 4, n), rng.uniform(0, 85, n))
    ts = np.clip(ts, 0, 89)
    ps = np.where(rng.random(n) < 0.5, 180 + rng.normal(0, 4, n), rng.uniform(0, 360, n))
    f = truth(np.radians(ti), 0 * ti, np.radians(ts), np.radians(ps))
    rows = "".join(f"{a},0,{b},{c},{d}\n" for a, b, c, d in zip(ti, ts, ps, f, strict=True))
    (tmp_path / "g.csv").write_text(HEADER + rows)
    s = read_gonio_csv(tmp_path / "g.csv")
    assert s.brdf.max() > 20
    k = int(np.argmax(s.brdf))
    good, _ = train_mlp(s, MLPConfig(epochs=1500, members=1))
    seed, _ = train_mlp(s, MLPConfig(recipe="seed", epochs=1500))
    args = (s.theta_i, s.phi_i, s.theta_s, s.phi_s)
    assert abs(good(*args)[k] / s.brdf[k] - 1) < 0.25
    assert agreement(good(*args), s.brdf) > 90
    assert agreement(good(*args), s.brdf) > agreement(seed(*args), s.brdf) + 10


def test_precision_recorded_and_metrics_use_values_above_it(tmp_path):
    from clnlos.brdf.data import significance_floor
    from clnlos.brdf.fit import metrics_for

    rows = "30,0,10,180,0.004\n30,0,20,180,0.000\n30,0,30,180,2.5\n30,0,40,180,0.75\n"
    (tmp_path / "q.csv").write_text(HEADER + rows)
    s = read_gonio_csv(tmp_path / "q.csv")
    assert s.meta["precision"] == pytest.approx(0.01) and significance_floor(s) == 0.01
    (tmp_path / "h.csv").write_text("# precision: 0.5\n" + HEADER + rows)
    h = read_gonio_csv(tmp_path / "h.csv")
    assert h.meta["precision"] == 0.5 and h.meta["precision_source"] == "file header"
    (tmp_path / "fine.csv").write_text(HEADER + "30,0,10,180,0.0000123\n")
    assert read_gonio_csv(tmp_path / "fine.csv").meta["precision"] == pytest.approx(1e-6)
    (tmp_path / "bad.csv").write_text("# precision: lots\n" + HEADER + rows)
    with pytest.raises(InputFileError, match="precision"):
        read_gonio_csv(tmp_path / "bad.csv")

    def wrong_below(ti, pi_, ts, ps):  # exact above 0.01, 100x off below
        return np.where(np.degrees(ts) > 25, np.interp(np.degrees(ts), [30, 40], [2.5, 0.75]),
                        1.0)

    m = metrics_for(wrong_below, s, h)
    assert m["train_agreement_pct"] == pytest.approx(100) and m["train_samples"] == 2
    assert m["train_samples_below_floor"] == 2 and m["train_floor_per_sr"] == 0.01
    assert m["test_floor_per_sr"] == 0.5 and m["test_samples"] == 2
    assert m["train_peak_error_pct"] == pytest.approx(0, abs=1e-9)


def test_brdf_evaluate_cli_scores_interpolation_and_extrapolation(tmp_path, capsys):
    truth = BRDFModel("phong", {"kd": 0.2, "ks": 0.8, "shininess": 40.0})
    d = tmp_path / "sets"
    d.mkdir()
    _synthetic_csv(d / "a_gonio.csv", truth, seed=1)
    _synthetic_csv(d / "a_test.csv", truth, seed=2)
    (d / "lonely_gonio.csv").write_text((d / "a_gonio.csv").read_text())
    out = tmp_path / "eval.csv"
    assert main(["brdf", "evaluate", str(d), "-o", str(out), "--models", "phong",
                 "five-param", "--splits", "2"]) == 0
    rows = json.loads(out.with_suffix(".json").read_text())
    # 2 interp splits + 1 extrap, for each of 2 models, only the complete set
    assert len(rows) == 6 and {r["material"] for r in rows} == {"a"}
    phong = [r for r in rows if r["model"] == "phong"]
    assert all(r["agreement_pct"] > 99 for r in phong)
    assert "| a | interp | phong |" in capsys.readouterr().out
    assert main(["brdf", "evaluate", str(tmp_path / "nothing"), "-o",
                 str(tmp_path / "e2.csv")]) == 2


@pytest.mark.parametrize("path", ["buffer", "image"])
def test_texture_lookup_matches_numpy(queue, dtype, path, tmp_path):
    if path == "image" and (dtype == np.float64 or not queue.device.image_support):
        pytest.skip("image path is float32 on devices with images")
    m = BRDFModel("phong", {"kd": 0.3, "ks": 0.7, "shininess": 10.0})
    tex = tabulate(m, 24, 20, 64, provenance={"model": "phong"})
    write_texture(tmp_path / "t.h5", tex)
    tex = read_texture(tmp_path / "t.h5")
    rng = np.random.default_rng(2)
    a = np.column_stack([rng.uniform(0, np.pi / 2, 2000), rng.uniform(-4, 4, 2000),
                         rng.uniform(0, np.pi / 2, 2000), rng.uniform(-4, 4, 2000)])
    # hard cases: exactly 0 and 90 degrees, azimuth wrap-around at +-180
    a[:4] = [[0, 0, 0, 0], [np.pi / 2, 0, np.pi / 2, np.pi], [0.5, np.pi, 0.5, -np.pi],
             [0.3, -3.1, 0.3, 3.1]]
    ref = lookup_numpy(tex.texture, a)
    out = TextureLookup(tex, path=path, dtype=dtype, queue=queue)(a)
    tol = 1e-5 if dtype == np.float32 else 1e-12
    assert np.abs(out - ref).max() <= tol * ref.max()
    # delta phi = 2 pi is delta phi = 0; -3.1 -> 3.1 is 6.2 rad, i.e. 2 pi - 6.2
    same = lookup_numpy(tex.texture, [[0.5, 0.0, 0.5, 0.0], [0.3, 0.0, 0.3, 2 * np.pi - 6.2]])
    np.testing.assert_allclose(out[2:4], same, rtol=tol, atol=tol * ref.max())


def test_texture_resolution_converges():
    m = BRDFModel("phong", {"kd": 0.3, "ks": 0.7, "shininess": 10.0})
    rng = np.random.default_rng(4)
    a = np.column_stack([rng.uniform(0, 1.4, 3000), np.zeros(3000), rng.uniform(0, 1.4, 3000),
                         rng.uniform(0, np.pi, 3000)])
    truth = m(*a.T)
    errs = [np.linalg.norm(lookup_numpy(tabulate(m, n, n, 8).texture, a) - truth)
            / np.linalg.norm(truth) for n in (8, 16, 32, 64)]
    assert all(b < a_ for a_, b in zip(errs, errs[1:], strict=False)) and errs[-1] < 5e-3


def test_brdf_cli_fit_texture_plot(tmp_path, capsys):
    truth = BRDFModel("phong", {"kd": 0.2, "ks": 0.8, "shininess": 40.0})
    csv = _synthetic_csv(tmp_path / "d.csv", truth)
    model = tmp_path / "m.h5"
    assert main(["brdf", "fit", str(csv), "--model", "phong", "-o", str(model),
                 "--test", str(csv), "--metrics-json", str(tmp_path / "m.json")]) == 0
    metrics = json.loads((tmp_path / "m.json").read_text())
    assert metrics["test_agreement_pct"] > 99
    m, meta = load_model(model)
    assert m.name == "phong" and meta["metrics"]["model"] == "phong"
    assert main(["brdf", "texture", str(model), "-o", str(tmp_path / "t.h5"),
                 "--resolution", "16"]) == 0
    assert read_texture(tmp_path / "t.h5").texture.shape == (16, 16, 16)
    assert main(["brdf", "plot", str(model), "--data", str(csv)]) == 0
    assert model.with_suffix(".png").stat().st_size > 1000
    bad = tmp_path / "bad.csv"
    bad.write_text(HEADER + "30,0,30,180,-1\n")
    assert main(["brdf", "fit", str(bad), "--model", "phong", "-o", str(tmp_path / "x.h5")]) == 2
    assert not (tmp_path / "x.h5").exists()


def _scene_against_reference(fm, tables):
    """(the model's transient, the float64 numpy reference of its light cone with the retro
    ``tables`` [materials, N_THETA] given): the same surface elements."""
    from reference.lightcone_ref import lightcone_ref

    sc, smp = fm.scene, fm.samples
    el = smp.elements
    ref = lightcone_ref(el.pos, el.normal, el.area, smp.albedo, smp.material, tables,
                        points=sc.points, width=sc.width_m, bins=sc.bins,
                        bin_width=sc.bin_width_s, start=sc.start_s,
                        splat_order=sc.splat_order)
    return fm.run(), ref


def test_texture_material_in_scene(queue, tmp_path):
    """A texture material renders the transient of its model's own retro slice (the float64
    reference with the analytic model's slice, not the texture's)."""
    from helpers import rel_l2

    from clnlos.forward.model import ForwardModel
    from clnlos.forward.sampling import N_THETA
    from clnlos.forward.scene import Scene

    m = BRDFModel("phong", {"kd": 0.2, "ks": 0.8, "shininess": 40.0})
    write_texture(tmp_path / "t.h5", tabulate(m, 8, 8, 256))
    d = {"scan": {"width_m": 0.3, "points": 4}, "time": {"bin_width_s": 2e-11, "bins": 100,
                                                          "start_s": 2.5e-9},
         "objects": [{"shape": "rectangle", "size_m": [0.1, 0.1], "material": "t.h5",
                      "translate_m": [0, 0, 0.4]}]}
    fm = ForwardModel(Scene.from_dict(d, base_dir=tmp_path), queue=queue)
    assert fm.stages == ["lightcone:brdf-table"]
    out, ref = _scene_against_reference(fm, retro_slice(m, N_THETA)[None])
    assert ref.sum() > 0 and rel_l2(ref, out) < 1e-3


@pytest.mark.shared_data
def test_measured_ptfe_five_param_fit(shared_data):
    d = shared_data / "brdf"
    r = fit_analytic("five-param", read_gonio_csv(d / "nist_ptfe_white_532nm_gonio.csv"),
                     read_gonio_csv(d / "nist_ptfe_white_532nm_test.csv"))
    assert r.metrics["test_agreement_pct"] > 95


def test_ten_presets_in_four_classes(queue):
    from helpers import rel_l2

    from clnlos.brdf.presets import CLASSES, preset_model, preset_table
    from clnlos.forward.model import ForwardModel
    from clnlos.forward.sampling import N_THETA
    from clnlos.forward.scene import Scene

    t = preset_table()
    assert len(t) == 10 and {v["class"] for v in t.values()} == set(CLASSES)
    for name, v in t.items():
        assert v["provenance"]
        r = retro_slice(preset_model(name), 64)
        assert np.all(np.isfinite(r)) and r.max() > 0, name
    d = {"scan": {"width_m": 0.3, "points": 4}, "time": {"bin_width_s": 2e-11, "bins": 100,
                                                          "start_s": 2.5e-9},
         "objects": [{"shape": "rectangle", "size_m": [0.1, 0.1], "material": "Quartz Glass",
                      "translate_m": [0, 0, 0.4]}]}
    out, ref = _scene_against_reference(ForwardModel(Scene.from_dict(d), queue=queue),
                                        retro_slice(preset_model("quartz glass"),
                                                    N_THETA)[None])
    assert ref.sum() > 0 and rel_l2(ref, out) < 1e-3
    lam = dict(d, objects=[{**d["objects"][0], "material": "lambertian"}])
    # its narrow lobe, not the Lambertian 1/pi: far from the Lambertian transient
    assert rel_l2(ForwardModel(Scene.from_dict(lam), queue=queue).run(), out) > 0.5
