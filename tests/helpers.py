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
