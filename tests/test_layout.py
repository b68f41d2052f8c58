"""The package's shape: no import cycles, few top-level modules, settings read in one place,
imports at the top, no private names used across modules (the registry of inversions:
tests/test_methods.py).

The one import the graph below cannot see is the registry's: clnlos.inverse.methods
imports a method's module by name when it is asked for it (importlib), and the method modules
import clnlos.inverse.methods for the base class -- a plugin table, not a cycle at import
time (methods.py imports none of them)."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "clnlos"
TOP_LEVEL_MAX = 10
# optional dependencies that stay lazy (imported where first needed), each commented there;
# scipy.fft._pocketfft: a private binding probed at run time (the public functions otherwise)
LAZY_OK = ("torch", "dask", "distributed", "pyvkfft", "matplotlib", "mpl_toolkits",
           "hypothesis", "mitsuba", "mitransient", "scipy.fft._pocketfft")


def module_name(path: Path) -> str:
    rel = path.relative_to(PKG.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def modules() -> dict[str, Path]:
    return {module_name(p): p for p in PKG.rglob("*.py")}


def imported(node: ast.AST, here: str, is_pkg: bool, known) -> list[str]:
    """The package modules an import statement loads (a ``from X import y`` loads X.y when
    that is a module, else X)."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names if a.name.startswith("clnlos")]
    if not isinstance(node, ast.ImportFrom):
        return []
    if node.level:
        base = here.split(".") if is_pkg else here.split(".")[:-1]
        base = base[:len(base) - (node.level - 1)]
        mod = ".".join(base + ([node.module] if node.module else []))
    else:
        mod = node.module or ""
    if not mod.startswith("clnlos"):
        return []
    out = []
    for a in node.names:
        sub = f"{mod}.{a.name}"
        out.append(sub if sub in known else mod)
    return out


def import_graph() -> dict[str, set[str]]:
    """Every import in the package, at the top and inside functions, as module -> modules
    (``from clnlos.a import b`` names clnlos.a.b when that is a module, else clnlos.a)."""
    mods = modules()
    graph: dict[str, set[str]] = {}
    for name, path in mods.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        deps = set()
        for node in ast.walk(tree):
            deps.update(imported(node, name, path.name == "__init__.py", mods))
        deps.discard(name)
        graph[name] = {d for d in deps if d in mods and d != "clnlos"}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycles():
    graph = import_graph()
    found = cycles(graph)
    assert not found, "import cycles: " + "; ".join(" <-> ".join(c) for c in found)
    back = sorted(f"{a} <-> {b}" for a in graph for b in graph[a] if a in graph.get(b, ()))
    assert not back, back


def package_of(module: str) -> str:
    """The package a module belongs to: ``clnlos.X`` for anything under ``clnlos/X/``, the
    module itself at the top (``clnlos.config``)."""
    return ".".join(module.split(".")[:2])


def package_graph(graph: dict[str, set[str]]) -> dict[str, set[str]]:
    """The import graph read at the level of packages (imports inside one package dropped)."""
    out: dict[str, set[str]] = {}
    for a, deps in graph.items():
        pa = package_of(a)
        out.setdefault(pa, set()).update(package_of(b) for b in deps if package_of(b) != pa)
    return out


def test_no_package_cycles():
    """No two packages import each other, through any modules (the house has no arrow
    back up: a lower layer never imports a higher one)."""
    graph = import_graph()
    found = cycles(package_graph(graph))
    detail = [f"{a} -> {b}" for c in found for a in sorted(graph) for b in sorted(graph[a])
              if package_of(a) in c and package_of(b) in c and package_of(a) != package_of(b)]
    assert not found, "package cycles: " + "; ".join(" <-> ".join(c) for c in found) + \
        " (" + ", ".join(detail) + ")"


def face_imports() -> list[str]:
    """Imports of the package's face (``clnlos/__init__.py``) from inside the package:
    ``import clnlos`` or ``from clnlos import name`` where ``clnlos.name`` is no module (the
    constants and the version have their own modules: clnlos.physics.constants,
    clnlos.version)."""
    mods = modules()
    bad = []
    for name, path in mods.items():
        if name == "clnlos":
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                bad += [f"{name}:{node.lineno} import clnlos" for a in node.names
                        if a.name == "clnlos"]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:  # relative: from . import x inside clnlos/ top modules
                    parts = name.split(".")[:-node.level] if path.name != "__init__.py" \
                        else name.split(".")[:len(name.split(".")) - node.level + 1]
                    base = ".".join(parts + ([node.module] if node.module else []))
                if base == "clnlos":
                    bad += [f"{name}:{node.lineno} from clnlos import {a.name}"
                            for a in node.names if f"clnlos.{a.name}" not in mods]
    return bad


def test_no_import_of_the_package_face_from_inside():
    found = face_imports()
    assert not found, found


def test_package_cycle_finder_reads_packages():
    graph = {"clnlos.study.run": {"clnlos.app.progress"},
             "clnlos.app.commands": {"clnlos.study.run"}, "clnlos.config": {"clnlos.app.cli"}}
    assert package_graph(graph) == {"clnlos.study": {"clnlos.app"},
                                    "clnlos.app": {"clnlos.study"}, "clnlos.config": {"clnlos.app"}}
    assert cycles(package_graph(graph)) == [["clnlos.app", "clnlos.study"]]


def test_cycle_finder_finds_a_cycle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_at_most_ten_top_level_modules():
    top = sorted(p.name for p in PKG.glob("*.py"))
    assert len(top) <= TOP_LEVEL_MAX, top


# modules that touch os.environ for other processes only (never to read a setting):
# the study pins the threads of the Dask workers it spawns and restores the variables
# after; the bench copies the environment for a worker with another FFT backend
ENVIRON_FOR_CHILDREN = {"study/samples/render.py", "bench/sections.py"}


def test_environment_read_in_one_place():
    """Every CLNLOS_* variable is read by clnlos.settings alone: no other module touches
    os.environ or getenv, but for the named ones that set up child processes."""
    pattern = re.compile(r"os\.environ|getenv|environ\.get")
    touch = sorted(str(p.relative_to(PKG)) for p in PKG.rglob("*.py")
                   if p.name != "settings.py" and pattern.search(p.read_text(encoding="utf-8")))
    assert set(touch) <= ENVIRON_FOR_CHILDREN, touch


def function_imports() -> list[str]:
    """Imports inside functions of package modules not of a lazy optional dependency."""
    bad = []
    for name, path in modules().items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for fn in ast.walk(tree):
            if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for node in ast.walk(fn):
                if isinstance(node, ast.Import):
                    mods = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and not node.level:
                    mods = [node.module or ""]
                elif isinstance(node, ast.ImportFrom):
                    mods = ["clnlos (relative)"]
                else:
                    continue
                bad += [f"{name}:{node.lineno} {m}" for m in mods
                        if not m.startswith(LAZY_OK)]
    return bad


def test_imports_at_the_top():
    found = function_imports()
    assert not found, found


def test_no_private_names_across_modules():
    """No ``from clnlos.x import _private`` and no ``obj._private(...)`` call on another
    module's object (attributes of ``self`` and ``cls`` are a class's own)."""
    bad = []
    for name, path in modules().items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("clnlos"):
                bad += [f"{name}:{node.lineno} imports {a.name}" for a in node.names
                        if a.name.startswith("_") and not a.name.startswith("__")]
            if (isinstance(node, ast.Attribute) and node.attr.startswith("_")
                    and not node.attr.startswith("__")
                    and not (isinstance(node.value, ast.Name)
                             and node.value.id in ("self", "cls"))):
                bad.append(f"{name}:{node.lineno} uses .{node.attr}")
    assert not bad, bad


@pytest.mark.parametrize("needle", ["def get_context", "png_bytes", "def significant"])
def test_dead_code_stays_removed(needle):
    hits = [str(p.relative_to(PKG)) for p in PKG.rglob("*.py")
            if needle in p.read_text(encoding="utf-8")]
    assert not hits, hits


# memo caches of pure functions (values, not device state) that need no clearing
PURE_MEMOS = {"physics/slab.py:effective_reflection", "brdf/catalog.py:preset_table",
              "brdf/lobes.py:named_lobe", "brdf/lobes.py:ladder_lobe"}


def test_every_cache_is_registered():
    """A function cached with functools (cache / lru_cache) is registered with
    clnlos.runtime.caches.CACHES (its ``cache_clear`` named in a ``CACHES.register``) or is
    a listed pure memo."""
    bad = []
    for path in PKG.rglob("*.py"):
        text = path.read_text(encoding="utf-8")
        for node in ast.walk(ast.parse(text)):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            names = {d.func.id if isinstance(d, ast.Call) and isinstance(d.func, ast.Name)
                     else d.id if isinstance(d, ast.Name)
                     else d.attr if isinstance(d, ast.Attribute) else ""
                     for d in node.decorator_list}
            if names & {"cache", "lru_cache"}:
                where = f"{path.relative_to(PKG)}:{node.name}"
                if where not in PURE_MEMOS and f"{node.name}.cache_clear" not in text:
                    bad.append(where)
    assert not bad, bad


def loaded_modules(code: str) -> set[str]:
    """The modules a fresh interpreter has loaded after running ``code``."""
    out = subprocess.run([sys.executable, "-c", code + "\nimport sys\n"
                          "print('\\n'.join(sorted(sys.modules)))"],
                         capture_output=True, text=True, check=True)
    return set(out.stdout.split())


HEAVY = ("torch", "matplotlib", "scipy.stats", "clnlos.study", "clnlos.bench", "dask")


def test_the_cli_starts_light():
    """`clnlos --version` loads no command's module; `clnlos reconstruct` (its module and the
    API) neither the study, scipy.stats, torch nor matplotlib."""
    start = loaded_modules("import clnlos.app.cli as c; c.build_parser(only='')")
    assert not {m for m in start if m.startswith(("clnlos.app.commands", "clnlos.api",
                                                  "pyopencl", "scipy") + HEAVY)}
    recon = loaded_modules("import clnlos, clnlos.app.cli as c; c.build_parser('reconstruct');"
                           " clnlos.reconstruct")
    assert "clnlos.inverse.pipeline" in recon  # the check can see what it checks
    assert not {m for m in recon if m.startswith(HEAVY)}, sorted(
        m for m in recon if m.startswith(HEAVY))


def test_parsing_modules_need_no_opencl():
    """The typed configs and the scene parser (pure parameters and text) load no OpenCL stack:
    a scene or a reconstruction TOML checks on a machine without a driver."""
    mods = loaded_modules("import clnlos.config, clnlos.forward.scene, clnlos.checks")
    assert "clnlos.forward.scene" in mods  # the check can see what it checks
    assert not {m for m in mods if m.startswith("pyopencl")}, sorted(
        m for m in mods if m.startswith(("pyopencl", "clnlos.runtime")))
