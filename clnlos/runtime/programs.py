"""Kernel programs: the packaged sources, -D defines, one cache of built programs per context."""

from __future__ import annotations

import hashlib
import importlib.resources
import importlib.util
import re
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import pyopencl as cl
from pyopencl import _find_pyopencl_include_path  # pyopencl's own header folder

from clnlos.physics.constants import C0
from clnlos.version import __version__
from clnlos.errors import KernelBuildError
from clnlos.runtime.caches import CACHES


# --------------------------------------------------------------------------- programs
def kernel_dir():
    """The packaged kernel folder (``clnlos.kernels``) as an importlib.resources Traversable."""
    return importlib.resources.files("clnlos.kernels")


_INCLUDE_RE = re.compile(r'^\s*#\s*include\s+"([^"]+)"', re.MULTILINE)


def _read_kernel(name: str) -> str:
    res = kernel_dir() / name
    if not res.is_file():
        raise KernelBuildError(f"kernel source {name!r} not found in package clnlos.kernels")
    return res.read_text(encoding="utf-8")


def source_with_headers(family: str) -> tuple[str, str]:
    """Source of ``family.cl`` and a hash over it and every local header it includes."""
    src = _read_kernel(f"{family}.cl")
    h = hashlib.sha256(src.encode())
    seen, todo = set(), _INCLUDE_RE.findall(src)
    while todo:
        inc = todo.pop()
        if inc in seen or not (kernel_dir() / inc).is_file():
            continue  # system headers such as pyopencl-complex.h come from -I paths
        seen.add(inc)
        text = _read_kernel(inc)
        h.update(inc.encode() + text.encode())
        todo.extend(_INCLUDE_RE.findall(text))
    return src, h.hexdigest()


def _include_options() -> list[str]:
    with importlib.resources.as_file(kernel_dir()) as kdir:
        return [f"-I{kdir}", f"-I{_find_pyopencl_include_path()}"]


class KernelSet:
    """The kernels of one built program, each ``cl.Kernel`` fetched once (attribute access)."""

    def __init__(self, program: cl.Program, family: str, options: tuple[str, ...]):
        self.program, self.family, self.options = program, family, options
        self._k = {k.function_name: k for k in program.all_kernels()}

    def __getattr__(self, name: str) -> cl.Kernel:
        try:
            return self.__dict__["_k"][name]
        except KeyError:
            raise AttributeError(f"kernel {name!r} not in {self.family}.cl") from None


_program_cache: dict[tuple, KernelSet] = {}
CACHES.register("built programs", _program_cache.clear)


def format_defines(defines: dict | None) -> tuple[str, ...]:
    out = []
    for k, v in sorted((defines or {}).items()):
        if v is None or v is False:
            continue
        out.append(f"-D{k}" if v is True else f"-D{k}={v}")
    return tuple(out)


def physical_defines() -> dict:
    """Constants every kernel may use, from their one Python statement (``clnlos.C0``)."""
    return {"C0_LIGHT": repr(float(C0))}


def get_kernels(ctx_or_queue, family: str, defines: dict | None = None) -> KernelSet:
    """Build (once) ``kernels/<family>.cl`` with ``-D`` defines and return its kernels.

    Cached by (context, source hash including local headers, build options).
    """
    ctx = ctx_or_queue.context if isinstance(ctx_or_queue, cl.CommandQueue) else ctx_or_queue
    src, digest = source_with_headers(family)
    options = format_defines({**physical_defines(), **(defines or {})}) + tuple(
        _include_options())
    key = (ctx, digest, options)
    hit = _program_cache.get(key)
    if hit is not None:
        return hit
    dev = ctx.devices[0]
    try:
        prg = cl.Program(ctx, src).build(options=list(options))
    except cl.RuntimeError as exc:
        raise KernelBuildError(
            f"building kernels/{family}.cl failed on device {dev.name.strip()!r} "
            f"with options {' '.join(options)}:\n{exc}"
        ) from None
    ks = KernelSet(prg, family, options)
    _program_cache[key] = ks
    return ks


def real_defines(dtype) -> dict:
    """``-D`` defines selecting the real type of a kernel family."""
    dt = np.dtype(dtype)
    return {"REAL_T": "double" if dt == np.float64 else "float",
            "USE_FP64": dt == np.float64}


def module_files(names: Iterable[str]) -> list[Path]:
    """The source files of modules or packages (a package: every ``.py`` under it)."""
    files: list[Path] = []
    for name in names:
        spec = importlib.util.find_spec(name)
        if spec is None or spec.origin is None:
            raise KernelBuildError(f"module {name!r} not found for the code digest")
        origin = Path(spec.origin)
        if spec.submodule_search_locations:
            files += sorted(origin.parent.rglob("*.py"))
        else:
            files.append(origin)
    return files


def code_digest(modules: Iterable[str], kernel_families: Iterable[str] = (),
                data_files: Iterable = ()) -> str:
    """SHA-256 over the clnlos version, the sources of ``modules`` (packages: every module
    under them), the kernel families with their local headers and ``data_files``
    (importlib.resources entries or paths): the code part of every on-disk cache key, so
    results computed by other code are never reused."""
    h = hashlib.sha256(__version__.encode())
    root = Path(importlib.util.find_spec("clnlos").origin).parent
    for f in module_files(modules):
        rel = f.relative_to(root) if f.is_relative_to(root) else Path(f.name)
        h.update(str(rel).encode() + f.read_bytes())
    for family in kernel_families:
        h.update(source_with_headers(family)[1].encode())
    for entry in data_files:
        h.update(entry.name.encode() + entry.read_bytes())
    return h.hexdigest()


def kernel_families() -> list[str]:
    """Every kernel family the package ships (``kernels/*.cl``)."""
    return sorted(e.name[:-3] for e in kernel_dir().iterdir() if e.name.endswith(".cl"))
