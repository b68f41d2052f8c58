"""clnlos: OpenCL kernels for non-line-of-sight imaging through scattering slabs.

The packages follow the physics (docs/architecture.md): :mod:`clnlos.physics` (pure slab,
grid and light-cone physics), :mod:`clnlos.diffusion` (the slab transmittance, stage 1),
:mod:`clnlos.forward` (scene -> capture), :mod:`clnlos.operators` (operators with adjoints),
:mod:`clnlos.inverse` (capture -> volume, the METHODS registry), :mod:`clnlos.runtime`
(devices, programs, buffers, FFT, caches), :mod:`clnlos.io` (captures and outputs),
:mod:`clnlos.app` (the CLI), :mod:`clnlos.brdf`, :mod:`clnlos.study`, :mod:`clnlos.bench`;
:mod:`clnlos.settings` reads the environment.

Array axis order everywhere: transients ``[t, y, x]``, volumes ``[z, y, x]``; SI units.
"""

__version__ = "0.1.0"

C0 = 299_792_458.0
"""Speed of light in vacuum, m/s."""
