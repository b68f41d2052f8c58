"""The study report opens with its answer: the headline figure and at most five findings in
the first screen (1400 x 900 px, headless Chromium), findings that claim no threshold beyond
the sweep and no order where the Wilson intervals overlap. A synthetic results dict (the keys
the first screen reads) stands in for a study run."""

from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path

import pytest

from clnlos.study.report.headline import (
    bracket_text,
    headline_findings,
    order_of,
    photons_needed_rows,
    sweep_bracket,
)
from clnlos.study.score.legibility import wilson_interval

ROOT = Path(__file__).resolve().parents[1]
CLASSES = {"standard white plate": "Lambertian", "cement board": "strong diffuse",
           "fuchsia lacquer board": "strong specular + diffuse",
           "aluminium alloy sample": "strong specular", "quartz glass": "strong specular"}


def ident(k: int, n: int) -> dict:
    return {"accuracy": k / n, "ci": list(wilson_interval(k, n)), "n": n, "chance": 0.125}


def synthetic_results(specular_k: int = 2, n: int = 16) -> dict:
    """The keys the first screen reads: the legible geometry's materials (each series'
    identification) and an exposure sweep with its photon counts."""
    mats = []
    for name, cls in CLASSES.items():
        spec = cls == "strong specular"
        mats.append({"name": name, "brdf_class": cls,
                     "identification": ident(specular_k if spec else n - 1, n),
                     "measurement_identification": ident(n // 2 if spec else n - 2, n),
                     "inversions": {"known": {"identification": ident(n // 2 if spec else n, n)},
                                    "auto": {"identification": ident(n // 4 if spec else n, n)}}})
    sweeps = []
    for m, first_legible in (("standard white plate", 0), ("fuchsia lacquer board", 2),
                             ("aluminium alloy sample", 9)):
        for j, exposure in enumerate((0.001, 0.01, 0.1, 1.0)):
            acc = 1.0 if j >= first_legible else 0.5
            for inv in ("lambertian", "known"):
                sweeps.append({"variable": "exposure_s", "value": exposure, "material": m,
                               "inversion": inv, "identification": ident(int(acc * 4), 4),
                               "measurement_identification": ident(2, 4),
                               "photon_counts": 3e4 * exposure})
    return {"legible_geometry": "legible", "legibility_sweeps": sweeps,
            "geometries": [{"name": "legible", "letter_height_m": 0.3, "depth_m": 0.5,
                            "materials": mats}]}


def test_sweep_thresholds_never_claim_beyond_the_sweep():
    assert sweep_bracket([(0.001, 1.0), (0.01, 1.0)]) == (None, 0.001)
    assert sweep_bracket([(0.001, 0.2), (0.01, 0.95)]) == (0.001, 0.01)
    assert sweep_bracket([(0.001, 0.2), (0.01, 0.5)]) == (0.01, None)
    assert bracket_text(None, 0.001, "s") == "<= 0.001 s (the smallest tried)"
    assert bracket_text(1.0, None, "s") == "> 1 s (the largest tried)"
    assert bracket_text(0.001, 0.01, "s") == "0.001 to 0.01 s"


def test_no_verdict_where_the_intervals_overlap():
    assert order_of(ident(15, 16), ident(2, 16)) == 1
    assert order_of(ident(2, 16), ident(15, 16)) == -1
    assert order_of(ident(9, 16), ident(7, 16)) == 0
    few = headline_findings(synthetic_results(specular_k=13, n=16))
    assert 1 <= len(few) <= 5
    assert "overlap" in few[0] and "decides" not in few[0]
    clear = headline_findings(synthetic_results(specular_k=1, n=16))
    assert "decides" in clear[0]
    exposure = clear[-1]
    assert "standard white plate &lt;= 0.001 s (the smallest tried)" in exposure
    assert "aluminium alloy sample &gt; 1 s (the largest tried)" in exposure
    assert "0.01 to 0.1 s" in exposure  # the lacquer board: bracketed by the sweep


def test_photons_needed_rows_bracket_each_series():
    rows = {(m, s): (lo, hi) for m, s, lo, hi in photons_needed_rows(synthetic_results())}
    assert rows[("standard white plate", "lambertian")] == (None, 30.0)
    assert rows[("aluminium alloy sample", "known")] == (3e4, None)
    assert rows[("standard white plate", "measurement")] == (3e4, None)


def chromium_or_skip():
    if not any(shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome")):
        pytest.skip("no Chromium (Debian package chromium, tools/setup.sh)")
    spec = importlib.util.spec_from_file_location("check_report",
                                                  ROOT / "tools" / "check_report.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_headline_figure_lies_in_the_first_screen(tmp_path):
    """The page as the report writes it -- its style, the headline and the findings, then a
    long rest -- in headless Chromium at 1400 x 900: the headline figure's box ends in the
    first screen, and nothing is wider than the window."""
    pytest.importorskip("matplotlib")
    check_report = chromium_or_skip()
    from clnlos.study.report.headline import headline_html
    from clnlos.study.report.page import page_html, png_base64

    real = [("letters_ut (real)", 2e3, (5e2, 2e3)), ("mannequin (real)", None, (8e3, None))]
    body = ["<h1>How the surface material of a hidden target changes what we can read</h1>",
            headline_html(synthetic_results(), png_base64, real),
            "<details><summary>details</summary><div style='height:4000px'></div></details>",
            "<div style='height:3000px'>the rest of the report</div>"]
    page = tmp_path / "report.html"
    page.write_text(page_html(body), encoding="utf-8")
    w, h = check_report.FIRST_SCREEN
    res = check_report.check(page, tmp_path / "first.png", w, h)
    assert res["headline"] is not None, res
    top, bottom = res["headline"]
    assert 0 < top < bottom <= h, res
    assert res["overflow"] is False and res["broken_images"] == 0, res
    assert (tmp_path / "first.png").stat().st_size > 10_000
