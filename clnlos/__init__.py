"""clnlos: OpenCL kernels for non-line-of-sight imaging through scattering slabs.

Stages (each a plan object with a shape/dtype/unit contract):

* :mod:`clnlos.diffusion` -- time-resolved slab transmittance (image-dipole series)
* :mod:`clnlos.runtime.device`   -- devices, queues, program cache, capability checks

Array axis order everywhere: transients ``[t, y, x]``, volumes ``[z, y, x]``; SI units.
"""

__version__ = "0.1.0"

C0 = 299_792_458.0
"""Speed of light in vacuum, m/s."""
