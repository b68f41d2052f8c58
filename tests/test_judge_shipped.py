"""The legibility judge shipped with clnlos: its twins' targets and labels, what it knows
(its domain and interval), that it loads with its provenance and answers without --model,
that no file name decides anything, and its verdict on a real capture along its ladder."""

from __future__ import annotations

import json
import re
import shutil
from dataclasses import replace

import h5py
import numpy as np
import pytest
from scipy import ndimage

import clnlos
from clnlos.app.cli import main
from clnlos.errors import InputFileError
from clnlos.forward.scene import Scene
from clnlos.io.files import read_capture, write_h5
from clnlos.study.judge.apply import SHIPPED_JUDGE, shipped_judge
from clnlos.study.judge.domain import (
    descriptor_domain,
    descriptor_notes,
    feature_domain,
    feature_notes,
    interval,
)
from clnlos.study.judge.heldout import BROAD_SPLITS
from clnlos.study.judge.model import JudgeModel
from clnlos.study.judge.recipe import judge_config
from clnlos.study.judge.targets import (
    OBJECTS,
    POSES,
    TARGET_KINDS,
    draw_target,
    object_mask,
    person_mask,
)
from clnlos.study.judge.twins import (
    FIDELITY_NCC,
    broad_plan,
    shape_label,
    true_footprint,
    write_files,
)
from clnlos.study.real.thinning import thinned_series
from clnlos.study.score.clarity import truth_thresholds


def test_every_silhouette_is_one_shape_inside_its_square():
    rng = np.random.default_rng(0)
    masks = [person_mask(rng, p)[0] for p in POSES] + [object_mask(o, rng) for o in OBJECTS]
    for m in masks:
        assert m.shape == (128, 128) and 0.04 < m.mean() < 0.8
        assert not (m[0].all() or m[-1].all() or m[:, 0].all() or m[:, -1].all())
        _, parts = ndimage.label(m, structure=np.ones((3, 3)))
        assert parts <= 3  # a figure, an object: one part (a mannequin's stand, a mug's ring)


def test_targets_and_their_true_front_view(tmp_path):
    """Every kind draws scene objects that validate; a plate's front view is its area, a
    printed sign's content is its letters (not its plate), a multi target's parts sit at
    different depths."""
    rng = np.random.default_rng(3)
    for kind in TARGET_KINDS[2:]:
        t = draw_target(kind, rng, 0.4, "lambertian")
        assert t.kind == kind and len(t.objects) == len(t.content) and any(t.content)
        folder = tmp_path / kind
        folder.mkdir()
        write_files(t.files, folder)
        objs = [{**o, "translate_m": [o["translate_m"][0], o["translate_m"][1],
                                      o["translate_m"][2] + 0.6]} for o in t.objects]
        scene = Scene.from_dict({"scan": {"width_m": 0.6, "points": 24},
                                 "time": {"bin_width_s": 32e-12, "bins": 300},
                                 "objects": objs}, base_dir=folder)
        cover = true_footprint(scene, t.content)
        assert cover.shape == (24, 24) and 0 < cover.mean() < 0.6
        if kind == "multi":
            depths = {round(o["translate_m"][2], 3) for o in t.objects}
            assert len(depths) >= 2
    plate = Scene.from_dict({"scan": {"width_m": 0.4, "points": 20},
                             "time": {"bin_width_s": 32e-12, "bins": 100},
                             "objects": [{"shape": "rectangle", "size_m": [0.2, 0.1],
                                          "translate_m": [0, 0, 0.5]}]})
    assert true_footprint(plate, [True]).sum() * 0.02 ** 2 == pytest.approx(0.02, rel=0.02)
    rng = np.random.default_rng(11)
    kinds = {draw_target("sign", rng, 0.4, "lambertian").name.split()[-1] for _ in range(12)}
    assert kinds == {"cut", "printed"}


def test_the_label_of_a_shape_asks_its_image_to_beat_its_box():
    cover = np.zeros((24, 24))
    cover[4:20, 10:13] = 1.0
    cover[4:7, 5:19] = 1.0        # a T
    ideal = ndimage.gaussian_filter(cover, 1.0, mode="constant")
    box = np.zeros_like(cover)
    box[4:20, 5:19] = 1.0
    noise = np.random.default_rng(0).random((24, 24))
    assert shape_label(ideal, cover, 1.0)["legible"]
    blob = shape_label(ndimage.gaussian_filter(box, 1.0, mode="constant"), cover, 1.0)
    assert not blob["legible"] and blob["match_box"] > blob["match"]
    got = shape_label(noise, cover, 1.0)
    assert not got["legible"] and got["match"] < FIDELITY_NCC


def test_broad_plan_crosses_kinds_rigs_and_materials():
    from collections import Counter

    plan = broad_plan(8, seed=1)
    assert len(plan) == 8 * len(TARGET_KINDS)
    pairs = Counter((e["kind"], e["material"]) for e in plan)
    assert len(pairs) == len(TARGET_KINDS) * 4      # every kind meets every material
    rigs = Counter((e["kind"], e["rig"]) for e in plan)
    assert len(rigs) == len(TARGET_KINDS) * 2       # and both rigs
    for e in plan:
        side = e.get("side_m", e.get("height_m"))
        assert 0 < side < e["scan_width_m"] and e["depth_m"] > 0


def test_domain_notes_and_interval():
    rng = np.random.default_rng(4)
    X = rng.normal(0, 1, (400, 3))
    dom = feature_domain(X, ("a", "b", "c"))
    assert feature_notes(np.zeros(3), dom) == []
    far = feature_notes(np.array([9.0, 0.0, 0.0]), dom)
    assert len(far) == 1 and "a outside" in far[0] and "b," not in far[0]
    rows = [{"points": p, "photons_per_point": n, "slab_thickness_m": s}
            for p, n, s in ((16, 10.0, 0.0), (32, 1e5, 0.0254))]
    d = descriptor_domain(rows)
    assert d["points"] == [16.0, 32.0] and d["slab_thickness_m"] == [0.0, 0.0254]
    assert descriptor_notes({"points": 24, "photons_per_point": 100.0,
                             "slab_thickness_m": 0.025}, d) == []
    notes = descriptor_notes({"points": 8, "photons_per_point": 1e7,
                              "slab_thickness_m": 0.05}, d)
    assert len(notes) == 3 and "scan points per side 8" in notes[0]
    y = X[:, 0] + 0.3 * rng.normal(size=400) > 0
    boot = [JudgeModel.fit(X[i], y[i], ("a", "b", "c"))
            for i in (rng.integers(0, 400, 400) for _ in range(10))]
    inside = interval(np.zeros(3), boot, [], dom, outside=False)
    ps = np.array([m.predict_proba(np.zeros((1, 3)))[0] for m in boot])
    assert inside == pytest.approx(list(np.quantile(ps, [0.05, 0.95])))
    # outside: every spread model, at the features as they are and clamped to the domain
    x = np.array([-4.0, 9.0, -9.0])
    held = [JudgeModel.fit(X[X[:, 1] > 0], y[X[:, 1] > 0], ("a", "b", "c"))]
    outside = interval(x, boot, held, dom, outside=True)
    every = [m.predict_proba(v.reshape(1, -1))[0] for m in boot + held
             for v in (x, np.clip(x, dom["low"], dom["high"]))]
    assert outside == pytest.approx([min(every), max(every)])
    assert interval(np.zeros(3), [], [], dom, False) is None


def test_truth_thresholds_follow_the_ground_truth_not_a_split():
    rng = np.random.default_rng(2)
    classes = rng.choice([1, 2, 3], 300, p=[0.6, 0.1, 0.3])
    scores = np.where(classes == 1, 3.0, np.where(classes == 2, 2.0, 1.0)) \
        + rng.normal(0, 0.1, 300)
    clear, fuzzy = truth_thresholds(scores, classes)
    assert 2.2 < clear < 2.8 and 1.2 < fuzzy < 1.8


# ------------------------------------------------------------------ the shipped judge
def test_the_shipped_judge_loads_with_its_provenance():
    judge = shipped_judge()
    info = judge.info
    assert re.fullmatch(r"[0-9a-f]{40}", info["provenance"]["commit"])
    assert info["provenance"]["command"].startswith("python tools/train_judge.py")
    assert info["training_set"]["scenes"] >= 7 * 40
    assert set(info["training_set"]["by_kind"]) == set(TARGET_KINDS)
    assert set(info["splits"]["capture"]) == set(BROAD_SPLITS)
    for name, s in info["splits"]["capture"].items():  # the bar, as recorded
        assert s["balanced_accuracy"] >= 0.85 and s["ece"] <= 0.08, (name, s)
        assert s["balanced_accuracy"] > s["baseline"], (name, s)
    for m in ("capture", "volume"):
        assert len(judge.spread[m]["bootstrap"]) >= 20 and judge.spread[m]["held_out"]
        assert "features" in judge.domain[m]
    assert {"points", "photons_per_point", "slab_thickness_m"} <= set(
        judge.domain["capture"]["descriptors"])


def _glyph_image(n, glyph="E", noise=0.0, seed=0):
    from clnlos.study.score.legibility import glyph_coverage

    c = (np.arange(n) + 0.5) / n - 0.5
    img = ndimage.gaussian_filter(glyph_coverage(glyph, 0.6, 0.15, (0, 0), c), n / 40)
    return np.clip(img + np.random.default_rng(seed).normal(0, noise, img.shape), 0, None)


EXTENTS = {"depth_min_m": 0.0, "depth_max_m": 1.0, "voxel_depth_m": 0.5, "x_min_m": -0.2,
           "x_max_m": 0.2, "y_min_m": -0.2, "y_max_m": 0.2, "voxel_lateral_m": 0.02}


def test_the_shipped_judge_answers_without_a_model(tmp_path, capsys):
    clean, noisy = tmp_path / "clean.h5", tmp_path / "noisy.h5"
    img = _glyph_image(32)
    write_h5(clean, {"volume": np.stack([0.3 * img, img]).astype(np.float32)}, EXTENTS)
    write_h5(noisy, {"volume": np.random.default_rng(1).random((4, 32, 32)).astype(
        np.float32)}, EXTENTS)
    assert main(["legibility", str(clean), str(noisy), "--json"]) == 0
    got = [json.loads(s) for s in capsys.readouterr().out.strip().splitlines()]
    assert got[0]["p_legible"] > 0.8 > 0.5 > got[1]["p_legible"]
    for g in got:
        lo, hi = g["interval"]
        assert lo <= g["p_legible"] <= hi and g["model"] == "volume"
        assert SHIPPED_JUDGE in g["judge"] and isinstance(g["notes"], list)
    # an image unlike anything the judge saw: a note and its interval, the text line says so
    tiny = clnlos.legibility(np.eye(6)[None])
    assert tiny.notes and "scan points per side 6" in " ".join(tiny.notes)
    assert tiny.interval[0] <= tiny.p_legible <= tiny.interval[1]
    assert "outside the judge's domain" in tiny.line()


def _small_capture(queue):
    scene = {"seed": 2, "scan": {"width_m": 0.6, "points": 24},
             "time": {"bin_width_s": 32e-12, "bins": 220},
             "objects": [{"shape": "letters", "text": "U", "height_m": 0.35,
                          "stroke_m": 0.09, "translate_m": [0, 0, 0.5],
                          "material": "standard white plate"}],
             "detector": {"exposure_s": 1.0, "etendue_m2_sr": 1e-5}}
    return clnlos.simulate(scene, device=queue)


def test_no_file_name_decides_anything(tmp_path, queue):
    """A capture in the CDT layout (no scan width, no slab in the file) under the name of a
    shared capture and under another: the same reconstruction settings, the same P; the
    settings come from the user's options."""
    cap = _small_capture(queue)
    counts = np.asarray(cap.transient)[:, ::-1, :]  # the CDT layout: y running down
    paths = [tmp_path / "letters_ut.mat", tmp_path / "my_capture.mat"]
    with h5py.File(paths[0], "w") as f:
        f["meas"] = np.transpose(counts)
    shutil.copy(paths[0], paths[1])
    read = [read_capture(p) for p in paths]
    cfgs = [judge_config(c, None) for c in read]
    assert cfgs[0] == cfgs[1] and cfgs[0].scan_width_m is None and cfgs[0].slab is None
    with pytest.raises(Exception, match="scan width|scan_width"):
        clnlos.legibility(paths[0], device=queue)
    p = [clnlos.legibility(x, scan_width_m=0.6, device=queue) for x in paths]
    assert p[0].p_legible == p[1].p_legible and p[0].features == p[1].features
    assert p[0].descriptors["scan_width_m"] == 0.6
    assert main(["legibility", str(paths[0]), "--json"]) == 2   # one error line, exit 2
    # a capture of anything but photon counts (a simulation without a [detector]): no
    # photons to split into halves, one error naming the way out
    with pytest.raises(InputFileError, match="photon counts.*its reconstruction"):
        clnlos.legibility(replace(cap, transient=np.asarray(cap.transient) * 0.5 + 0.25),
                          device=queue)


def test_the_shipped_judge_on_a_real_capture_and_its_ladder(shared_data, queue):
    """data_s_u, as released: legible at full photons; thinned (nested, binomial) to 1e-4
    of its photons, where its image is gone, not legible."""
    cap = read_capture(shared_data / "lct" / "data_s_u.mat")
    full, thin = thinned_series(cap.transient, (1.0, 1e-4), seed=48)
    p = [clnlos.legibility(replace(cap, transient=c), device=queue) for c in (full, thin)]
    assert p[0].p_legible >= 0.8 > 0.5 > p[1].p_legible, [v.p_legible for v in p]
    assert not p[0].notes
