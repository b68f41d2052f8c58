"""MkDocs hook: the numbers and references the pages show are read from the code when the site
is built, so they cannot drift from it.

Placeholders a page may hold:

- ``{{ const:MODULE.NAME }}``: a constant, formatted ``%g`` (``1e+04`` as ``1e4``);
- ``{{ list:MODULE.NAME }}``: a tuple of numbers, comma-separated;
- ``{{ falloff:METHOD }}``: the method's default radiometric exponent (its registry entry);
- ``{{ generated:reconstruction-table }}``: every reconstruction TOML key with its field,
  type, default, CLI flag, the methods that read it and the CLI's help text;
- ``{{ generated:reconstruction-example }}``: the commented example TOML of
  :mod:`clnlos.config` (tests/test_docs.py parses it with ReconstructionConfig);
- ``{{ generated:scene-example }}`` and ``{{ generated:scene-materials }}``: the commented
  example scene and the materials paragraph of :mod:`clnlos.forward.scene`;
- ``{{ generated:plausibility-table }}``: the plausibility rule of every capture
  (:data:`clnlos.checks.PLAUSIBLE`), its bounds and the unit slips it names;
- ``{{ source:PATH }}``: the text of a file of the repository (an example script) as a code
  block;
- ``{{ oracle:PATH }}``: a summary CSV of tools/oracle_params.py as a table (ORACLE_COLUMNS,
  three decimals).

The figures of tools/results named in RESULT_FIGURES are served as ``figures/NAME`` (not
copied into docs/: the result file is the one source).

The executed examples' figures (docs/examples/figures, git-ignored) are made by the build
when missing: each example of EXAMPLES without its figure runs at its small size
(``--small``), all at once, before the pages are read, so ``mkdocs build --strict`` works
from a clean clone after the set-up. An example that needs ../shared/data
(``CLNLOS_DOCS_DATA`` overrides the folder) and finds none writes no figure; its page then
says so in place of the image. ``python docs/examples/NAME.py`` remakes a figure full size.
"""

from __future__ import annotations

import csv
import dataclasses
import importlib
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PLACEHOLDER = re.compile(r"\{\{\s*(const|list|falloff|generated|source|oracle):([\w./\-]+)\s*\}\}")
RESULT_FIGURES = ("slab_calibration.png", "real_cdt_defaults.png", "lct_release_check.png",
                  "lct_release_check_lct.png",
                  "real_materials.png", "legibility_real_ladders.png", "legibility_twins.png")
# executed example (docs/examples/NAME.py) -> whether it needs ../shared/data
EXAMPLES = {"demo_round_trip": False, "ytal_round_trip": False, "real_cdt": True,
            "brdf_texture": True}
EXAMPLE_TIMEOUT_S = 600
FIGURE_LINK = re.compile(r"!\[[^\]]*\]\(figures/(\w+)\.png\)")
# the columns of an oracle summary a page shows: (CSV column, heading)
ORACLE_COLUMNS = (("capture", "capture"), ("method", "method"), ("seeds", "seeds"),
                  ("auto_iou_mean", "default IoU"), ("gcv_rule_iou_mean", "GCV rule IoU"),
                  ("today_iou_mean", "photon rule IoU"), ("oracle_iou_mean", "oracle IoU"),
                  ("gap_mean", "gap to oracle"))


def number(v) -> str:
    """1e4, 0.7, 3e5, 0.15 (a compact %g without the exponent's sign and zero padding)."""
    s = f"{float(v):.3g}"
    return re.sub(r"e\+?(-?)0*(\d)", r"e\1\2", s)


def attribute(path: str):
    module, name = path.rsplit(".", 1)
    return getattr(importlib.import_module(module), name)


def config_doc_example() -> str:
    """The indented example block of clnlos.config's module docstring."""
    config = importlib.import_module("clnlos.config")
    doc = config.__doc__ or ""
    block = doc.split("::", 1)[1].split("\n\n", 2)[1]
    return textwrap.dedent(block)


def example_comments() -> dict[tuple[str, str], str]:
    """(section, key) -> the comment of that key in clnlos.config's example (with its
    continuation lines)."""
    out: dict[tuple[str, str], str] = {}
    section, key = "", None
    for line in config_doc_example().splitlines():
        head = re.match(r"\[(\w+)\]", line)
        if head:
            section, key = head.group(1), None
            continue
        m = re.match(r"(\w+)\s*=\s*[^#]*#\s*(.*)", line)
        if m:
            key = m.group(1)
            out[(section, key)] = m.group(2).strip()
        elif key and re.match(r"\s+#\s*(.*)", line):
            out[(section, key)] += " " + line.strip().lstrip("#").strip()
        else:
            key = None
    return out


def reconstruct_help() -> dict[str, str]:
    """CLI flag -> its help text (``clnlos reconstruct``), defaults filled in."""
    cli = importlib.import_module("clnlos.app.cli")
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.choices and "reconstruct" in a.choices)
    rec = sub.choices["reconstruct"]
    out = {}
    for action in rec._actions:
        for flag in action.option_strings:
            out[flag] = (action.help or "").replace("%(default)s", str(action.default))
    return out


def reconstruction_table() -> str:
    config = importlib.import_module("clnlos.config")
    commands = importlib.import_module("clnlos.app.commands")
    methods = importlib.import_module("clnlos.inverse.methods")
    fields = {f.name: f for f in dataclasses.fields(config.ReconstructionConfig)}
    flags = {field: flag for field, flag in commands.RECON_FLAGS.values()}
    helps = reconstruct_help()
    comments = example_comments()
    rows = ["| TOML key | field | type | default | flag | methods | what |",
            "|---|---|---|---|---|---|---|"]
    for (section, key), name in config.TOML_FIELDS.items():
        f = fields[name]
        default = f.default if f.default is not dataclasses.MISSING else None
        flag = flags.get(name)
        readers = methods.methods_reading(name)
        what = helps.get(flag) if flag else comments.get((section, key), "")
        what = (what or comments.get((section, key), "")).replace("|", "\\|")
        rows.append(f"| `[{section}] {key}` | `{name}` | `{f.type}` | `{default!r}` | "
                    f"{f'`{flag}`' if flag else ''} | {', '.join(readers)} | {what} |")
    slab_flags = {key: flag for key, flag in commands.SLAB_FLAGS.values()}
    for key in config.SLAB_KEYS:
        what = comments.get(("slab", key), "")
        flag = slab_flags.get(key)
        rows.append(f"| `[slab] {key}` | `slab.{key}` | | | {f'`{flag}`' if flag else ''} | "
                    f"all | {helps.get(flag, what) if flag else what} |")
    return "\n".join(rows)


def scene_doc() -> tuple[str, str]:
    """(the example scene TOML, the materials paragraph) of clnlos.forward.scene's docstring."""
    doc = importlib.import_module("clnlos.forward.scene").__doc__ or ""
    rest = doc.split("::", 1)[1]
    block, materials = rest.split("\n\n", 2)[1:3]
    materials = re.sub(r"``([^`]+)``", r"`\1`", materials.strip())
    return textwrap.dedent(block), " ".join(materials.split())


def generated(name: str) -> str:
    if name == "reconstruction-table":
        return reconstruction_table()
    if name == "reconstruction-example":
        return "```toml\n" + config_doc_example().rstrip() + "\n```"
    if name == "scene-example":
        return "```toml\n" + scene_doc()[0].rstrip() + "\n```"
    if name == "scene-materials":
        return scene_doc()[1]
    if name == "study-template":
        return importlib.import_module("clnlos.study.file.spec").builtin_text(
            "template").rstrip()
    if name == "plausibility-table":
        return plausibility_table()
    raise KeyError(name)


# what each kind of the plausibility rule is checked on (clnlos.checks.PLAUSIBLE)
PLAUSIBLE_WHAT = {
    "scan_width_m": "the scan width (`--scan-width`, `[capture] scan_width_m`, a file's, "
                    "`[scan] width_m`)",
    "time_step_s": "a time resolution: the bin width (`--bin-width`, `[capture] bin_width_s`, "
                   "a file's, `[time] bin_width_s`) and the laser pulse (`[laser] "
                   "pulse_width_s`)",
    "depth_m": "a depth behind the scan plane: where the time window ends, c (start + n dt) "
               "/ 2, and starts, c start / 2 (`[capture] start_s`, a file's, `[time] "
               "start_s`); `max_path_m` / 2; `depth_min_m`",
}


def plausibility_table() -> str:
    """The plausibility rule as a Markdown table (usual range, possible range, slips)."""
    checks = importlib.import_module("clnlos.checks")

    def shown(v, unit):
        return checks.shown_quantity(v, unit).replace(" ", "&nbsp;")

    rows = ["| quantity | usual (no word) | possible (a warning outside usual) | "
            "likely slip above / below |", "|---|---|---|---|"]
    for kind, p in checks.PLAUSIBLE.items():
        rows.append(f"| {PLAUSIBLE_WHAT[kind]} | {shown(p.usual[0], p.unit)} to "
                    f"{shown(p.usual[1], p.unit)} | {shown(p.possible[0], p.unit)} to "
                    f"{shown(p.possible[1], p.unit)} | {p.slip_high} / {p.slip_low} |")
    return "\n".join(rows)


def oracle_table(path: str) -> str:
    """A summary CSV (mean over noise seeds per capture and method) as a Markdown table."""
    with open(ROOT / path, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))

    def cell(v: str) -> str:
        try:
            return f"{float(v):.3f}" if "." in v else v
        except ValueError:
            return v or "-"

    out = ["| " + " | ".join(h for _, h in ORACLE_COLUMNS) + " |",
           "|" + "---|" * len(ORACLE_COLUMNS)]
    out += ["| " + " | ".join(cell(r.get(c, "")) for c, _ in ORACLE_COLUMNS) + " |"
            for r in rows]
    return "\n".join(out)


def replace(match: re.Match) -> str:
    kind, arg = match.groups()
    if kind == "const":
        return number(attribute(arg))
    if kind == "list":
        return ", ".join(number(v) for v in attribute(arg))
    if kind == "oracle":
        return oracle_table(arg)
    if kind == "source":
        text = (ROOT / arg).read_text(encoding="utf-8").rstrip()
        return f"```python\n{text}\n```" if arg.endswith(".py") else f"```\n{text}\n```"
    if kind == "falloff":
        methods = importlib.import_module("clnlos.inverse.methods")
        return number(methods.default_falloffs()[arg])
    return generated(arg)


def shared_data() -> Path:
    return Path(os.environ.get("CLNLOS_DOCS_DATA", ROOT.parent / "shared" / "data"))


def make_missing_figures(docs_dir: Path) -> dict[str, str]:
    """Run (concurrently, small) every example whose figure is missing from
    ``docs_dir``/examples/figures; name -> its output, for those run. A failing example is
    a RuntimeError (the build stops)."""
    figures = Path(docs_dir) / "examples" / "figures"
    procs = {}
    for name, needs_data in EXAMPLES.items():
        if (figures / f"{name}.png").is_file():
            continue
        args = [sys.executable, str(Path(docs_dir) / "examples" / f"{name}.py"), "--small",
                "--out", str(figures)] + (["--data", str(shared_data())] if needs_data else [])
        procs[name] = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                       text=True)
    out = {}
    for name, p in procs.items():
        text, _ = p.communicate(timeout=EXAMPLE_TIMEOUT_S)
        if p.returncode != 0:
            raise RuntimeError(f"docs/examples/{name}.py --small failed:\n{text}")
        out[name] = text
    return out


def on_pre_build(config, **kwargs) -> None:
    make_missing_figures(Path(config["docs_dir"]))


def figure_or_why(match: re.Match, docs_dir: Path) -> str:
    """The image link, or where its figure could not be made (no ../shared/data) a sentence
    saying so."""
    name = match.group(1)
    if name not in EXAMPLES or (docs_dir / "examples" / "figures" / f"{name}.png").is_file():
        return match.group(0)
    return (f"*(The figure is made by running `python docs/examples/{name}.py`; it needs "
            f"`../shared/data`, absent when this site was built.)*")


def on_page_markdown(markdown: str, **kwargs) -> str:
    config = kwargs.get("config")
    if config is not None:
        docs_dir = Path(config["docs_dir"])
        markdown = FIGURE_LINK.sub(lambda m: figure_or_why(m, docs_dir), markdown)
    return PLACEHOLDER.sub(replace, markdown)


def on_files(files, config, **kwargs):
    from mkdocs.structure.files import File  # mkdocs runs this hook; the tests import the rest

    for name in RESULT_FIGURES:
        files.append(File.generated(config, f"figures/{name}",
                                    abs_src_path=str(ROOT / "tools" / "results" / name)))
    return files
