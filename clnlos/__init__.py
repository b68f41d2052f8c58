"""clnlos: OpenCL kernels for non-line-of-sight imaging through scattering slabs.

The Python API (:mod:`clnlos.api`, the functions the CLI calls)::

    import clnlos
    capture = clnlos.simulate("scene.toml")          # or clnlos.read_capture("x.mat")
    rec = clnlos.reconstruct(capture, method="lct")  # the recorded slab is deconvolved
    clnlos.plot_volume(rec)                          # matplotlib axes
    clnlos.study.run("out/study")                    # the material study

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

from clnlos.api import (
    plot_volume,
    read_capture,
    reconstruct,
    reconstruction_config,
    simulate,
)
from clnlos.physics.constants import C0  # the speed of light (m/s), stated there
from clnlos.version import __version__  # stated there (pyproject reads it)

__all__ = ["C0", "__version__", "plot_volume", "read_capture", "reconstruct",
           "reconstruction_config", "simulate", "study"]


def __getattr__(name: str):
    """``clnlos.study`` on first use (PEP 562): the study's imports (scipy.signal, the
    dataset's workers) stay out of ``import clnlos`` until a study runs."""
    if name == "study":
        return importlib.import_module("clnlos.study")
    raise AttributeError(f"module 'clnlos' has no attribute {name!r}")
