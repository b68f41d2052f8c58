"""clnlos: OpenCL kernels for non-line-of-sight imaging through scattering slabs.

The Python API (:mod:`clnlos.api`, the functions the CLI calls)::

    import clnlos
    capture = clnlos.simulate("scene.toml")          # or clnlos.read_capture("x.mat")
    rec = clnlos.reconstruct(capture, method="lct")  # the recorded slab is deconvolved
    clnlos.plot_volume(rec)                          # matplotlib axes
    clnlos.study.run("out/study")                    # the material study
    clnlos.legibility("x.mat").p_legible             # the shipped judge (model=: a study's)

The packages follow the physics (docs/architecture.md): :mod:`clnlos.physics` (pure slab,
grid and light-cone physics), :mod:`clnlos.diffusion` (the slab transmittance, stage 1),
:mod:`clnlos.forward` (scene -> capture), :mod:`clnlos.operators` (operators with adjoints),
:mod:`clnlos.inverse` (capture -> volume, the METHODS registry), :mod:`clnlos.runtime`
(devices, programs, buffers, FFT, caches), :mod:`clnlos.io` (captures and outputs),
:mod:`clnlos.app` (the CLI), :mod:`clnlos.brdf`, :mod:`clnlos.study`, :mod:`clnlos.bench`;
:mod:`clnlos.settings` reads the environment.

Array axis order everywhere: transients ``[t, y, x]``, volumes ``[z, y, x]``; SI units.
"""

import importlib

from clnlos.physics.constants import C0  # the speed of light (m/s), stated there
from clnlos.version import __version__  # stated there (pyproject reads it)

# the API's names -> their module, imported on first use (PEP 562): ``import clnlos`` and the
# CLI's start-up (``clnlos --version``) load neither the pipeline nor the study
_LAZY = {"plot_volume": "clnlos.api", "read_capture": "clnlos.api",
         "reconstruct": "clnlos.api", "reconstruction_config": "clnlos.api",
         "simulate": "clnlos.api", "api": None, "study": None,
         "legibility": "clnlos.study.judge.apply"}

__all__ = ["C0", "__version__", "legibility", "plot_volume", "read_capture", "reconstruct",
           "reconstruction_config", "simulate", "study"]


def __getattr__(name: str):
    """The API (:mod:`clnlos.api`) and ``clnlos.study`` on first use (PEP 562): their
    imports (the pipeline, scipy, the study's workers) stay out of ``import clnlos``."""
    if name not in _LAZY:
        raise AttributeError(f"module 'clnlos' has no attribute {name!r}")
    module = _LAZY[name]
    if module is None:
        return importlib.import_module(f"clnlos.{name}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
