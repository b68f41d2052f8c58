"""A retroreflective surface seen by a confocal scan (pure numpy): its BRDF from the
coefficient of retroreflection, and that BRDF averaged over the scanned spot.

The coefficient of retroreflection R_A (cd lx^-1 m^-2 = 1/sr; ASTM E808, D4956) is the
luminous intensity returned per illuminance on a plane normal to the incident light per
area of sheeting. With the radiance L = I / (A cos beta) and the illuminance on the surface
E = E_perp cos beta, the BRDF in the retro direction is

    f = L / E = R_A(beta, alpha) / cos^2(beta)                                  (1/sr) (1)

(beta the entrance angle: the angle between the incident light and the normal; alpha the
observation angle: between the incident and the returned light). The observation-angle
profile is a Gaussian of rms angle sigma and the entrance-angle profile a parabola that
reaches zero at the acceptance angle beta_max,

    R_A(beta, alpha) = R_A0 g(beta) exp(-alpha^2 / (2 sigma^2)),
    g(beta) = max(0, 1 - (beta / beta_max)^2),                                       (2)

over a Lambertian floor of the sheeting's diffuse albedo rho_d (its luminance factor):
f = rho_d / pi + R_A / cos^2(beta). R_A0, sigma and beta_max are fitted to three data-sheet
points (:func:`fit_datasheet`; the points and their source: :data:`ASTM_D4956_TYPE_I_WHITE`).

In a confocal scan the laser illuminates one point of the relay wall and the detector
collects from a disc of radius a about it (its field of view on the wall, "the spot"). A
surface point at distance r returns its cone about the direction to the laser point; the
detector collects the part of the returned light that lands in the disc, of angular radius
beta_s = a / r seen from the target: the collected signal is the Lambertian model's with f
replaced by f averaged over the disc's solid angle (observation angle alpha from 0 to
beta_s, small angles),

    f_eff = rho_d / pi + f0(beta) S(beta_s / sigma),
    S = (2 sigma^2 / beta_s^2) (1 - exp(-beta_s^2 / (2 sigma^2))),
    f0(beta) = R_A0 g(beta) / cos^2(beta).                                           (3)

For beta_s << sigma, S = 1 (the cone is wider than the spot: the signal falls off as
1 / r^4, a diffuse surface's); for beta_s >> sigma, S = 2 sigma^2 r^2 / a^2 (all of the
cone lands in the spot: 1 / r^2). That is the physics behind the falloff switch of O'Toole
et al. (Nature 2018): (t/T)^2 for retroreflective targets, (t/T)^4 for diffuse ones.
S depends on r only through x = beta_s^2 / (2 sigma^2) = c / r^2 with the spot constant
c = a^2 / (2 sigma^2) (m^2) (:attr:`Retroreflector.spot_constant_m2`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# ASTM D4956 (Standard Specification for Retroreflective Sheeting for Traffic Control),
# Type I (engineering grade, enclosed glass beads), white: minimum R_A (cd lx^-1 m^-2) at
# (observation angle deg, entrance angle deg), and its minimum luminance factor Y (diffuse
# albedo); see docs/brdf.md ("Retroreflective targets").
ASTM_D4956_TYPE_I_WHITE = {
    "source": "ASTM D4956, Type I white sheeting: minimum R_A and minimum daytime "
              "luminance factor Y",
    "ra_cd_lx_m2": {(0.2, -4.0): 70.0, (0.5, -4.0): 30.0, (0.2, 30.0): 30.0,
                    (0.5, 30.0): 15.0},
    "luminance_factor": 0.27,
}
# the scanned spot's radius on the relay wall (the detector's field of view there): not
# stated by the published captures; an assumption of this preset (docs/brdf.md)
DEFAULT_SPOT_RADIUS_M = 0.01

# ranges of the physical parameters (scene-TOML overrides are checked against them)
RETRO_LIMITS = {
    "ra_peak_cd_lx_m2": (1e-3, 1e5),
    "divergence_deg": (1e-3, 30.0),
    "acceptance_deg": (1.0, 89.0),
    "spot_radius_m": (1e-5, 1.0),
    "diffuse_albedo": (0.0, 1.0),
}


def fit_datasheet(ra: dict) -> tuple[float, float, float]:
    """(R_A0 cd lx^-1 m^-2, sigma deg, beta_max deg) of (2) from data-sheet points
    {(observation deg, entrance deg): R_A}: sigma from the two observation angles at the
    smallest entrance angle, R_A0 the Gaussian's peak there divided by g of that entrance
    angle, beta_max from the ratio of R_A at the largest entrance angle to that at the
    smallest (same observation angle)."""
    ents = sorted({abs(e) for _, e in ra})
    e0, e1 = ents[0], ents[-1]
    at0 = sorted((o, v) for (o, e), v in ra.items() if abs(e) == e0)
    (o1, v1), (o2, v2) = at0[0], at0[-1]
    sigma2 = (o2 * o2 - o1 * o1) / (2.0 * math.log(v1 / v2))
    at1 = {o: v for (o, e), v in ra.items() if abs(e) == e1}
    q = at1[o1] / v1                         # g(e1) / g(e0)
    bmax2 = (e1 * e1 - q * e0 * e0) / (1.0 - q)
    g0 = 1.0 - e0 * e0 / bmax2
    peak = v1 * math.exp(o1 * o1 / (2.0 * sigma2)) / g0
    return peak, math.sqrt(sigma2), math.sqrt(bmax2)


@dataclass(frozen=True)
class Retroreflector:
    """The parameters of (2) and (3): R_A0 (cd lx^-1 m^-2), sigma (deg, rms observation
    angle), beta_max (deg, acceptance), a (m, the spot's radius), rho_d (diffuse albedo)."""

    ra_peak_cd_lx_m2: float
    divergence_deg: float
    acceptance_deg: float
    spot_radius_m: float
    diffuse_albedo: float

    @classmethod
    def preset(cls, **overrides) -> Retroreflector:
        """White glass-bead sheeting (:data:`ASTM_D4956_TYPE_I_WHITE`, fitted by
        :func:`fit_datasheet`) seen through a spot of DEFAULT_SPOT_RADIUS_M; ``overrides``
        by field name."""
        peak, sigma, bmax = fit_datasheet(ASTM_D4956_TYPE_I_WHITE["ra_cd_lx_m2"])
        base = dict(ra_peak_cd_lx_m2=peak, divergence_deg=sigma, acceptance_deg=bmax,
                    spot_radius_m=DEFAULT_SPOT_RADIUS_M,
                    diffuse_albedo=ASTM_D4956_TYPE_I_WHITE["luminance_factor"])
        base.update(overrides)
        return cls(**base)

    @property
    def sigma_rad(self) -> float:
        return math.radians(self.divergence_deg)

    @property
    def spot_constant_m2(self) -> float:
        """c = a^2 / (2 sigma^2) (m^2): S of (3) is a function of c / r^2."""
        return self.spot_radius_m ** 2 / (2.0 * self.sigma_rad ** 2)

    def cone_slice(self, theta) -> np.ndarray:
        """f0(theta) of (3) (1/sr): the cone's peak BRDF at entrance angle theta (rad)."""
        th = np.asarray(theta, np.float64)
        g = np.clip(1.0 - (th / math.radians(self.acceptance_deg)) ** 2, 0.0, None)
        return self.ra_peak_cd_lx_m2 * g / np.maximum(np.cos(th), 1e-9) ** 2

    def diffuse_slice(self, theta) -> np.ndarray:
        return np.full(np.shape(theta), self.diffuse_albedo / math.pi)

    def spot_factor(self, r_m) -> np.ndarray:
        """S of (3) at distance ``r_m`` (m) from the spot."""
        return spot_factor(self.spot_constant_m2 / np.square(np.asarray(r_m, np.float64)))


def spot_factor(x) -> np.ndarray:
    """(1 - exp(-x)) / x, x = beta_s^2 / (2 sigma^2) (1 at x = 0): S of (3)."""
    x = np.asarray(x, np.float64)
    small = x < 1e-6
    xs = np.where(small, 1.0, x)
    return np.where(small, 1.0 - 0.5 * x, -np.expm1(-xs) / xs)
