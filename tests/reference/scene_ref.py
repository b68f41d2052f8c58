"""Tiny numpy forward model for synthetic checks: points/patches seen confocally (1/r^4)."""

import numpy as np

C0 = 299_792_458.0


def scan_centres(n, width):
    return (np.arange(n) + 0.5) * width / n - width / 2


def points_transient(points, weights, nt, n, width, dt):
    """tau[t, y, x] of isotropic point scatterers (x, y, z), linear splatting in time."""
    tau = np.zeros((nt, n, n))
    c = scan_centres(n, width)
    Y, X = np.meshgrid(c, c, indexing="ij")
    for (px, py, pz), w in zip(points, weights, strict=True):
        r = np.sqrt((X - px) ** 2 + (Y - py) ** 2 + pz**2)
        tb = 2 * r / C0 / dt - 0.5  # bin index whose centre is the arrival time
        k = np.floor(tb).astype(int)
        f = tb - k
        amp = w / r**4
        for kk, ww in ((k, 1 - f), (k + 1, f)):
            ok = (kk >= 0) & (kk < nt)
            np.add.at(tau, (kk[ok], *np.nonzero(ok)), (amp * ww)[ok])
    return tau


def patch_points(centre, size, n_side=9):
    cx, cy, cz = centre
    o = (np.arange(n_side) + 0.5) / n_side * size - size / 2
    return [(cx + a, cy + b, cz) for a in o for b in o], [size**2 / n_side**2] * n_side**2
