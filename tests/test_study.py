"""The material study: clarity and no-reference metrics, labels, the CNN, a tiny end-to-end
study (serial = Dask), the report's layout in a real browser."""

import contextlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

import clnlos
from clnlos.forward.geometry import letters_mask
from clnlos.study.score.clarity import clarity_label, clarity_score, label_thresholds
from clnlos.study.judge.cnn import dihedral
from clnlos.study.file.spec import StudyGrid, load_study, parse_study
from clnlos.study.findings.sweeps import SEED_FIGURE9, mean_interval, specular_fraction
from clnlos.study.plan.entries import study_plan
from clnlos.study.plan.scenes import dataset_samples, scene_dict, window_m
from clnlos.study.report.page import _reconstruction_detail
from clnlos.study.run import run_study
from clnlos.study.samples.materials import prepare_materials
from clnlos.study.score.quality import (
    central_energy,
    depth_coherence,
    otsu_separability,
    quality_metrics,
    validate_metrics,
)


def _sharp_image(n=64):
    c = (np.arange(n) + 0.5) / n - 0.5
    Y, X = np.meshgrid(c, c, indexing="ij")
    return letters_mask("UT", 0.5, 0.08, np.column_stack([X.ravel(), Y.ravel()])
                        ).reshape(n, n).astype(float)


def test_clarity_falls_monotonically_with_blur():
    img = _sharp_image()
    # up to sigma = 5 px (letters 32 px high, strokes 5 px); past that the score sits at the
    # floor set by the window's own spectrum
    scores = [clarity_score(gaussian_filter(img, s)) if s else clarity_score(img)
              for s in (0, 0.5, 1, 1.5, 2, 3, 4, 5)]
    assert all(b < a for a, b in zip(scores, scores[1:], strict=False)), scores
    assert clarity_score(np.zeros((8, 8))) == 0.0
    assert clarity_score(3 * img) == pytest.approx(clarity_score(img))  # scale-free


def test_labels_reproduce_the_seed_split():
    s = np.random.default_rng(0).lognormal(size=1000)
    th = label_thresholds(s)
    lab = np.array([clarity_label(v, th) for v in s])
    assert [int((lab == k).sum()) for k in (1, 2, 3)] == pytest.approx([193, 514, 293], abs=2)


def test_no_reference_metrics_on_known_images():
    img = _sharp_image(32)
    assert otsu_separability(img) == pytest.approx(1.0)  # two levels exactly
    blurred = gaussian_filter(img, 2)
    assert otsu_separability(blurred) < otsu_separability(img)
    noise = np.random.default_rng(1).random((32, 32))
    assert otsu_separability(noise) < otsu_separability(blurred)
    corner = np.zeros((32, 32))
    corner[:3, :3] = 1.0
    assert central_energy(corner) == 0.0 and central_energy(img) > 0.95
    flat = np.full((32, 32), 0.5)
    assert depth_coherence(img, flat) == 1.0
    rough = 0.5 + 0.02 * np.random.default_rng(2).standard_normal((32, 32))
    assert depth_coherence(img, rough) < 0.5
    vol = np.zeros((20, 32, 32))
    vol[8] = img
    q = quality_metrics(vol, 0.01)
    assert q["nr_clarity"] == pytest.approx(q["otsu_separability"] * q["central_energy"])
    assert q["depth_coherence"] == 1.0 and np.isfinite(q["fft_clarity"])


def test_metric_validation_and_interval():
    x = np.arange(10.0)
    v = validate_metrics({"a": x, "b": -x}, {"iou": 2 * x + 1})
    assert v["a"]["iou"] == pytest.approx(1.0) and v["b"]["iou"] == pytest.approx(-1.0)
    m, (lo, hi) = mean_interval([0.5, 0.6, 0.7, 0.6, 0.6])
    assert m == pytest.approx(0.6) and lo < 0.6 < hi and hi - lo < 0.2
    assert mean_interval([0.3]) == (0.3, [0.3, 0.3])


def test_dihedral_augmentation():
    a = np.arange(2 * 9, dtype=float).reshape(2, 3, 3)
    d = dihedral(a)
    assert d.shape == (16, 3, 3)
    assert {tuple(x.ravel()) for x in d[::2]} >= {tuple(np.rot90(a[0], k).ravel())
                                                    for k in range(4)}


def test_specular_fraction_orders_models():
    from clnlos.brdf.models import BRDFModel

    assert specular_fraction(BRDFModel("lambert", {})) == 0.0
    assert specular_fraction(BRDFModel("microfacet", {"alpha": 0.1})) == pytest.approx(1.0)
    mixed = specular_fraction(BRDFModel("microfacet", {"kd": 0.3, "alpha": 0.1}))
    assert 0 < mixed < 1


def test_dataset_design_and_scenes():
    from clnlos.brdf.presets import preset_names
    from clnlos.forward.scene import Scene

    s = dataset_samples(60, [{"material": m} for m in preset_names()], 3)
    assert len({x["material"] for x in s}) >= 8
    assert {x["object"] for x in s} == {"letters", "bars", "rectangle", "sphere"}
    ex = np.array([x["exposure_s"] for x in s])
    assert ex.min() >= 5e-3 and ex.max() <= 0.3 and ex.max() / ex.min() > 10
    g = StudyGrid()
    for x in s[:12]:
        sc = Scene.from_dict(scene_dict(x, g))  # every sample is a valid scene
        assert sc.slab is not None and sc.detector.exposure_s == x["exposure_s"]
        assert sc.bins * sc.bin_width_s * 3e8 >= window_m(x, g)
    bars = next(x for x in s if x["object"] == "bars")
    assert len(scene_dict(bars, g)["objects"]) >= 2
    no_slab = scene_dict({**s[0], "slab_thickness_m": 0.0}, g)
    assert "slab" not in no_slab
    assert set(SEED_FIGURE9) == set(preset_names())


CDT = {"thickness_m": 0.0254, "mu_a": 0.53, "mu_s_prime": 262.0, "n": 1.12}
GLYPH_SET = ["E", "H", "T", "U"]
TINY_MATERIALS = ["standard white plate", "quartz glass", "painted steel plate"]
# a tiny material study: every section of the built-in ones on a 12 x 12 grid
TINY = {
    "study": {"name": "tiny", "realisations": 1, "refine_ratio": 0},
    "scan": {"width_m": 0.3, "points": 12}, "time": {"bin_width_s": 64e-12}, "slab": CDT,
    "laser": {"pulse_width_s": 35e-12},
    "detector": {"exposure_s": 0.1, "etendue_m2_sr": 1e-9, "dark_count_rate_hz": 1000.0},
    "sampling": {"density_per_m2": 2e4}, "reconstruction": {"iterations": 10},
    "inversions": {"reflectance": ["lambertian", "known", "auto"]},
    "materials": [{"brdf": m} for m in TINY_MATERIALS],
    "targets": [{"name": "seed_table1", "glyphs": GLYPH_SET, "height_m": 0.15,
                 "stroke_m": 0.04, "depth_m": 0.5, "scan_width_m": 0.3},
                {"name": "legible", "glyphs": GLYPH_SET, "height_m": 0.3, "stroke_m": 0.08,
                 "depth_m": 0.5, "scan_width_m": 0.6}],
    "sweeps": [
        {"letter_height_m": [0.2, 0.3], "targets": ["legible"], "glyphs": ["E"],
         "materials": ["quartz glass", "standard white plate"],
         "reflectance": ["lambertian", "known"]},
        {"exposure_s": [0.1, 1.0], "targets": ["legible"], "glyphs": ["E"],
         "materials": ["quartz glass", "standard white plate"],
         "reflectance": ["lambertian", "known"]},
        {"tilt_deg": [0.0, 10.0], "targets": ["legible"], "glyphs": ["E", "T"],
         "materials": ["quartz glass"], "reflectance": ["lambertian", "known"]},
        *({var: vals, "targets": ["seed_table1"], "glyphs": ["E", "T"],
           "materials": ["quartz glass", "standard white plate"],
           "reflectance": ["lambertian"]}
          for var, vals in (("scan_width_m", [0.3, 0.5]), ("depth_m", [0.4, 0.6]),
                            ("slab_thickness_m", [0.0, 0.0254])))],
    "table": {"aware_glyphs": ["E"], "legible_target": "legible",
              "seed_target": "seed_table1"},
    "judge": {"twins": 1}, "classifier": {"extras": 6, "epochs": 3}}

# the distributed runs: two materials, the Lambertian inversion, one point per sweep
SMALL = {**TINY, "classifier": {"extras": 0},
         "materials": TINY["materials"][:2], "inversions": {"reflectance": ["lambertian"]},
         "sweeps": [{"depth_m": [0.4], "targets": ["seed_table1"], "glyphs": ["E", "T"],
                     "materials": ["quartz glass"]}]}


def _check_contract(res, d):
    """results.json: today's keys and the legibility contract of the study issue."""
    opts = parse_study(d)
    names = [m.name for m in opts.materials]
    glyphs = opts.target("legible").glyphs
    assert [m["name"] for m in res["materials"]] == names
    geos = [g["name"] for g in res["geometries"]]
    assert "seed_table1" in geos and "legible" in geos
    for g in res["geometries"]:
        for k in ("scan_width_m", "letter_height_m", "stroke_m", "depth_m",
                  "stroke_over_resolution"):
            assert np.isfinite(g[k]) and g[k] > 0
        assert [m["name"] for m in g["materials"]] == names
        for m in g["materials"]:
            for k in ("brdf_class", "clarity_score", "clarity_label", "cnn_label", "iou",
                      "iou_ci", "label", "seed_label", "depth_error_m", "identification",
                      "iou_box_baseline"):
                assert k in m
            ident = m["identification"]
            assert ident["chance"] == pytest.approx(1 / len(glyphs))
            assert ident["n"] == len(glyphs) * opts.table.realisations
            assert ident["ci"][0] <= ident["accuracy"] <= ident["ci"][1]
            assert m["label"] in (1, 2, 3) and m["cnn_label"] in (1, 2, 3, None)
            assert 0 <= m["iou"] <= 1 and 0 < m["iou_box_baseline"] <= 1
            assert m["seed_label"] == SEED_FIGURE9[m["name"]]
    r = res["resolution"]
    assert r["bound_lateral_m"] > 0 and r["effective_temporal_fwhm_s"] > 0
    for method in ("lct", "fk", "iterative"):
        assert r[method]["lateral_fwhm_m"] > 0 and r[method]["axial_fwhm_m"] > 0
    rows = res["legibility_sweeps"]
    assert {x["variable"] for x in rows} == {"letter_height_m", "exposure_s"}
    for x in rows:
        assert {"value", "material", "identification", "iou", "iou_box_baseline"} <= set(x)
    sweep = next(s for s in opts.sweeps if "exposure_s" in s.variables)
    invs = (*sweep.reflectance, "best")
    assert sorted((x["material"], x["inversion"]) for x in res["smallest_legible"]) == sorted(
        (m, inv) for m in sweep.materials for inv in invs)
    for x in res["smallest_legible"]:
        assert {"material", "inversion", "letter_height_m", "exposure_s"} <= set(x)
        if x["inversion"] == "best":
            for var in ("letter_height_m", "exposure_s"):
                assert (x[var] is None) == (x[f"{var}_inversion"] is None)
    # every material row with each inversion; the tilt sweep with the measurement beside
    for g in res["geometries"]:
        for m in g["materials"]:
            assert set(m["inversions"]) == set(opts.table.reflectance)
            assert m["inversions"]["lambertian"]["identification"] == m["identification"]
    tilts = res["tilt_sweep"]
    tilt = next(s for s in opts.sweeps if "tilt_deg" in s.variables)
    assert {(t["material"], t["tilt_deg"]) for t in tilts} == {
        (m, t) for m in tilt.materials for t in dict(tilt.values)["tilt_deg"]}
    for t in tilts:
        for col in (*tilt.reflectance, "measurement"):
            assert 0 <= t[col]["identification"]["accuracy"] <= 1 and t[col]["shift_m"] >= 0
    assert "statement" in res["findings"] and "brdf" in res["findings"]["statement"]
    assert {s["variable"] for s in res["sweeps"]} == {"scan_width_m", "depth_m",
                                                       "slab_thickness_m"}
    assert all(0 <= s["iou"] <= 1 and "identification" in s for s in res["sweeps"])


def test_setup_line_names_the_snr_rule_each_method_ran():
    """The report's setup line names the SNR rule of every method: the study's pinned rule
    where it is valid for the method, else the method's own "auto"."""
    assert _reconstruction_detail({"method": "lct", "snr_rule": "gcv"}) == "SNRs by gcv"
    assert _reconstruction_detail({"method": "iterative", "snr_rule": "gcv",
                                   "iterations": 50}) == "50 iterations, SNRs by gcv"
    assert _reconstruction_detail({"method": "fk", "snr_rule": "thinning"}) == (
        "SNRs by auto (reproducibility on counts of the slab simulated)")
    assert _reconstruction_detail({"method": "iterative", "snr_rule": "reproducibility",
                                   "iterations": 5}).endswith("SNRs by auto (gcv)")


@pytest.mark.slow
def test_tiny_study_serial_and_dask_agree(tmp_path):
    serial = run_study(tmp_path / "serial", parse_study(TINY), workers=1)
    html = (tmp_path / "serial" / "report.html").read_text()
    assert html.count("data:image/png;base64,") >= 12 and "standard white plate" in html
    assert html.index("id='headline'") < html.index("<details")  # the answer first
    assert "Tilted glyphs" in html and "known BRDF" in html
    assert "dataset.overflow" in html and "max-width" in html and "box baseline" in html
    assert "SNRs by gcv)" in html  # the rule the study pins, named for every method
    res = json.loads((tmp_path / "serial" / "results.json").read_text())
    _check_contract(res, TINY)
    # the plan: one exposure curve per material x inversion of the exposure sweep
    assert {(r["material"], r["reflectance"]) for r in res["plan"]} == {
        (m, i) for m in ("quartz glass", "standard white plate") for i in ("lambertian",
                                                                          "known")}
    for r in res["plan"]:
        assert [p["exposure_s"] for p in r["curve"]] == [0.1, 1.0]
        assert r["status"] in ("bracketed", "beyond the sweep",
                               "at most the smallest exposure")
    # the legibility classifier: three held-out splits, the contract's keys, every glyph
    # reconstruction tested once per split; no real captures given: no thinning rows
    assert set(res["classifier"]) == {"splits", "volume_splits", "family", "real_thinning"}
    assert res["classifier"]["real_thinning"] == [] and res["classifier"]["family"]["rows"] == []
    assert set(res["classifier"]["splits"]) == {"glyph", "geometry", "material"}
    for name, s in res["classifier"]["splits"].items():
        assert set(s) == {"balanced_accuracy", "auc", "ece", "majority", "baseline"}
        assert 0 <= s["balanced_accuracy"] <= 1 and 0 <= s["ece"] <= 1
        folds = res["judge"]["splits"][name]["folds"]
        assert sum(f["n_test"] for f in folds) == res["judge"]["n"] > 0
        vfolds = res["judge"]["volume_splits"][name]["folds"]
        assert sum(f["n_test"] for f in vfolds) == res["judge"]["n_volume"] > res["judge"]["n"]
    assert "cnn_seed_recipe" not in res
    # the judge beside results.json answers for a volume of the study's own
    judge = clnlos.legibility(np.stack([np.eye(12)] * 2), model=tmp_path / "serial")
    assert 0 <= judge.p_legible <= 1 and judge.kind == "volume"
    assert res["labels"]["metric"] == "identification" and "fft_clarity" in res["metrics"]
    # resume: a rerun reads every sample from the cache; one file per distinct scene
    n_cached = len(sorted((tmp_path / "serial" / "cache").glob("*.npz")))
    again = run_study(tmp_path / "serial", parse_study(TINY), workers=1)
    assert len(sorted((tmp_path / "serial" / "cache").glob("*.npz"))) == n_cached
    assert again["materials"] == serial["materials"]
    fft = run_study(tmp_path / "serial", parse_study(TINY), workers=1, labels="fft")
    assert fft["labels"]["metric"] == "fft_clarity"
    seed_cnn = fft["cnn_seed_recipe"]  # the seed's recipe beside the legibility classifier
    assert 0 <= seed_cnn["val_accuracy"] <= 1 and 0 < seed_cnn["majority_baseline"] <= 1
    assert seed_cnn["n_val"] > 0  # the held-out glyphs and letter size
    assert len(seed_cnn["train_loss"]) == 3 and len(seed_cnn["val_loss"]) == 3
    assert fft["classifier"]["splits"] == serial["classifier"]["splits"]  # seeded
    pytest.importorskip("dask.distributed")
    local = run_study(tmp_path / "local", parse_study(SMALL), workers=1)
    dask = run_study(tmp_path / "dask", parse_study(SMALL), workers=2)
    for a, b in zip(local["materials"], dask["materials"], strict=True):
        assert a["iou"] == b["iou"] and a["identification"] == b["identification"]
    report = tmp_path / "serial" / "report.html"
    if shutil.which("chromium"):
        tool = Path(__file__).resolve().parents[1] / "tools" / "check_report.py"
        r = subprocess.run([sys.executable, str(tool), str(report), "-o",
                            str(tmp_path / "r.png")], capture_output=True, text=True,
                           timeout=300)
        assert r.returncode == 0, r.stdout + r.stderr
        r = subprocess.run([sys.executable, str(tool), str(report), "--first-screen", "-o",
                            str(tmp_path / "first.png")], capture_output=True, text=True,
                           timeout=300)
        assert r.returncode == 0, r.stdout + r.stderr  # the headline in the first screen


@pytest.mark.slow
def test_study_on_a_separately_started_dask_cluster(tmp_path):
    """`dask scheduler` and `dask worker` started as processes on 127.0.0.1 (bounded in time,
    always stopped): run_study(scheduler=...) gives the results of the local serial run."""
    import os
    import signal
    import time

    pytest.importorskip("dask.distributed")
    dask_cli = Path(sys.executable).with_name("dask")
    if not dask_cli.exists():
        pytest.skip("the dask command-line tool is not installed")
    small = parse_study(SMALL)
    sched_file = tmp_path / "scheduler.json"
    env = dict(os.environ, CLNLOS_THREADS="1", POCL_MAX_PTHREAD_COUNT="1")
    procs = []
    try:
        procs.append(subprocess.Popen(
            [str(dask_cli), "scheduler", "--host", "127.0.0.1", "--port", "0",
             "--no-dashboard", "--scheduler-file", str(sched_file)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
            start_new_session=True))
        deadline = time.time() + 60
        while not sched_file.exists() and time.time() < deadline:
            time.sleep(0.2)
        assert sched_file.exists(), "the scheduler did not start within 60 s"
        address = json.loads(sched_file.read_text())["address"]
        procs.append(subprocess.Popen(
            [str(dask_cli), "worker", address, "--nworkers", "1", "--nthreads", "1",
             "--no-dashboard", "--host", "127.0.0.1"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
            start_new_session=True))
        remote = run_study(tmp_path / "remote", small, scheduler=address)
    finally:
        for p in reversed(procs):
            with contextlib.suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGTERM)
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
    local = run_study(tmp_path / "local", small, workers=1)
    for a, b in zip(local["materials"], remote["materials"], strict=True):
        assert a["iou"] == b["iou"] and a["identification"] == b["identification"]
    assert [s["iou"] for s in local["sweeps"]] == [s["iou"] for s in remote["sweeps"]]


def test_findings_name_the_sweep_condition_in_words():
    from clnlos.study.report.page import sweep_condition

    assert sweep_condition("slab_thickness_m", 0.0) == "without the slab"
    assert sweep_condition("slab_thickness_m", 0.0254) == "behind a 2.54 cm slab"
    assert sweep_condition("depth_m", 0.9) == "at a target depth of 0.9 m"


def test_real_data_folder_is_named_not_searched(tmp_path, shared_data):
    """The study reads real captures only from the folder it is given (--real-data): none
    by default, a folder without them is one warning and the study goes on."""
    import warnings

    from clnlos.study.run import real_capture_dir

    assert real_capture_dir(None) is None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert real_capture_dir(tmp_path) is None
    assert len(caught) == 1 and "--real-data" in str(caught[0].message)
    assert real_capture_dir(shared_data) == shared_data / "cdt"


def test_quick_plan_runs_auto_at_the_legible_geometry_and_compares_sweeps_on_equal_glyphs(
        tmp_path):
    """The quick study: brdf auto only at its table's auto targets; every inversion of a
    legibility sweep point on the same glyphs (smallest legible compares them)."""
    quick = load_study("quick")
    mats, _ = prepare_materials(quick, tmp_path)
    plan, notes = study_plan(quick, mats)
    assert not notes
    auto_geos = {m["geometry"] for m, _ in plan if m.get("inversion") == "auto"}
    assert auto_geos == {"legible"}
    sweep = {}
    for m, _ in plan:
        if m["set"] == "legibility_sweep":
            sweep.setdefault((m["variable"], m["value"], m["material"], m["inversion"]),
                             set()).add(m["glyph"])
    for (var, val, mat, inv), glyphs in sweep.items():
        assert glyphs == sweep[(var, val, mat, "lambertian")], (var, val, mat, inv)


def test_quick_study_keeps_its_questions(tmp_path):
    """The quick study asks what the full one asks (issue 25, 50): at least four letter
    heights, exposures over two decades, both geometries, the tilt sweep; its sweep points
    at the legible geometry's own size and exposure are the table's samples (no extra
    render)."""
    quick = load_study("quick")
    values = {var: vals for s in quick.sweeps for var, vals in s.values}
    heights, exposures = values["letter_height_m"], values["exposure_s"]
    assert len(set(heights)) >= 4 and max(exposures) / min(exposures) >= 100
    assert {t.name for t in quick.targets} == {"legible", "seed_table1"}
    assert len(values["tilt_deg"]) >= 2 and max(values["tilt_deg"]) > 0
    legible = quick.target("legible")
    assert legible.height_m in heights and quick.grid.exposure_s in exposures
    mats, _ = prepare_materials(quick, tmp_path)
    plan, _ = study_plan(quick, mats)
    main = {json.dumps(s, sort_keys=True) for m, s in plan if m["set"] == "main"}
    own = {("letter_height_m", legible.height_m), ("exposure_s", quick.grid.exposure_s)}
    shared = [s for m, s in plan if m["set"] == "legibility_sweep"
              and (m["variable"], m["value"]) in own]
    assert shared and all(json.dumps(s, sort_keys=True) in main for s in shared)
