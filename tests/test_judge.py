"""The legibility judge: its features do not see where or how large the target is, its
logistic model is calibrated and round-trips through judge.json, ``clnlos legibility``
answers one line per file, and a judge trained on a few twins ranks a thinning ladder of a
simulated capture from legible down to noise."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import ndimage

import clnlos
from clnlos.app.cli import main
from clnlos.io.files import write_h5
from clnlos.study.judge.model import Judge, JudgeModel, load_judge, train_judge
from clnlos.study.judge.features import (
    CAPTURE_FEATURES,
    MIP_FEATURES,
    feature_matrix,
    half_features,
    mip_features,
)
from clnlos.study.score.legibility import glyph_coverage
from clnlos.study.judge.twins import TWIN_GEOMETRIES, TwinGrid, render_twin, twin_plan


def _glyph_image(n, height, centre, glyph="E", blur=1.0, seed=0, noise=0.02):
    c = (np.arange(n) + 0.5) / n - 0.5
    img = glyph_coverage(glyph, height, height * 0.27, centre, c)
    img = ndimage.gaussian_filter(img, blur * n / 32)
    return np.clip(img + np.random.default_rng(seed).normal(0, noise, img.shape), 0, None)


def test_mip_features_ignore_the_targets_place_and_scale():
    base = mip_features(_glyph_image(48, 0.4, (0.0, 0.0)))
    moved = mip_features(_glyph_image(48, 0.4, (0.2, -0.15)))
    small = mip_features(_glyph_image(48, 0.2, (0.05, 0.1)))
    zoomed = mip_features(ndimage.zoom(_glyph_image(48, 0.4, (0.0, 0.0)), 2, order=1))
    for f in MIP_FEATURES:
        for other in (moved, small, zoomed):
            assert abs(other[f] - base[f]) < 0.12, (f, base[f], other[f])
    # a volume [z, y, x] is judged by its MIP, at any albedo scale
    vol = np.stack([0.2 * _glyph_image(48, 0.4, (0, 0)), 7.0 * _glyph_image(48, 0.4, (0, 0))])
    assert mip_features(vol) == pytest.approx(mip_features(vol[1]))


def test_half_agreement_tells_signal_from_noise_wherever_it_sits():
    rng = np.random.default_rng(1)
    clean = _glyph_image(32, 0.5, (0.1, 0.0), noise=0.0)
    halves = [rng.poisson(50 * clean) for _ in range(2)]
    noise = [rng.poisson(np.full(clean.shape, 2.0)) for _ in range(2)]
    moved = [np.roll(h, (5, -4), axis=(0, 1)) for h in halves]
    sig, noi, mov = half_features(*halves), half_features(*noise), half_features(*moved)
    assert sig["half_agreement"] > 0.8 > 0.3 > noi["half_agreement"]
    assert mov["half_agreement"] == pytest.approx(sig["half_agreement"], abs=0.05)
    assert sig["half_overlap"] > noi["half_overlap"]


def _synthetic_rows(n=120, seed=0):
    """Rows of features of glyph images from clear to noise, labelled by the noise level."""
    rng = np.random.default_rng(seed)
    rows = []
    for k in range(n):
        noise = float(rng.uniform(0.0, 0.6))
        clean = _glyph_image(32, rng.uniform(0.3, 0.6), rng.uniform(-0.1, 0.1, 2),
                             glyph="EHLTUX"[k % 6], noise=0.0)
        imgs = [np.clip(clean + rng.normal(0, noise, clean.shape), 0, None) for _ in range(3)]
        rows.append({"features": {**mip_features(imgs[0]), **half_features(imgs[1], imgs[2])},
                     "legible": noise < 0.25, "glyph": "EHLTUX"[k % 6],
                     "geometry": f"g{k % 4}", "material": f"m{k % 3}"})
    return rows


@pytest.fixture(scope="module")
def tiny_judge_dir(tmp_path_factory):
    rows = _synthetic_rows()
    judge, validation = train_judge(rows, {"method": "lct", "snr_rule": "gcv"})
    d = tmp_path_factory.mktemp("judge")
    (d / "judge.json").write_text(json.dumps(judge.to_json()))
    return d, judge, validation


def test_judge_validates_and_round_trips(tiny_judge_dir):
    d, judge, validation = tiny_judge_dir
    splits, details = validation["capture"]
    for name, s in splits.items():
        assert set(s) == {"balanced_accuracy", "auc", "ece", "majority", "baseline"}
        assert s["balanced_accuracy"] > 0.8 and s["auc"] > 0.9, (name, s)
        assert sum(f["n_test"] for f in details[name]["folds"]) == details[name]["n"]
    again = load_judge(d)
    X = np.random.default_rng(2).normal(0.5, 0.3, (5, len(CAPTURE_FEATURES)))
    assert np.allclose(again.capture.predict_proba(X), judge.capture.predict_proba(X))
    # a perfectly separated feature: P above 1/2 only past the cut
    x = np.linspace(-1, 1, 40)[:, None]
    m = JudgeModel.fit(x, x[:, 0] > 0.5, ("f",))
    p = m.predict_proba(np.array([[-1.0], [0.0], [0.9]]))
    assert p[2] > 0.5 > max(p[0], p[1])


def test_cli_and_api_judge_volumes_and_captures(tiny_judge_dir, tmp_path, capsys, queue):
    d, judge, _ = tiny_judge_dir
    vol = tmp_path / "vol.h5"
    clean = _glyph_image(20, 0.5, (0, 0), noise=0.0)
    extents = {"depth_min_m": 0.0, "depth_max_m": 1.0, "voxel_depth_m": 0.5, "x_min_m": -0.2,
               "x_max_m": 0.2, "y_min_m": -0.2, "y_max_m": 0.2, "voxel_lateral_m": 0.02}
    write_h5(vol, {"volume": np.stack([clean * 0.5, clean]).astype(np.float32)}, extents)
    noisy = tmp_path / "noise.h5"
    write_h5(noisy, {"volume": np.random.default_rng(0).random((3, 16, 16)).astype(
        np.float32)}, extents)
    assert main(["legibility", str(vol), str(noisy), "--model", str(d), "--json"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    got = [json.loads(s) for s in lines]
    assert [g["file"] for g in got] == [str(vol), str(noisy)]
    assert all(g["model"] == "volume" for g in got)
    assert got[0]["p_legible"] > 0.5 > got[1]["p_legible"]
    v = clnlos.legibility(vol, model=d)
    assert v.p_legible == pytest.approx(got[0]["p_legible"]) and v.kind == "volume"
    # a capture: reconstructed with the judge's recipe and split into photon halves
    scene = {"seed": 1, "scan": {"width_m": 0.4, "points": 12},
             "time": {"bin_width_s": 64e-12, "bins": 80},
             "objects": [{"shape": "letters", "text": "L", "height_m": 0.25,
                          "stroke_m": 0.07, "translate_m": [0, 0, 0.4]}],
             "detector": {"exposure_s": 1.0, "etendue_m2_sr": 1e-6}}
    cap = clnlos.simulate(scene, device=queue)
    c = clnlos.legibility(cap, model=d, device=queue)
    assert c.kind == "capture" and set(c.features) == set(CAPTURE_FEATURES)
    # the judge's own model of the features it reports: legible for this easy L
    x = np.array([[c.features[f] for f in judge.capture.features]])
    assert c.p_legible == pytest.approx(float(judge.capture.predict_proba(x)[0]), rel=1e-9)
    assert c.p_legible > 0.5
    # the same L with 1e-11 of the exposure (tens of photons): judged illegible
    dim = {**scene, "detector": {**scene["detector"], "exposure_s": 1e-11}}
    assert clnlos.legibility(clnlos.simulate(dim, device=queue), model=d,
                             device=queue).p_legible < 0.5
    # errors a user can cause: one line, exit 2, before any work
    assert main(["legibility", str(vol), "--model", str(tmp_path)]) == 2
    assert "no judge.json" in capsys.readouterr().err
    assert main(["legibility", str(tmp_path / "none.h5"), "--model", str(d)]) == 2
    assert "no such file" in capsys.readouterr().err


def test_a_judge_from_twins_ranks_a_thinning_ladder(queue):
    grid = TwinGrid(points=12, bin_width_s=64e-12)
    geos = [g.name for g in TWIN_GEOMETRIES if g.family == "lct"][:2]
    plan = [e for e in twin_plan(per_geometry=3, seed=5) if e["geometry"] in geos]
    fractions = (1.0, 1e-2, 1e-4, 1e-6, 1e-7)
    rows = [r for e in plan for r in render_twin(replace_white(e), grid, fractions, queue)]
    assert any(r["legible"] for r in rows) and not all(r["legible"] for r in rows)
    judge, _ = train_judge(rows, {"method": "lct", "snr_rule": "gcv"})
    assert isinstance(judge, Judge)
    # a new twin (another glyph and seed), its own ladder: P falls as the photons fall
    test = replace_white({**plan[0], "glyph": "U", "seed": 12345})
    ladder = [r for r in render_twin(test, grid, fractions, queue) if "view" not in r]
    assert [r["fraction"] for r in ladder] == list(fractions)
    p = judge.capture.predict_proba(feature_matrix([r["features"] for r in ladder],
                                                   CAPTURE_FEATURES))
    assert all(b <= a + 0.05 for a, b in zip(p, p[1:], strict=False)), p
    assert p[0] > 0.5 > p[-1], p


def replace_white(entry):
    """A twin entry in the diffuse white preset (the ladder test's target)."""
    return {**entry, "material": "standard white plate", "background": 0.1}


def test_charts_mask_what_the_scene_holds_and_stay_inside_the_scan():
    """A chart's true mask is the union of the rectangles its scene objects hold; twins of
    every pattern lie inside the scan at most TWIN_MAX_FILL wide."""
    from clnlos.study.score.patterns import (
        CHART_SCALE,
        TWIN_PATTERNS,
        is_chart,
        pattern_mask,
        pattern_objects,
    )
    from clnlos.study.judge.twins import TWIN_MAX_FILL, twin_placement
    rng = np.random.default_rng(3)
    pts = rng.uniform(-0.3, 0.3, (4000, 2))
    for name in ("bars_v", "bars_h", "dots_3x3", "dots_2x2"):
        objs = pattern_objects(name, 0.3, 0.08, (0.02, -0.01, 0.5), "retroreflective")
        assert all(o["shape"] == "rectangle" and o["material"] == "retroreflective"
                   for o in objs)
        inside = np.zeros(len(pts), bool)
        for o in objs:
            (w, h), (x, y, _) = o["size_m"], o["translate_m"]
            inside |= (np.abs(pts[:, 0] - x) <= w / 2) & (np.abs(pts[:, 1] - y) <= h / 2)
        assert np.array_equal(inside, pattern_mask(name, 0.3, 0.08, pts - [0.02, -0.01]))
        share = inside.mean() * 0.36 / (0.3 * CHART_SCALE) ** 2
        assert 0.2 < share < 0.7  # neither empty nor full
    assert pattern_objects("S", 0.3, 0.08, (0, 0, 0.5), "lambertian")[0]["text"] == "S"
    for geo in TWIN_GEOMETRIES:
        for name in TWIN_PATTERNS:
            p = twin_placement(geo, name, rng)
            side = p["height_m"] * (CHART_SCALE if is_chart(name) else 1.0)
            assert side <= TWIN_MAX_FILL * geo.scan_width_m + 1e-12
            assert max(abs(v) for v in p["offset_m"]) + side / 2 <= geo.scan_width_m / 2 + 1e-9


def test_blob_fit_tells_a_blob_from_a_glyph():
    blob = _glyph_image(48, 0.4, (0.05, 0.0), blur=8.0, noise=0.0)
    y, x = np.mgrid[:48, :48]
    gauss = np.exp(-((x - 20) ** 2 + (y - 27) ** 2 / 2.0) / 30.0)
    glyphs = [mip_features(_glyph_image(48, 0.4, (0.0, 0.0), glyph=g, blur=0.5,
                                        noise=0.0))["blob_fit"] for g in "HLTUX"]
    assert mip_features(gauss)["blob_fit"] > 0.9  # the fit sees its foreground only
    assert mip_features(blob)["blob_fit"] > max(glyphs)


@pytest.mark.parametrize("per_geometry", [8, 14, 16])
def test_twin_plan_crosses_every_pattern_with_every_material(per_geometry):
    """No pattern is tied to a material (else held out by material also holds out patterns):
    once the plan has a round of the patterns per material, every pair occurs, and the
    patterns are dealt evenly (within one) and the materials within two."""
    from collections import Counter

    from clnlos.study.score.patterns import TWIN_PATTERNS
    from clnlos.study.judge.twins import TWIN_MATERIALS
    plan = twin_plan(per_geometry=per_geometry, seed=0)
    assert len(plan) == per_geometry * len(TWIN_GEOMETRIES)
    pairs = Counter((e["glyph"], e["material"]) for e in plan)
    if len(plan) >= len(TWIN_PATTERNS) * len(TWIN_MATERIALS):
        assert len(pairs) == len(TWIN_PATTERNS) * len(TWIN_MATERIALS)
    for key, spread in (("glyph", 1), ("material", 2)):
        counts = Counter(e[key] for e in plan).values()
        assert max(counts) - min(counts) <= spread, (key, counts)
