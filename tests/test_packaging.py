"""Release hygiene: one version (clnlos.version.__version__, read by pyproject, CITATION.cff and the
changelog agree), the licence, the no-root install route (the cpu extra: PoCL from PyPI), and
a README a new user reads in five minutes whose test command is what CI runs."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import clnlos

ROOT = Path(__file__).resolve().parents[1]


def pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))


def test_one_version():
    p = pyproject()
    assert "version" in p["project"]["dynamic"] and "version" not in p["project"]
    assert p["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "clnlos.version.__version__"}
    cff = (ROOT / "CITATION.cff").read_text(encoding="utf-8")
    assert re.search(rf"^version: {re.escape(clnlos.__version__)}$", cff, re.M)
    changelog = (ROOT / "CHANGELOG.md").read_text(encoding="utf-8")
    assert re.search(r"^## (\S+)", changelog, re.M).group(1) == clnlos.__version__


def test_licence_and_typing_marker():
    assert pyproject()["project"]["license"] == {"text": "MIT"}
    assert (ROOT / "LICENSE").read_text(encoding="utf-8").startswith("MIT License")
    assert (ROOT / "clnlos" / "py.typed").is_file()
    assert "py.typed" in pyproject()["tool"]["setuptools"]["package-data"]["clnlos"]


def test_no_root_install_route():
    """`pip install "clnlos[cpu]"` brings PoCL from PyPI; the README and the install page say
    so; the test extra brings the docs build."""
    extras = pyproject()["project"]["optional-dependencies"]
    assert any(d.startswith("pocl-binary-distribution") for d in extras["cpu"])
    assert any(d.startswith("mkdocs") for d in extras["test"])
    for doc in ("README.md", "docs/install.md"):
        assert 'pip install "clnlos[cpu]"' in (ROOT / doc).read_text(encoding="utf-8"), doc


def test_readme_is_short_and_runs_what_ci_runs():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) <= 120
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    test_cmd = "bash tools/setup.sh && .venv/bin/python -m pytest -q"
    assert test_cmd in ci and f"    {test_cmd}\n" in readme
    assert "    bash tools/setup.sh && .venv/bin/clnlos study" in readme
    for cite in ("J. Imaging", "Nature Communications", "Lindell", "Yang"):
        assert cite in readme, cite
    assert "import clnlos" in readme and "clnlos demo" in readme
