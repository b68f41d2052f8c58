"""The benchmark report: JSON schema, every section runs at ``--tiny``, and each knob's error
falls as its accuracy rises (a property of the kernels, not a timing: no test asserts a time)."""

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from clnlos import bench
from clnlos.app.cli import main as cli_main
from clnlos.bench.harness import ROW_KEYS, Bench

pytestmark = pytest.mark.slow  # runs the benchmark harness

REPORT_SECTIONS = ("diffusion", "lightcone", "brdf", "iterative")  # through main: the report
SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
BRDF_DATA = SHARED / "brdf"
TORCH = importlib.util.find_spec("torch") is not None


@pytest.fixture(scope="module")
def bench_doc(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    bench.main(["--tiny", "-o", str(out), "--only", ",".join(REPORT_SECTIONS)])
    return json.loads((out / "bench.json").read_text()), out


@pytest.fixture(scope="module")
def section_rows(queue):
    """Each section not run by ``bench_doc``, at ``tiny``, on a Bench of its own."""
    runs = {}
    for name, fn in bench.SECTIONS.items():
        if name not in REPORT_SECTIONS:
            b = Bench(queue, "tiny")
            b.options["brdf_data"] = BRDF_DATA
            b.options["real_data"] = SHARED  # absent: the released capture's rows skipped
            fn(b)
            runs[name] = b
    return runs


@pytest.mark.parametrize("name", [n for n in bench.SECTIONS if n not in REPORT_SECTIONS])
def test_every_section_runs_at_tiny(section_rows, name):
    b = section_rows[name]
    assert b.rows, (name, b.notes)
    for r in b.rows:
        for k in ROW_KEYS:
            assert k in r, (name, k, r)
        assert r["median_s"] > 0  # measured (end_to_end's cli@cold keeps max_s of a no-op)


def test_only_help_lists_every_section(capsys):
    try:
        cli_main(["bench", "--help"])
    except SystemExit:
        pass
    text = " ".join(capsys.readouterr().out.split())
    assert bench.ONLY_HELP in text
    assert all(name in bench.ONLY_HELP for name in bench.SECTIONS)


def test_lightcone_grid_rows(section_rows):
    rows = section_rows["lightcone_grid"].rows
    grid = {(r["dtype"], r["impl"]): r for r in rows if r["knob"] == "grid"}
    assert {("float32", "opencl"), ("float64", "numpy")} <= set(grid)
    assert all(r["pairs_per_s"] > 0 and r["elements"] > 0 for r in grid.values())
    # the same sum as the device's most precise run (float64 where the device has it, else
    # float32 -- rusticl, many GPUs): the float32 light cone rounds its splat sums to a few
    # tens of eps32 (2.8e-6 measured on rusticl), float64 to far below 1e-6
    ref = "float64" if ("float64", "opencl") in grid else "float32"
    tol = 1e-6 if ref == "float64" else 64 * float(np.finfo(np.float32).eps)
    assert grid[("float64", "numpy")]["error"] < tol, (ref, grid[("float64", "numpy")])
    den = [r["error"] for r in rows if (r["knob"], r["dtype"]) ==
           ("density_per_m2@sampled", "float32")]
    assert len(den) >= 3 and all(b < a for a, b in zip(den, den[1:], strict=False)), den


def test_blur_reach_rows(section_rows):
    rows = {r["value"].split()[0]: r for r in section_rows["blur_reach"].rows}
    assert rows["1"]["value"] == "1 (margin 0)"
    assert rows["0.001"]["error"] < 0.1 * rows["1"]["error"]  # the margin is what matters


def test_brdf_measured_rows_or_notes(section_rows):
    b = section_rows["brdf_measured"]
    mlp = [r for r in b.rows if r["knob"] == "mlp-eval"]
    assert len(mlp) == (1 if TORCH else 0)
    fits = {r["value"]: r for r in b.rows if r["kernel"] == "brdf-measured"}
    if BRDF_DATA.is_dir():
        want = {"five-param"} | ({"mlp-seed", "mlp-improved"} if TORCH else set())
        assert set(fits) == want
        assert fits["five-param"]["test_agreement_pct"] > 0
    else:
        assert not fits and any("no measured data" in n for n in b.notes), b.notes


def test_optional_parts_skip_with_a_note(queue, tmp_path, monkeypatch):
    """Without torch and without the measured data: no rows, a note for each."""
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "torch" else real(name, *a))
    b = Bench(queue, "tiny")
    b.options["brdf_data"] = tmp_path / "absent"
    bench.SECTIONS["brdf_measured"](b)
    assert not b.rows
    assert any("torch not installed" in n for n in b.notes), b.notes
    assert any("no measured data" in n for n in b.notes), b.notes


def test_reconstruction_process_rows(section_rows):
    rows = section_rows["reconstruction_process"].rows
    by = {(r["impl"], r["knob"]): r for r in rows}
    for impl in ("opencl-hostfft", "numpy"):
        for stage in ("deconvolve", "lct", "fk", "end_to_end"):
            r = by[(impl, f"{stage}@grid")]
            assert r["value"] == "16x16x64" and r["plan_s"] > 0 and r["peak_mem_bytes"] > 0
    assert by[("opencl-hostfft", "lct@grid")]["fft_backend"] == "host"  # CLNLOS_FFT reached it


def test_schema(bench_doc):
    doc, out = bench_doc
    assert doc["copy_bandwidth_gbs"] > 0 and doc["rows"]
    for r in doc["rows"]:
        for k in ROW_KEYS:
            assert k in r, (k, r)
        assert r["median_s"] > 0 and r["min_s"] <= r["median_s"] <= r["max_s"]
    assert (out / "bench.html").read_text().count("data:image/png") >= 3
    assert doc["recommendations"]


def _series(doc, kernel, knob, dtype):
    return [r for r in doc["rows"] if (r["kernel"], r["knob"], r["dtype"], r["impl"]) ==
            (kernel, knob, dtype, "opencl")]


def test_errors_fall_as_accuracy_rises(bench_doc):
    doc, _ = bench_doc
    # float64 rows exist only on fp64 devices; the truncation error dominates either way
    best = "float64" if _series(doc, "diffusion", "n_dipoles", "float64") else "float32"
    dip = [r["error"] for r in _series(doc, "diffusion", "n_dipoles", best)
           if r["value"] in (1, 2, 3)]
    if best == "float64":
        assert dip[0] > dip[1] > dip[2]
    else:  # float32 reference: the error falls to float32 rounding (~1e-7), then stays
        assert dip[0] > 100 * dip[1] and max(dip[1:]) < 1e-6, dip
    den = [r["error"] for r in _series(doc, "lightcone", "density_per_m2", "float32")]
    assert all(b < a for a, b in zip(den, den[1:], strict=False)), den
    tex = [r["error"] for r in _series(doc, "brdf", "resolution@buffer", "float32")]
    assert all(b < a for a, b in zip(tex, tex[1:], strict=False)), tex
    # linear splatting beats nearest-bin deposit at the same density
    s0 = _series(doc, "lightcone", "density_per_m2@splat0", "float32")[-1]["error"]
    assert den[-1] < s0


def test_iterative_rows_beside_lct_and_fk(bench_doc):
    """The inversion-quality section: LCT, f-k and the iterative method at each iteration
    count, for a noise-free and a photon-noise capture; error = 1 - IoU."""
    doc, out = bench_doc
    rows = [r for r in doc["rows"] if r["kernel"] == "inversion_quality"]
    values = {r["value"] for r in rows}
    assert {"lct", "fk", "iterative@5", "iterative@20"} <= values
    assert all(0 <= r["error"] <= 1 and r["error"] == pytest.approx(1 - r["iou"]) for r in rows)
    assert {r["knob"] for r in rows} == {"method@noise-free", "method@photon-noise"}
    assert all(r["depth_error_m"] >= 0 and r["mip_rel_l2"] >= 0 for r in rows)
    assert "inversion_quality" in (out / "bench.html").read_text()


def test_cli_bench(tmp_path):
    assert cli_main(["bench", "--tiny", "--only", "diffusion", "-o", str(tmp_path)]) == 0
    assert json.loads((tmp_path / "bench.json").read_text())["rows"]


def test_auto_params_cost_rows(section_rows):
    """A row per method and rule (fixed, GCV, UPRE where a light-cone filter has it, both,
    the method's split search, auto): the split searches alone run reconstructions besides
    the one returned, the fixed row's gain is zero and every gain is against it."""
    from clnlos.bench.sections import auto_params_rules

    rows = [r for r in section_rows["auto_params_cost"].rows if not r.get("released")]
    for method in ("lct", "fk", "iterative"):
        mine = {r["rule"]: r for r in rows if r["method"] == method}
        assert set(mine) == {rule for rule, _ in auto_params_rules(method)}
        assert mine["fixed"]["iou_gain"] == 0.0
        for rule, r in mine.items():
            assert r["iou_gain"] == pytest.approx(r["iou"] - mine["fixed"]["iou"])
            assert r["error"] == pytest.approx(1 - r["iou"])
            split = rule in ("thinning", "reproducibility") or (
                rule == "auto" and r["snr_rule_used"] in ("thinning", "reproducibility"))
            assert (r["extra_reconstructions"] > 0) == split, (method, rule, r)
            assert r["peak_mem_bytes"] > 0 and r["peak_above_start_bytes"] >= 0
    assert {"upre", "gcv+upre"} <= {r["rule"] for r in rows if r["method"] == "lct"}
    assert "upre" not in {r["rule"] for r in rows if r["method"] == "fk"}


def test_auto_params_cost_on_the_released_capture(section_rows):
    """With ../shared/data: the fixed and the default light-cone SNR of LCT on the released
    S+U capture, each with the stages its volume records (the choice among them for auto)
    and its pipeline time over the fixed one's; without it a note says the rows are
    skipped."""
    b = section_rows["auto_params_cost"]
    rows = {r["rule"]: r for r in b.rows if r.get("released")}
    if not (SHARED / "lct" / "data_s_u.mat").is_file():
        assert not rows and any("no released LCT capture" in n for n in b.notes)
        pytest.skip("../shared/data/lct not present")
    assert set(rows) == {"fixed", "auto"}
    assert rows["fixed"]["over_fixed"] == 1.0
    assert "choose_inversion_snr" in rows["auto"]["stages_s"]
    assert "choose_inversion_snr" not in rows["fixed"]["stages_s"]
    assert rows["auto"]["inversion_snr_rule"] == "upre"
    assert rows["auto"]["pipeline_s"] == pytest.approx(sum(rows["auto"]["stages_s"].values()))
