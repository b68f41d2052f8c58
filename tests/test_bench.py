"""The benchmark report: JSON schema, and each knob's error falls as its accuracy rises (a
property of the kernels, not a timing)."""

import json
import sys
from pathlib import Path

import pytest

from clnlos.cli import main as cli_main

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))


@pytest.fixture(scope="module")
def bench_doc(tmp_path_factory):
    import bench_all

    out = tmp_path_factory.mktemp("bench")
    bench_all.main(["--tiny", "-o", str(out), "--only", "diffusion,lightcone,brdf"])
    return json.loads((out / "bench.json").read_text()), out


def test_schema(bench_doc):
    import bench_all

    doc, out = bench_doc
    assert doc["copy_bandwidth_gbs"] > 0 and doc["rows"]
    for r in doc["rows"]:
        for k in bench_all.ROW_KEYS:
            assert k in r, (k, r)
        assert r["median_s"] > 0 and r["min_s"] <= r["median_s"] <= r["max_s"]
    assert (out / "bench.html").read_text().count("data:image/png") >= 3
    assert doc["recommendations"]


def _series(doc, kernel, knob, dtype):
    return [r for r in doc["rows"] if (r["kernel"], r["knob"], r["dtype"], r["impl"]) ==
            (kernel, knob, dtype, "opencl")]


def test_errors_fall_as_accuracy_rises(bench_doc):
    doc, _ = bench_doc
    dip = [r["error"] for r in _series(doc, "diffusion", "n_dipoles", "float64")
           if r["value"] in (1, 2, 3)]
    assert dip[0] > dip[1] > dip[2]
    den = [r["error"] for r in _series(doc, "lightcone", "density_per_m2", "float32")]
    assert all(b < a for a, b in zip(den, den[1:], strict=False)), den
    tex = [r["error"] for r in _series(doc, "brdf", "resolution@buffer", "float32")]
    assert all(b < a for a, b in zip(tex, tex[1:], strict=False)), tex
    # linear splatting beats nearest-bin deposit at the same density
    s0 = _series(doc, "lightcone", "density_per_m2@splat0", "float32")[-1]["error"]
    assert den[-1] < s0


def test_cli_bench(tmp_path):
    assert cli_main(["bench", "--tiny", "--only", "diffusion", "-o", str(tmp_path)]) == 0
    assert json.loads((tmp_path / "bench.json").read_text())["rows"]
