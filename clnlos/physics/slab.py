"""A homogeneous scattering slab: its parameters and diffusion constants (pure, no OpenCL).

Physics in :mod:`clnlos.diffusion`; this module holds the plain data (so configs and scenes
parse without an OpenCL stack) and the published CDT medium.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from clnlos.physics.constants import C0
from clnlos.checks import check_keys, integer, positive
from clnlos.errors import ParameterError

FRESNEL_NODES = 64  # Gauss-Legendre nodes of the R_eff integrals (exact to ~1e-13)


def fresnel_inside(theta, n: float):
    """Unpolarised Fresnel reflectance from inside a medium of relative index n at internal
    angle theta (< the critical angle; numpy, vectorised)."""
    ci = np.cos(theta)
    st = n * np.sin(theta)
    ct = np.sqrt(np.maximum(0.0, 1.0 - st * st))
    rs = (n * ci - ct) / (n * ci + ct)
    rp = (n * ct - ci) / (n * ct + ci)
    return 0.5 * (rs * rs + rp * rp)


@lru_cache(maxsize=256)
def effective_reflection(n: float) -> float:
    """R_eff for diffuse light inside a medium of relative index ``n`` (>= 1) at its boundary.

    R_eff = (R_phi + R_j) / (2 - R_phi + R_j), with
    R_phi = int_0^{pi/2} 2 sin(th) cos(th) R_F(th) dth and
    R_j   = int_0^{pi/2} 3 sin(th) cos(th)^2 R_F(th) dth,
    R_F the unpolarised Fresnel reflectance from inside (total reflection past the
    critical angle th_c = asin(1/n)). Past th_c R_F = 1 and the integrals are 1 - sin^2 th_c
    and cos^3 th_c; below it the substitution th = th_c - s^2 removes the square-root kink
    of R_F at th_c and Gauss-Legendre in s converges exponentially. Returns 0 for n = 1.
    """
    n = float(n)
    if n == 1.0:
        return 0.0
    theta_c = math.asin(1.0 / n) if n > 1 else math.pi / 2
    x, w = np.polynomial.legendre.leggauss(FRESNEL_NODES)
    s_max = math.sqrt(theta_c)
    sv = (x + 1) / 2 * s_max
    ws = w / 2 * s_max
    th = theta_c - sv * sv
    jac = 2 * sv  # d th = -2 s ds
    rf = fresnel_inside(th, n)
    r_phi = float(np.sum(ws * jac * 2 * np.sin(th) * np.cos(th) * rf))
    r_j = float(np.sum(ws * jac * 3 * np.sin(th) * np.cos(th) ** 2 * rf))
    if theta_c < math.pi / 2:
        r_phi += 1.0 - math.sin(theta_c) ** 2
        r_j += math.cos(theta_c) ** 3
    return (r_phi + r_j) / (2 - r_phi + r_j)


@dataclass(frozen=True)
class Slab:
    """A homogeneous scattering slab (SI units; coefficients in 1/m).

    ``ze_m`` overrides the extrapolation distance computed from ``n``.
    """

    thickness_m: float
    mu_a: float
    mu_s_prime: float
    n: float
    ze_m: float | None = None

    def __post_init__(self):
        # upper bounds: well past any physical slab, before the series degenerates
        object.__setattr__(self, "thickness_m",
                           positive("thickness_m", self.thickness_m, upper=10.0))
        object.__setattr__(self, "mu_a",
                           positive("mu_a", self.mu_a, allow_zero=True, upper=1e6))
        object.__setattr__(self, "mu_s_prime",
                           positive("mu_s_prime", self.mu_s_prime, upper=1e7))
        n = positive("n", self.n, upper=5.0)
        if n < 1.0:
            raise ParameterError("n", self.n, ">= 1 (relative refractive index)")
        object.__setattr__(self, "n", n)
        if self.ze_m is not None:
            object.__setattr__(self, "ze_m",
                               positive("ze_m", self.ze_m, allow_zero=True, upper=10.0))

    @property
    def D(self) -> float:
        """Diffusion coefficient D = 1/(3 (mu_a + mu_s')), m."""
        return 1.0 / (3.0 * (self.mu_a + self.mu_s_prime))

    @property
    def v(self) -> float:
        """Speed of light in the medium, m/s."""
        return C0 / self.n

    @property
    def z0(self) -> float:
        """Depth of the isotropic source, 1/mu_s', m."""
        return 1.0 / self.mu_s_prime

    @property
    def r_eff(self) -> float:
        return effective_reflection(self.n)

    @property
    def ze(self) -> float:
        """Extrapolation distance, m (given, or 2 D (1+R_eff)/(1-R_eff))."""
        if self.ze_m is not None:
            return self.ze_m
        r = self.r_eff
        return 2.0 * self.D * (1.0 + r) / (1.0 - r)

    def total_transmittance_lossless(self) -> float:
        """Time- and space-integrated transmittance for mu_a = 0: (z0 + ze)/(d + 2 ze)."""
        return (self.z0 + self.ze) / (self.thickness_m + 2.0 * self.ze)


CDT_SLAB = Slab(thickness_m=0.0254, mu_a=0.53, mu_s_prime=262.0, n=1.12)
"""The 1-inch slab of the published CDT captures (Lindell & Wetzstein 2020, seed Table 1);
the published reconstructions override ze with ``ze_m = 0.0036`` (examples/cdt_*.toml)."""


# the keys of a [slab] table (scene TOML, reconstruction TOML, capture files)
SLAB_KEYS = ("thickness_m", "mu_a", "mu_s_prime", "n", "ze_m", "n_dipoles")


def slab_from_table(t: dict, section: str = "slab", names: dict | None = None
                    ) -> tuple[Slab, int | None]:
    """(Slab, n_dipoles) from a [slab] table; ``names`` maps keys to how the user wrote
    them (a CLI flag) for error messages."""
    names = names or {}

    def nm(k):
        return names.get(k, f"{section}.{k}")

    check_keys(section, t, SLAB_KEYS)
    nd = t.get("n_dipoles")
    if nd is not None:
        nd = integer(nm("n_dipoles"), nd, 0, 10000)
    for k in ("thickness_m", "mu_a", "mu_s_prime", "n", "ze_m"):
        if k in t and t[k] is not None:
            positive(nm(k), t[k], allow_zero=k in ("mu_a", "ze_m"))
    needed = ("thickness_m", "mu_a", "mu_s_prime", "n")
    missing = [k for k in needed if k not in t]
    if missing:  # after the values given: a bad one is named before one left out
        given = [nm(k) for k in needed if k in t]
        raise ParameterError(nm(missing[0]), None, "a number: a slab needs all of "
                             + ", ".join(nm(k) for k in needed)
                             + (f" (given: {', '.join(given)})" if given else ""))
    try:
        slab = Slab(thickness_m=t["thickness_m"], mu_a=t["mu_a"], mu_s_prime=t["mu_s_prime"],
                    n=t["n"], ze_m=t.get("ze_m"))
    except ParameterError as exc:
        raise ParameterError(nm(exc.name), exc.value, exc.allowed) from None
    return slab, nd


def slab_table(slab: Slab) -> dict:
    """The [slab] table of a Slab (inverse of :func:`slab_from_table`)."""
    d = {"thickness_m": slab.thickness_m, "mu_a": slab.mu_a, "mu_s_prime": slab.mu_s_prime,
         "n": slab.n}
    if slab.ze_m is not None:
        d["ze_m"] = slab.ze_m
    return d
