"""The study report opens with its answer: the headline figure and at most five findings in
the first screen (1400 x 900 px, headless Chromium), findings that claim no threshold beyond
the sweep and no order where the Wilson intervals overlap. A synthetic results dict (the keys
the first screen reads) stands in for a study run."""

from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path

import pytest

from clnlos.study.findings.exposure import exposure_needed
from clnlos.study.report.headline import headline_findings, order_of
from clnlos.study.score.legibility import wilson_interval

ROOT = Path(__file__).resolve().parents[1]
CLASSES = {"standard white plate": "Lambertian", "cement board": "strong diffuse",
           "fuchsia lacquer board": "strong specular + diffuse",
           "aluminium alloy sample": "strong specular", "quartz glass": "strong specular"}


def ident(k: int, n: int) -> dict:
    return {"accuracy": k / n, "ci": list(wilson_interval(k, n)), "n": n, "chance": 0.125}


def plan_row(material: str, method: str, reflectance: str, ks, albedo=1.0) -> dict:
    """A plan row (results.json ``plan``) from the legible realisations of 4 at 1 ms - 1 s."""
    curve = [{"exposure_s": e, "photons": 3e7 * e * albedo, "n": 4, "k": k,
              "fraction": k / 4, "ci": list(wilson_interval(k, 4))}
             for e, k in zip((0.001, 0.01, 0.1, 1.0), ks, strict=True)]
    a = exposure_needed(curve, 0.9)
    return {"material": material, "target": "E", "method": method,
            "reflectance": reflectance, "at": {}, "sweep": 0,
            **{k: v for k, v in a.items() if k != "fit"},
            "curve": [{**p, "fit": f} for p, f in zip(curve, a["fit"], strict=True)]}


def synthetic_results(specular_k: int = 2, n: int = 16) -> dict:
    """The keys the first screen reads: the legible geometry's materials (each series'
    identification) and the plan's rows."""
    mats = []
    for name, cls in CLASSES.items():
        spec = cls == "strong specular"
        mats.append({"name": name, "brdf_class": cls,
                     "identification": ident(specular_k if spec else n - 1, n),
                     "measurement_identification": ident(n // 2 if spec else n - 2, n),
                     "inversions": {"known": {"identification": ident(n // 2 if spec else n, n)},
                                    "auto": {"identification": ident(n // 4 if spec else n, n)}}})
    plan = [plan_row("standard white plate", "lct", "lambertian", (4, 4, 4, 4)),
            plan_row("standard white plate", "iterative", "lambertian", (4, 4, 4, 4)),
            plan_row("white plate, dark", "lct", "lambertian", (1, 3, 4, 4), albedo=0.25),
            plan_row("white plate, dark", "iterative", "lambertian", (0, 4, 4, 4), albedo=0.25),
            plan_row("aluminium alloy sample", "iterative", "lambertian", (0, 0, 1, 2)),
            plan_row("aluminium alloy sample", "iterative", "known", (0, 1, 4, 4))]
    for r in plan:  # the best of each material: the least exposure (bounds as bounds)
        mine = [x for x in plan if x["material"] == r["material"]]
        r["best"] = r is min(mine, key=lambda x: (x["status"] != "at most the smallest "
                                                  "exposure", x["exposure_needed_s"] or 9))
    return {"legible_geometry": "legible", "plan": plan,
            "options": {"legible_fraction": 0.9, "grid": {"exposure_s": 0.1}},
            "materials_prepared": [
                {"name": "standard white plate", "brdf": "standard white plate", "albedo": 1.0},
                {"name": "white plate, dark", "brdf": "standard white plate", "albedo": 0.25}],
            "geometries": [{"name": "legible", "letter_height_m": 0.3, "depth_m": 0.5,
                            "materials": mats}]}


def test_no_verdict_where_the_intervals_overlap():
    assert order_of(ident(15, 16), ident(2, 16)) == 1
    assert order_of(ident(2, 16), ident(15, 16)) == -1
    assert order_of(ident(9, 16), ident(7, 16)) == 0
    few = headline_findings(synthetic_results(specular_k=13, n=16))
    assert 1 <= len(few) <= 5
    table = [f for f in few if "Lambertian inversion, diffuse" in f]
    assert table and "overlap" in table[0] and "decides" not in table[0]
    clear = headline_findings(synthetic_results(specular_k=1, n=16))
    assert any("decides" in f for f in clear)


def test_plan_findings_never_claim_beyond_the_sweep():
    res = synthetic_results()
    found = headline_findings({k: v for k, v in res.items() if k != "geometries"})
    text = " ".join(found)
    assert "standard white plate, E: legible in 90% of realisations from at most 1 ms" in text
    assert "aluminium alloy sample" in text and "beyond the sweep" in text
    albedo = next(f for f in found if "albedo 0.25" in f)
    assert "white plate, dark (albedo 0.25) needs" in albedo


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

    body = ["<h1>How the surface material of a hidden target changes what we can read</h1>",
            headline_html(synthetic_results(), png_base64),
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
