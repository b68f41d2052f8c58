"""Fits that say how good they are (issue 58, items 4 and 5): ``clnlos brdf fit`` prints its
held-out agreement and peak error in one line, stores them, warns on a fit that is not usable
naming a model that fits better; ``--model auto`` keeps the best candidate on held-out data;
``brdf texture`` and ``simulate`` carry the warning on; MERL ``.binary`` files are read."""

from __future__ import annotations

import json

import numpy as np
import pytest

import clnlos
from clnlos.app.cli import main
from clnlos.brdf.data import MERL_GONIO_DEG, MERL_SHAPE, merl_samples, write_merl_binary
from clnlos.brdf.fit import AUTO_VALIDATION_FRACTION, USABLE_AGREEMENT_PCT
from clnlos.brdf.models import BRDFModel
from clnlos.brdf.store import FitQualityWarning, load_model
from clnlos.forward.scene import Scene

HEADER = "theta_i_deg,phi_i_deg,theta_s_deg,phi_s_deg,brdf\n"


def _csv(path, model, incidences, n=400, seed=0):
    """Samples of ``model`` at the given incidence angles (deg), random detector directions."""
    rng = np.random.default_rng(seed)
    ti = rng.choice(incidences, n)
    ts, ps = rng.uniform(0, 85, n), rng.uniform(0, 360, n)
    f = model(np.radians(ti), 0 * ti, np.radians(ts), np.radians(ps))
    path.write_text("# precision: 0\n" + HEADER + "".join(
        f"{a:.6f},0,{b:.6f},{c:.6f},{d:.9g}\n" for a, b, c, d in zip(ti, ts, ps, f, strict=True)))
    return path


def _fit(capsys, *args):
    rc = main(["brdf", "fit", *map(str, args)])
    out = capsys.readouterr()
    assert rc == 0, out.err
    return out.out.splitlines(), [ln for ln in out.err.splitlines()
                                  if ln.startswith("clnlos: warning:")]


def test_a_fit_at_its_bound_says_so_with_its_known_numbers(tmp_path, capsys):
    """A Lambertian of kd = 30 fitted by ``lambert`` (kd at most 10): the fit stops at its
    bound, agreement 100 (1 - 20/30) = 33.3%, peak error -66.7%, not usable; the data's own
    family is named as fitting better."""
    bright = BRDFModel("lambert", {"kd": 30.0})
    train, test = _csv(tmp_path / "g.csv", bright, [30.0, 60.0]), _csv(
        tmp_path / "t.csv", bright, [15.0, 45.0], seed=1)
    out, warn = _fit(capsys, train, "--test", test, "--model", "lambert", "-o",
                     tmp_path / "m.h5")
    assert out[-2] == "lambert: held-out agreement 33.3%, peak error -66.7% (400 samples)"
    assert len(warn) == 1 and "lambert fit is not usable" in warn[0]
    assert "kd = 10 (upper bound)" in warn[0] and "agreement 33.3% < 80%" in warn[0]
    assert "minnaert agrees better" in warn[0] or "phong agrees better" in warn[0] \
        or "five-param agrees better" in warn[0], warn[0]
    q = load_model(tmp_path / "m.h5")[1]["metrics"]["fit_quality"]
    assert q["usable"] is False and q["on"] == "test"
    assert q["agreement_pct"] == pytest.approx(100 / 3, abs=1e-6)
    assert q["peak_error_pct"] == pytest.approx(-200 / 3, abs=1e-6)
    # a usable fit: no warning
    dim = BRDFModel("lambert", {"kd": 0.5})
    out, warn = _fit(capsys, _csv(tmp_path / "d.csv", dim, [30.0]), "--model", "lambert",
                     "-o", tmp_path / "d.h5")
    assert warn == [] and out[-2].startswith("lambert: training (no held-out data: --test) "
                                             "agreement 100.0%, peak error +0.0%")


def test_auto_keeps_the_best_candidate_on_held_out_data(tmp_path, capsys):
    """Data of a GGX lobe: ``auto`` chooses the microfacet model on the held-out part of the
    training set (not the test set) and beats the worst candidate on the test set."""
    glossy = BRDFModel("microfacet", {"kd": 0.3, "ks": 1.0, "alpha": 0.2, "f0": 1.0})
    train = _csv(tmp_path / "g.csv", glossy, [30.0, 45.0, 60.0], n=300)
    test = _csv(tmp_path / "t.csv", glossy, [20.0, 50.0], n=200, seed=3)
    out, warn = _fit(capsys, train, "--test", test, "--model", "auto", "--candidates",
                     "lambert", "torrance-sparrow", "minnaert", "-o", tmp_path / "a.h5")
    auto_line = next(ln for ln in out if ln.startswith("auto: "))
    assert f"on {AUTO_VALIDATION_FRACTION * 100:g}% of the training data" in auto_line
    assert auto_line.endswith("torrance-sparrow kept")
    metrics = load_model(tmp_path / "a.h5")[1]["metrics"]
    assert metrics["model"] == "torrance-sparrow" and set(metrics["auto"]["candidates"]) == \
        {"lambert", "torrance-sparrow", "minnaert"}
    assert metrics["fit_quality"]["agreement_pct"] > 99 and warn == []
    _, _ = _fit(capsys, train, "--test", test, "--model", "lambert", "-o", tmp_path / "l.h5")
    worst = load_model(tmp_path / "l.h5")[1]["metrics"]["fit_quality"]["agreement_pct"]
    assert worst < USABLE_AGREEMENT_PCT < metrics["fit_quality"]["agreement_pct"]
    assert main(["brdf", "fit", str(train), "--model", "phong", "--candidates", "lambert",
                 "-o", str(tmp_path / "x.h5")]) == 2


def test_texture_and_simulate_carry_the_warning(tmp_path, capsys):
    bright = BRDFModel("lambert", {"kd": 30.0})
    _fit(capsys, _csv(tmp_path / "g.csv", bright, [30.0]), "--model", "lambert", "-o",
         tmp_path / "m.h5")
    assert main(["brdf", "texture", str(tmp_path / "m.h5"), "-o", str(tmp_path / "t.h5"),
                 "--resolution", "8", "--retro", "16"]) == 0
    err = capsys.readouterr().err
    assert "clnlos: warning: " in err and "m.h5: lambert fit is not usable" in err
    scene = {"scan": {"width_m": 0.3, "points": 4}, "time": {"bin_width_s": 32e-12,
                                                             "bins": 96},
             "objects": [{"shape": "rectangle", "size_m": [0.1, 0.1], "material": "t.h5",
                          "translate_m": [0, 0, 0.4]}]}
    with pytest.warns(FitQualityWarning, match=r"t\.h5 \(a texture of .*m\.h5\): lambert "
                      r"fit is not usable"):
        clnlos.simulate(Scene.from_dict(scene, base_dir=tmp_path))


def test_merl_binary_is_read_by_brdf_fit(tmp_path, capsys):
    """A MERL file (the database's layout: three int32 dims, then red, green, blue float64
    tables stored divided by their channel scales): ``brdf fit`` samples its green channel;
    a Lambertian green table gives kd back exactly, a lobe in theta_half peaks at the mirror
    direction."""
    rgb = np.empty((3, *MERL_SHAPE))
    rgb[0], rgb[1], rgb[2] = 0.1, 0.25 / np.pi, 0.9
    write_merl_binary(tmp_path / "grey.binary", rgb)
    raw = np.fromfile(tmp_path / "grey.binary", np.float64, count=2, offset=12 + 8 * 1458000)
    assert raw[0] == pytest.approx(0.25 / np.pi * 1500 / 1.15)  # green, stored unscaled
    out, warn = _fit(capsys, tmp_path / "grey.binary", "--test", tmp_path / "grey.binary",
                     "--model", "lambert", "-o", tmp_path / "g.h5")
    metrics = load_model(tmp_path / "g.h5")[1]["metrics"]
    assert metrics["params"]["kd"] == pytest.approx(0.25, rel=1e-9) and warn == []
    assert out[-2] == "lambert: held-out agreement 100.0%, peak error +0.0% (2000 samples)"
    # a lobe about the half vector (its index sqrt(theta_h / 90 deg) x 90 in the table)
    ih = np.arange(MERL_SHAPE[0])[:, None, None]
    rgb[1] = (0.1 + 20.0 * np.exp(-(ih / 6.0) ** 2)) * np.ones(MERL_SHAPE)
    write_merl_binary(tmp_path / "lobe.binary", rgb)
    s = merl_samples(tmp_path / "lobe.binary")
    k = int(np.argmax(s.brdf))
    assert min(abs(np.degrees(s.theta_i[k]) - a) for a in MERL_GONIO_DEG) < 1e-9
    assert np.degrees(s.theta_s[k]) == pytest.approx(np.degrees(s.theta_i[k]))
    assert np.degrees(s.phi_s[k]) == pytest.approx(180.0) and s.brdf[k] == pytest.approx(20.1)
    assert json.loads(json.dumps(s.meta))["channel"] == "G"
