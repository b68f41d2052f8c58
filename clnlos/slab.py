"""A homogeneous scattering slab: its parameters and diffusion constants (pure, no OpenCL).

Physics in :mod:`clnlos.diffusion`; this module holds the plain data (so configs and scenes
parse without an OpenCL stack) and the published CDT medium.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

from . import C0
from .checks import positive
from .errors import ParameterError


@lru_cache(maxsize=256)
def effective_reflection(n: float) -> float:
    """R_eff for diffuse light inside a medium of relative index ``n`` (>= 1) at its boundary.

    R_eff = (R_phi + R_j) / (2 - R_phi + R_j), with
    R_phi = int_0^{pi/2} 2 sin(th) cos(th) R_F(th) dth and
    R_j   = int_0^{pi/2} 3 sin(th) cos(th)^2 R_F(th) dth,
    R_F the unpolarised Fresnel reflectance from inside (total reflection past the
    critical angle). Returns 0 for n = 1.
    """
    from scipy.integrate import quad

    n = float(n)
    if n == 1.0:
        return 0.0
    theta_c = math.asin(1.0 / n) if n > 1 else math.pi / 2

    def fresnel(th: float) -> float:
        if th >= theta_c:
            return 1.0
        ci = math.cos(th)
        st = n * math.sin(th)
        ct = math.sqrt(max(0.0, 1.0 - st * st))
        rs = (n * ci - ct) / (n * ci + ct)
        rp = (n * ct - ci) / (n * ct + ci)
        return 0.5 * (rs * rs + rp * rp)

    pts = [theta_c] if theta_c < math.pi / 2 else None
    r_phi = quad(lambda th: 2 * math.sin(th) * math.cos(th) * fresnel(th), 0, math.pi / 2,
                 points=pts, limit=200)[0]
    r_j = quad(lambda th: 3 * math.sin(th) * math.cos(th) ** 2 * fresnel(th), 0, math.pi / 2,
               points=pts, limit=200)[0]
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
