"""Float64 reference of the slab transmittance: the plain image-dipole sum, no tricks.

Written straight from Contini et al. (1997) Eq. 36 (flux form), to be compared against the
OpenCL kernel where the plain sum is well conditioned (moderate times).
"""

import math

import numpy as np

C0 = 299_792_458.0


def fresnel_r_eff(n):
    """R_eff by brute-force midpoint integration (independent of scipy.quad in the package)."""
    if n == 1.0:
        return 0.0
    th = (np.arange(200000) + 0.5) * (np.pi / 2) / 200000
    st = n * np.sin(th)
    ci = np.cos(th)
    ct = np.sqrt(np.clip(1 - st**2, 0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        rs = (n * ci - ct) / (n * ci + ct)
        rp = (n * ct - ci) / (n * ct + ci)
    rf = np.where(st >= 1, 1.0, 0.5 * (rs**2 + rp**2))
    w = (np.pi / 2) / 200000
    r_phi = np.sum(2 * np.sin(th) * ci * rf) * w
    r_j = np.sum(3 * np.sin(th) * ci**2 * rf) * w
    return (r_phi + r_j) / (2 - r_phi + r_j)


def params(thickness_m, mu_a, mu_s_prime, n, ze_m=None):
    D = 1.0 / (3.0 * (mu_a + mu_s_prime))
    v = C0 / n
    z0 = 1.0 / mu_s_prime
    if ze_m is None:
        r = fresnel_r_eff(n)
        ze_m = 2 * D * (1 + r) / (1 - r)
    return D, v, z0, ze_m


def slab_transmittance_ref(rho, t, *, thickness_m, mu_a, mu_s_prime, n, ze_m=None, M=200):
    rho, t = np.broadcast_arrays(np.asarray(rho, float), np.asarray(t, float))
    D, v, z0, ze = params(thickness_m, mu_a, mu_s_prime, n, ze_m)
    d = thickness_m
    out = np.zeros(t.shape)
    pos = t > 0
    tp, rp = t[pos], rho[pos]
    a = 4 * D * v * tp
    s = np.zeros(tp.shape)
    for m in range(-M, M + 1):
        z1 = (1 - 2 * m) * d - 4 * m * ze - z0
        z2 = (1 - 2 * m) * d - (4 * m - 2) * ze + z0
        s += z1 * np.exp(-z1**2 / a) - z2 * np.exp(-z2**2 / a)
    out[pos] = ((4 * np.pi * D * v) ** -1.5 * tp**-2.5 * np.exp(-mu_a * v * tp - rp**2 / a)
                * 0.5 * s)
    return out


def fluence_1d_images(z, t, *, thickness_m, mu_a, mu_s_prime, n, ze_m=None, M=200):
    """The 1D image-series Green's function at depth z (used to check the zero boundaries)."""
    D, v, z0, ze = params(thickness_m, mu_a, mu_s_prime, n, ze_m)
    L = thickness_m + 2 * ze
    a = 4 * D * v * t
    g = 0.0
    for m in range(-M, M + 1):
        zp = 2 * m * L + z0
        zm = 2 * m * L - 2 * ze - z0
        g += math.exp(-(z - zp) ** 2 / a) - math.exp(-(z - zm) ** 2 / a)
    return g / math.sqrt(math.pi * a)


def slab_transmittance_mp(rho, t, *, thickness_m, mu_a, mu_s_prime, n, ze_m, M=400, dps=60):
    """High-precision (mpmath) pointwise value: no cancellation, no underflow."""
    import mpmath as mp

    mp.mp.dps = dps
    D = mp.mpf(1) / (3 * (mp.mpf(mu_a) + mp.mpf(mu_s_prime)))
    v = mp.mpf(C0) / mp.mpf(n)
    z0 = 1 / mp.mpf(mu_s_prime)
    d, ze, t, rho = mp.mpf(thickness_m), mp.mpf(ze_m), mp.mpf(t), mp.mpf(rho)
    if t <= 0:
        return 0.0
    a = 4 * D * v * t
    s = mp.mpf(0)
    for m in range(-M, M + 1):
        z1 = (1 - 2 * m) * d - 4 * m * ze - z0
        z2 = (1 - 2 * m) * d - (4 * m - 2) * ze + z0
        s += z1 * mp.exp(-z1**2 / a) - z2 * mp.exp(-z2**2 / a)
    val = (4 * mp.pi * D * v) ** mp.mpf(-1.5) * t ** mp.mpf(-2.5) * mp.exp(
        -mp.mpf(mu_a) * v * t - rho**2 / a) * s / 2
    return float(val)
