"""Small test helpers (tolerances, error measures)."""

import numpy as np

# Stated tolerances (relative L2 against the float64 reference) per precision.
TOL_DIFFUSION = {np.dtype(np.float32): 1e-5, np.dtype(np.float64): 1e-10}


def rel_l2(ref, out):
    ref = np.asarray(ref)
    out = np.asarray(out)
    if not (np.iscomplexobj(ref) or np.iscomplexobj(out)):
        ref, out = ref.astype(np.float64), out.astype(np.float64)
    else:
        ref, out = ref.astype(np.complex128), out.astype(np.complex128)
    den = np.linalg.norm(ref)
    return float(np.linalg.norm(out - ref) / (den if den > 0 else 1.0))


# a small plate behind the CDT slab, photon counts: the API and new-user tests' capture
SMALL_SCENE = """seed = 3
[scan]
width_m = 0.3
points = 8
[time]
bin_width_s = 2e-11
bins = 160
[[objects]]
shape = "rectangle"
size_m = [0.12, 0.08]
translate_m = [0.03, 0.0, 0.3]
[slab]
thickness_m = 0.0254
mu_a = 0.53
mu_s_prime = 262.0
n = 1.12
[detector]
power_w = 0.4
exposure_s = 0.5
"""
