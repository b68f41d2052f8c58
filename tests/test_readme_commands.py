"""Every command line of README.md and of the docs' getting-started page runs as written, in
order, in a fresh directory holding a clone's files with ``../shared`` beside it, exits 0 and
writes what it says (issue 51: a README command that failed as written, one that overwrote
the capture a later one read).

A command line is an indented line of a Markdown code block outside fences that starts with
``clnlos``, ``.venv/bin/`` or ``bash``. Skipped, each with its reason (SKIPS): the set-up
(CI runs exactly the README's two commands, .ci/run), the material study (minutes; the
README's main job, run by CI's owner), the ``COMMAND --help`` template, ``--brdf auto``
(its lobe search is tested in tests/test_lobe.py); and a command reading ``../shared/data``
when that folder is absent. The rest takes 1-4 minutes on 2 cores (235 s summed, one
command at a time, at a load average of 11 on 2 cores)."""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
PAGES = ("README.md", "docs/getting-started.md")
BIN = Path(sys.executable).parent  # the environment's clnlos
# (a pattern of the command line, why it is not run here)
SKIPS = (
    (r"^bash tools/setup\.sh", "the set-up: CI runs the README's two commands (.ci/run)"),
    (r"\bclnlos study\b(?!.*--init)", "a study takes minutes (the README's main job; "
                                      "tests/test_study.py runs one small)"),
    (r"\bclnlos COMMAND\b", "a template (COMMAND stands for a sub-command)"),
    (r"--brdf auto\b", "the held-out lobe search (2-5 extra half reconstructions, ~30 s "
                       "here); tests/test_lobe.py runs brdf auto on counts"),
)
COMMAND_TIMEOUT_S = 300


def command_lines(text: str) -> list[str]:
    """The shell command lines of a Markdown page: indented code lines (outside ``` fences)
    starting with clnlos, .venv/bin/ or bash, their trailing ``# comments`` dropped."""
    out, fenced = [], False
    for line in text.splitlines():
        if line.strip().startswith("```"):
            fenced = not fenced
            continue
        if fenced or not line.startswith("    "):
            continue
        cmd = line.strip()
        if re.match(r"(clnlos|\.venv/bin/|bash )", cmd):
            out.append(strip_comment(cmd))
    return out


def strip_comment(cmd: str) -> str:
    """The command without a trailing ``# comment`` (outside quotes)."""
    lexer = shlex.shlex(cmd, posix=True, punctuation_chars=False)
    lexer.whitespace_split, lexer.commenters = True, "#"
    words = list(lexer)
    # re-quote the words: the shell sees what the page shows
    return " ".join(shlex.quote(w) if w != "&&" else w for w in words)


def skip_reason(cmd: str) -> str | None:
    for pattern, why in SKIPS:
        if re.search(pattern, cmd):
            return why
    if "../shared/data" in cmd and not (SHARED / "data").is_dir():
        return "needs ../shared/data, absent here"
    return None


def outputs(cmd: str) -> list[str]:
    """The paths a command line says it writes: each ``-o PATH``."""
    words = shlex.split(cmd)
    return [words[i + 1] for i, w in enumerate(words[:-1]) if w in ("-o", "--output")]


def fresh_clone(tmp: Path) -> Path:
    """tmp/clone with the clone's tracked example and data files, tmp/shared -> ../shared."""
    clone = tmp / "clone"
    for folder in ("examples", "clnlos/data"):
        shutil.copytree(ROOT / folder, clone / folder)
    if SHARED.is_dir():
        (tmp / "shared").symlink_to(SHARED, target_is_directory=True)
    return clone


def test_command_lines_parse_both_pages():
    for page in PAGES:
        cmds = command_lines((ROOT / page).read_text(encoding="utf-8"))
        assert any(c.startswith("clnlos reconstruct") or ".venv/bin/clnlos" in c
                   for c in cmds), page
    readme = command_lines((ROOT / "README.md").read_text(encoding="utf-8"))
    assert sum(c.startswith("bash tools/setup.sh") for c in readme) == 2  # the two commands
    assert strip_comment('clnlos a -o x.h5 --brdf "quartz glass"   # note') == \
        "clnlos a -o x.h5 --brdf 'quartz glass'"


@pytest.mark.slow
def test_every_command_runs_in_order(tmp_path):
    """README.md's command lines in order, then the getting-started page's in the same fresh
    clone (its commands are the README's first ones: a line already run above, with the
    same outputs, is not run twice)."""
    clone = fresh_clone(tmp_path)
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}",
           "MPLBACKEND": "Agg"}
    done: set[str] = set()
    for page in PAGES:
        for cmd in command_lines((ROOT / page).read_text(encoding="utf-8")):
            shell_cmd = cmd.replace(".venv/bin/", f"{BIN}/")
            if skip_reason(cmd) or shell_cmd.replace(f"{BIN}/", "") in done:
                continue
            r = subprocess.run(shell_cmd, shell=True, cwd=clone, env=env,
                               capture_output=True, text=True, timeout=COMMAND_TIMEOUT_S)
            assert r.returncode == 0, f"{page}: {cmd}\n{r.stdout}\n{r.stderr}"
            for path in outputs(cmd):
                assert (clone / path).exists(), f"{page}: {cmd} did not write {path}"
            for path in re.findall(r"^wrote (\S+)", r.stdout, flags=re.M):
                assert (clone / path).exists(), f"{page}: {cmd} says it wrote {path}"
            assert "clnlos: error" not in r.stderr, r.stderr
            done.add(shell_cmd.replace(f"{BIN}/", ""))
    assert len(done) >= 10, done
    glossy_reads_as_the_readme_says(clone)


def glossy_reads_as_the_readme_says(clone: Path) -> None:
    """The README's words on the specular "E": assumed Lambertian it is not read as an E
    (a blob), assuming its material it is (the study's identification among its 8 glyphs)."""
    from clnlos.forward.scene import Scene
    from clnlos.io.files import read_volume
    from clnlos.study.score.legibility import glyph_templates, identify

    scene = Scene.from_toml(clone / "examples" / "scene_glossy_e.toml")
    obj = scene.objects[0]
    templates = glyph_templates(obj.height_m, obj.stroke_m, obj.translate_m[:2],
                                scene.scan_centres(), 0.0)
    read = {name: identify(read_volume(clone / "out" / f"{name}.h5")[0].max(axis=0),
                           templates)[0] for name in ("glossy_lam", "glossy_qg")}
    assert read["glossy_qg"] == obj.text and read["glossy_lam"] != obj.text, read
