"""Small test helpers (tolerances, error measures)."""

import numpy as np

# Stated tolerances (relative L2 against the float64 reference) per precision.
TOL_DIFFUSION = {np.dtype(np.float32): 1e-5, np.dtype(np.float64): 1e-10}


def rel_l2(ref, out):
    ref = np.asarray(ref, np.float64)
    out = np.asarray(out, np.float64)
    den = np.linalg.norm(ref)
    return float(np.linalg.norm(out - ref) / (den if den > 0 else 1.0))
