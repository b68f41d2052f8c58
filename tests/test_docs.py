"""The docs site: the executed examples run at a small size, their figures land on the pages,
and ``mkdocs build --strict`` passes (no warning: broken links and missing images fail). The
reference pages are generated from the typed configs, and the example TOMLs they show parse
and validate. Skipped where mkdocs (the test extra) is not installed."""

from __future__ import annotations

import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from clnlos.config import TOML_FIELDS, ReconstructionConfig
from clnlos.forward.scene import Scene

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"


def hooks():
    """tools/docs_hooks.py as a module."""
    sys.path.insert(0, str(ROOT / "tools"))
    try:
        import docs_hooks
    finally:
        sys.path.pop(0)
    return docs_hooks


EXAMPLES = hooks().EXAMPLES  # example -> whether it needs ../shared/data


def test_reference_examples_parse_and_validate():
    """The example TOMLs the reference pages show (the docstrings of clnlos.config and
    clnlos.forward.scene) are valid, and the reconstruction one sets every TOML key."""
    h = hooks()
    cfg_text = h.config_doc_example()
    table = tomllib.loads(cfg_text)
    ReconstructionConfig.from_dict(table)
    keys = {(sec, key) for sec, t in table.items() if sec != "slab" for key in t}
    assert keys == set(TOML_FIELDS), set(TOML_FIELDS) ^ keys
    scene_text, materials = h.scene_doc()
    scene = Scene.from_dict(tomllib.loads(scene_text), text=scene_text)
    assert scene.slab is not None and scene.detector is not None
    assert "quartz glass" in materials


def test_reference_table_lists_every_field_and_flag():
    table = hooks().reconstruction_table()
    for (sec, key), field in TOML_FIELDS.items():
        assert f"`[{sec}] {key}`" in table and f"`{field}`" in table
    assert "`--snr-rule`" in table and "`--slab-thickness`" in table
    assert "%(default)s" not in table


def copy_site_sources(dst: Path) -> None:
    """What a clone holds for the site (docs/examples/figures is git-ignored: left out)."""
    shutil.copytree(ROOT / "docs", dst / "docs", ignore=shutil.ignore_patterns("figures"))
    shutil.copy(ROOT / "mkdocs.yml", dst / "mkdocs.yml")
    shutil.copytree(ROOT / "tools" / "results", dst / "tools" / "results")  # figures, tables
    shutil.copy(ROOT / "tools" / "docs_hooks.py", dst / "tools")
    shutil.copytree(ROOT / "examples", dst / "examples")  # the example scripts read these


@pytest.mark.slow
def test_site_builds_strict_from_a_clean_clone(tmp_path, monkeypatch):
    """The site's sources as a clone has them (no example figures: git-ignored): the build's
    hook runs the examples small and makes them (docs_hooks.make_missing_figures, what
    on_pre_build calls), then ``mkdocs build --strict`` passes. Without ../shared/data the
    examples that need it write no figure and their pages say so instead of a missing
    image."""
    pytest.importorskip("mkdocs")
    pytest.importorskip("mkdocstrings")
    copy_site_sources(tmp_path)
    figures = tmp_path / "docs" / "examples" / "figures"
    assert not figures.exists()
    h = hooks()
    monkeypatch.setenv("CLNLOS_DOCS_DATA", str(SHARED))
    outs = h.make_missing_figures(tmp_path / "docs")
    assert set(outs) == set(EXAMPLES)
    ran = {name for name in EXAMPLES if (figures / f"{name}.png").is_file()}
    assert {"demo_round_trip", "ytal_round_trip"} <= ran
    for name in ran:
        assert "wrote" in outs[name], outs[name]
    if "brdf_texture" in ran:  # the number agrees with the picture (issue 51)
        assert "fitted texture: read as 'H'" in outs["brdf_texture"], outs["brdf_texture"]
    for name in set(EXAMPLES) - ran:
        assert EXAMPLES[name] and not SHARED.is_dir(), f"{name} wrote no figure:\n{outs[name]}"
    assert h.make_missing_figures(tmp_path / "docs") == {}  # made once
    site = tmp_path / "site"
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f",
                        str(tmp_path / "mkdocs.yml"), "-d", str(site)],
                       capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "WARNING" not in r.stderr, r.stderr
    for name in EXAMPLES:
        page = (site / "examples" / name / "index.html").read_text(encoding="utf-8")
        if name in ran:
            assert f'src="../figures/{name}.png"' in page, name
            shipped = site / "examples" / "figures" / f"{name}.png"
            assert shipped.read_bytes() == (figures / f"{name}.png").read_bytes(), name
        else:
            assert "it needs <code>../shared/data</code>" in page, name
        assert "import clnlos" in page  # the script itself is on the page
    oracle = (site / "validation" / "oracle-tables" / "index.html").read_text(encoding="utf-8")
    assert oracle.count("<tr>") > 3 * 10 and "oracle IoU" in oracle
    params = (site / "parameters" / "index.html").read_text(encoding="utf-8")
    assert "{{" not in params and "MEASURED_MODEL_SNR" in params and "1e4" in params
    api = (site / "reference" / "api" / "index.html").read_text(encoding="utf-8")
    for fn in ("read_capture", "simulate", "reconstruct", "plot_volume"):
        assert f"clnlos.api.{fn}" in api or f'id="clnlos.api.{fn}"' in api, fn
    for page in ("validation/slab-calibration", "validation/real-captures"):
        html = (site / page / "index.html").read_text(encoding="utf-8")
        assert "../../figures/" in html and (site / "figures").is_dir(), page
