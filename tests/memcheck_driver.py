"""Runs every kernel family once on tiny inputs; executed under Oclgrind by test_memcheck.py.

Run with OCL_ICD_VENDORS pointing at Oclgrind's ICD and CLNLOS_FFT=host (VkFFT's generated
kernels are not ours and take minutes to interpret).
"""

import os

import numpy as np
import pyopencl.array as cla

from clnlos.brdf.lobes import retro_lobe
from clnlos.brdf.models import BRDFModel
from clnlos.brdf.texture import tabulate
from clnlos.brdf.texture_lookup import TextureLookup
from clnlos.diffusion import SlabTransmittance, diffusion_psf
from clnlos.forward.blur import slab_blur
from clnlos.forward.geometry import Elements
from clnlos.forward.lightcone import LightCone
from clnlos.forward.pulse import PulseBlur
from clnlos.forward.sampling import N_THETA, SurfaceSamples
from clnlos.forward.transport import LightConeTransport
from clnlos.inverse.fk import FKMigration
from clnlos.inverse.lct import LCT
from clnlos.inverse.solvers import ProxKernels, fista
from clnlos.operators.resample import AxisResample, overlap_matrix
from clnlos.physics.slab import CDT_SLAB
from clnlos.runtime.device import get_queue, has_fp64

# Keep every device array alive until exit. Oclgrind 21.10's uninitialised-value tracking
# goes wrong when a freed buffer's address is reused by a larger buffer (the cells past the
# old size read as uninitialised although a kernel or the host has written them; the values
# are right -- same pattern with the arrays kept alive: no report). Inputs here are tiny.
_KEEP = []
_array_init = cla.Array.__init__


def _keep_alive(self, *args, **kwargs):
    _array_init(self, *args, **kwargs)
    _KEEP.append(self)


cla.Array.__init__ = _keep_alive

q = get_queue("oclgrind")
# The work-group light cone adds floats by compare-and-swap on local memory, which Oclgrind's
# uninitialised-value plugin cannot follow (fatal error in Uninitialized.cpp): test_memcheck
# runs it in a second pass with that plugin off (bounds and data-race checks stay on).
VARIANTS = ("group",) if os.environ.get("CLNLOS_MEMCHECK_GROUP") == "1" else ("item",)
slab = CDT_SLAB
dtypes = [np.float32] + ([np.float64] if has_fp64(q.device) else [])
for dt in dtypes:
    # diffusion: element-wise, series table, PSF table (odd sizes on purpose)
    p = SlabTransmittance(slab, dtype=dt, queue=q)
    p(np.array([0.0, 0.01, 0.02]), np.array([0.0, 1e-10, 2e-9]))
    diffusion_psf(slab, nt=5, bin_width_s=5e-11, ny=3, nx=5, pitch_m=0.02, dtype=dt, queue=q)
    # resampling, padding (zero and mirror), Wiener and spectral kernels, LCT, f-k
    shape = (6, 3, 5)
    x = np.random.default_rng(0).random(shape).astype(dt)
    op = AxisResample(overlap_matrix(np.linspace(0, 1, 7), np.sqrt(np.linspace(0, 1, 5))),
                      (3, 5), dtype=dt, queue=q, out_plane=(4, 6), out_rows=5)
    op.apply_adjoint(op(x))
    blur = slab_blur(slab, shape, bin_width_s=5e-11, pitch_m=0.03, dtype=dt, queue=q)
    blur.apply_adjoint(blur(x))
    slab_blur(slab, shape, bin_width_s=5e-11, pitch_m=0.03, mode="wiener", snr=1e2,
              lateral_pad="mirror", dtype=dt, queue=q)(x)
    LCT(shape, bin_width_s=5e-11, scan_width_m=0.3, dtype=dt, queue=q)(x)  # + kernels/lct.cl
    FKMigration(shape, bin_width_s=5e-11, scan_width_m=0.3, dtype=dt, queue=q)(x)
    # light cone (Lambertian and BRDF-table paths, both splatting orders), pulse blur
    el = Elements(np.array([[0.01, 0.0, 0.2], [-0.02, 0.01, 0.25], [0.0, 0.0, 0.21]]),
                  np.array([[0, 0, -1.0], [0, 0.6, -0.8], [0, 0, 1.0]]), np.full(3, 1e-4))
    tables = np.stack([np.linspace(1.0, 0.1, N_THETA), np.full(N_THETA, 0.3)])
    for retro in (False, True):
        for splat in (0, 1):
            for variant in VARIANTS:
                lc = LightCone(points=3, width_m=0.1, bins=7, bin_width_s=3e-11,
                               start_s=1.2e-9, retro=retro, splat_order=splat, dtype=dt,
                               queue=q, variant=variant)
                out = lc(SurfaceSamples(el, np.ones(3), np.array([0, 1, 0], np.int32),
                                        tables if retro else None))
    PulseBlur((7, 3, 3), 35e-12, 3e-11, dtype=dt, queue=q)(out)
    # light-cone transport (margin, support) and the solver's prox kernels (with TV)
    tr = LightConeTransport((9, 3, 4), bin_width_s=5e-11, scan_width_m=0.2, margin=1,
                            depth_min_m=0.02, dtype=dt, queue=q)
    y = tr(np.random.default_rng(1).random((9, 3, 4)).astype(dt))
    tr.apply_adjoint(y)
    # a lobe's terms split over the axes (kernels/wiener.cl scale_rows, folded cone spectra)
    lobe_tr = LightConeTransport((9, 3, 4), bin_width_s=5e-11, scan_width_m=0.2,
                                 depth_min_m=0.02, dtype=dt, queue=q,
                                 lobe=retro_lobe("glossy-paint"), lobe_terms=2)
    lobe_tr.apply_adjoint(lobe_tr(np.random.default_rng(4).random((9, 3, 4)).astype(dt)))
    fista(tr, cla.to_device(q, y), cla.zeros(q, (9, 3, 4), dt), l1=1e-3, tv=1e-3,
          row_min=tr.k_min, iterations=2, lipschitz_const=1.0)
    pk = ProxKernels(q, (9, 3, 4), dt)
    a = cla.to_device(q, np.random.default_rng(2).random((9, 3, 4)).astype(dt))
    pk.weighted_residual(a, a, a, cla.empty_like(a))
    # BRDF texture lookup
    tex = tabulate(BRDFModel("phong", {}), 3, 4, 5)
    ang = np.array([[0.0, 0.0, 0.0, 0.0], [1.5707963, 3.1415, 1.5707963, -3.1415],
                    [0.3, 0.1, 0.7, 2.0]])
    TextureLookup(tex, path="buffer", dtype=dt, queue=q)(ang)
    if dt == np.float32 and q.device.image_support:
        TextureLookup(tex, path="image", queue=q)(ang)
q.finish()
print("MEMCHECK DONE", [np.dtype(d).name for d in dtypes])
