"""The benchmark report: JSON schema, and each knob's error falls as its accuracy rises (a
property of the kernels, not a timing)."""

import json

import pytest

from clnlos import bench
from clnlos.app.cli import main as cli_main

pytestmark = pytest.mark.slow  # runs the benchmark harness


@pytest.fixture(scope="module")
def bench_doc(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    bench.main(["--tiny", "-o", str(out), "--only", "diffusion,lightcone,brdf,iterative"])
    return json.loads((out / "bench.json").read_text()), out


def test_schema(bench_doc):
    doc, out = bench_doc
    assert doc["copy_bandwidth_gbs"] > 0 and doc["rows"]
    for r in doc["rows"]:
        for k in bench.ROW_KEYS:
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
