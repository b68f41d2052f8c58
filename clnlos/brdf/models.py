"""Analytic BRDF models, one interface: ``f(theta_i, phi_i, theta_s, phi_s)`` in 1/sr, vectorised.

Angles in radians; (theta_i, phi_i) points towards the source and (theta_s, phi_s) towards
the detector, both away from the surface; the mirror direction is (theta_i, phi_i + pi).
The confocal NLOS kernel needs only the retro-reflection slice f(w, w) = f(t, 0, t, 0)
(:func:`retro_slice`).

Models and parameters:

* ``lambert``: kd / pi.
* ``phong`` (energy-normalised): kd / pi + ks (n + 2) / (2 pi) max(cos a, 0)^n, a the angle
  between the detector and the mirror direction.
* ``minnaert``: kd / pi (cos ti cos ts)^(k - 1).
* ``microfacet`` (Torrance-Sparrow / Cook-Torrance): kd / pi + ks D(h) F(i.h) G / (4 cos ti
  cos ts), D = GGX (default) or Beckmann with roughness alpha, F Schlick with f0, G the
  separable Smith term of the same distribution.
* ``five-param`` (the seed's five-parameter model):
  kb [kr^2 cos a / (1 + (kr^2 - 1) cos a)] exp[b (1 - cos g)^a_exp] G / (cos ti cos ts) + diffuse,
  cos 2g = cos ti cos ts + sin ti sin ts cos(ps - pi) (the README of the measured data uses
  this phi convention), cos a = (cos ti + cos ts) / (2 cos g), G = [1 + (a/W) exp(-2g/tau)] /
  (1 + a/W) (Maxwell-Beard shadowing, a the angle of cos a, W = 1, tau = 0.5 fixed), and the
  diffuse term ``kd`` (default, as a constant it keeps reciprocity), ``kd cos ti`` or
  ``kd / cos ti`` (option ``diffuse``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from clnlos.errors import ParameterError


def _cos_mirror(ti, pi_, ts, ps):
    """cos of the angle between the detector direction and the mirror of the source direction."""
    return np.cos(ti) * np.cos(ts) - np.sin(ti) * np.sin(ts) * np.cos(ps - pi_)


def lambert(ti, pi_, ts, ps, kd=1.0):
    return np.broadcast_to(kd / np.pi, np.broadcast(ti, ts).shape).astype(float)


def phong(ti, pi_, ts, ps, kd=0.5, ks=0.5, shininess=20.0):
    c = np.clip(_cos_mirror(ti, pi_, ts, ps), 0, 1)
    return kd / np.pi + ks * (shininess + 2) / (2 * np.pi) * c**shininess


def minnaert(ti, pi_, ts, ps, kd=1.0, k=1.0):
    c = np.clip(np.cos(ti) * np.cos(ts), 1e-12, 1)
    return kd / np.pi * c ** (k - 1)


def _half_vector_cos(ti, pi_, ts, ps):
    ti, pi_, ts, ps = np.broadcast_arrays(*(np.asarray(a, float) for a in (ti, pi_, ts, ps)))
    wi = np.stack([np.sin(ti) * np.cos(pi_), np.sin(ti) * np.sin(pi_), np.cos(ti)])
    wo = np.stack([np.sin(ts) * np.cos(ps), np.sin(ts) * np.sin(ps), np.cos(ts)])
    h = wi + wo
    hn = np.linalg.norm(h, axis=0)
    hn = np.where(hn > 0, hn, 1)
    return h[2] / hn, np.clip((wi * h).sum(0) / hn, 0, 1)


def microfacet(ti, pi_, ts, ps, kd=0.0, ks=1.0, alpha=0.2, f0=0.04, distribution="ggx"):
    cos_h, cos_ih = _half_vector_cos(ti, pi_, ts, ps)
    ci, co = np.clip(np.cos(ti), 1e-9, 1), np.clip(np.cos(ts), 1e-9, 1)
    a2 = alpha * alpha
    c2 = np.clip(cos_h, 1e-9, 1) ** 2
    if distribution == "ggx":
        D = a2 / (np.pi * (c2 * (a2 - 1) + 1) ** 2)

        def g1(c):
            return 2 * c / (c + np.sqrt(a2 + (1 - a2) * c * c))
    else:
        D = np.exp((c2 - 1) / (a2 * c2)) / (np.pi * a2 * c2 * c2)

        def g1(c):
            t = np.sqrt(np.clip(1 - c * c, 0, 1)) / c
            a = np.where(t > 0, 1 / (alpha * np.where(t > 0, t, 1)), np.inf)
            return np.where(a < 1.6, (3.535 * a + 2.181 * a * a) / (1 + 2.276 * a + 2.577 * a * a),
                            1.0)
    F = f0 + (1 - f0) * (1 - cos_ih) ** 5
    return kd / np.pi + ks * D * F * g1(ci) * g1(co) / (4 * ci * co)


def five_param(ti, pi_, ts, ps, kb=1.0, kr=1.5, b=-5.0, a_exp=1.0, kd=0.1, diffuse="kd",
               W=1.0, tau=0.5):
    ci, cs = np.cos(ti), np.cos(ts)
    # the data convention writes cos(ps - pi) with phi_i = 0: in general the relative azimuth
    cos2g = np.clip(ci * cs + np.sin(ti) * np.sin(ts) * np.cos(ps - pi_ - np.pi), -1, 1)
    g = 0.5 * np.arccos(cos2g)
    cg = np.cos(g)
    cos_a = np.clip((ci + cs) / (2 * np.maximum(cg, 1e-12)), -1, 1)
    a = np.arccos(cos_a)
    G = (1 + (a / W) * np.exp(-2 * g / tau)) / (1 + a / W)
    kr2 = kr * kr
    spec = kb * (kr2 * cos_a / (1 + (kr2 - 1) * cos_a)) * np.exp(b * (1 - cg) ** a_exp) * G
    spec = spec / np.maximum(ci * cs, 1e-9)
    if diffuse == "kd":
        dif = kd
    elif diffuse == "kd_cos":
        dif = kd * ci
    elif diffuse == "kd_over_cos":
        dif = kd / np.maximum(ci, 1e-9)
    else:
        raise ParameterError("diffuse", diffuse, "'kd', 'kd_cos' or 'kd_over_cos'")
    return spec + dif


MODELS = {"lambert": lambert, "phong": phong, "minnaert": minnaert, "microfacet": microfacet,
          "torrance-sparrow": microfacet, "five-param": five_param}

_BOUNDS = {"kd": (0, 1e3), "ks": (0, 1e3), "shininess": (0, 1e6), "k": (0, 10),
           "alpha": (1e-4, 1), "f0": (0, 1), "kb": (0, 1e6), "kr": (1e-3, 1e3),
           "b": (-1e3, 1e3), "a_exp": (1e-3, 10), "W": (1e-6, 1e3), "tau": (1e-6, 1e3)}


@dataclass
class BRDFModel:
    """A named analytic model with parameters: ``model(ti, pi, ts, ps) -> f`` (1/sr)."""

    name: str
    params: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.name not in MODELS:
            raise ParameterError("material.model", self.name, " or ".join(sorted(MODELS)))
        for k, v in self.params.items():
            if k in ("distribution", "diffuse"):
                continue
            if k not in _BOUNDS:
                raise ParameterError(f"material.{k}", v, "a parameter of the "
                                     f"{self.name} model")
            lo, hi = _BOUNDS[k]
            if not isinstance(v, int | float) or not lo <= v <= hi:
                raise ParameterError(f"material.{k}", v, f"{lo:g} to {hi:g}")
        if self.params.get("distribution", "ggx") not in ("ggx", "beckmann"):
            raise ParameterError("material.distribution", self.params["distribution"],
                                 "'ggx' or 'beckmann'")

    def __call__(self, ti, pi_, ts, ps):
        return MODELS[self.name](ti, pi_, ts, ps, **self.params)


def make_model(spec: dict) -> BRDFModel:
    spec = dict(spec)
    name = spec.pop("model", None)
    if name is None:
        raise ParameterError("material.model", None, " or ".join(sorted(MODELS)))
    return BRDFModel(name, spec)


RETRO_SUB = 256  # samples per node averaging the retro slice (hat-weighted)
GRAZING = 1e-6  # angles are evaluated this far inside the hemisphere (cosines vanish at 90 deg)


def hat_samples(n: int, amax: float, sub: int, polar: bool = False
                ) -> tuple[np.ndarray, np.ndarray]:
    """(positions [n, sub], weights [n, sub] summing to 1 per node): midpoint samples of the
    hat function of each of n nodes i amax / (n - 1) over [0, amax] (an end node: its half
    inside), weighted by the hat -- and, ``polar``, by the projected solid angle sin t cos t
    of a polar angle t. With them a node holds the weighted mean of f, and the linear
    interpolant of the nodes has the integral of f in that measure whatever f's width
    (sum_i c_i int hat_i m = sum_i int f hat_i m = int f m): a lobe narrower than the node
    spacing keeps its energy instead of being read at one point."""
    h = amax / (n - 1)
    u = (np.arange(sub) + 0.5) / sub  # (0, 1)
    nodes = np.arange(n)[:, None] * h
    off = np.where(np.arange(n)[:, None] == 0, u * h,
                   np.where(np.arange(n)[:, None] == n - 1, -u * h, (2 * u - 1) * h))
    pos = nodes + off
    w = 1.0 - np.abs(off) / h
    if polar:
        w = w * np.sin(pos) * np.cos(np.minimum(pos, np.pi / 2 - GRAZING))
    return pos, w / w.sum(axis=1, keepdims=True)


def retro_slice(model, n_theta: int = 256) -> np.ndarray:
    """f(w, w) on n_theta nodes theta uniformly in [0, pi/2] (1/sr), each node the
    mean of f over its neighbourhood weighted by the hat and sin t cos t
    (:func:`hat_samples`, RETRO_SUB samples): the slice read linearly between the nodes
    keeps the energy int f(t, t) sin t cos t dt of a lobe narrower than a node."""
    pos, w = hat_samples(int(n_theta), np.pi / 2, RETRO_SUB, polar=True)
    th = np.minimum(pos, np.pi / 2 - GRAZING)
    f = np.asarray(model(th, 0.0 * th, th, 0.0 * th), float)
    f = np.nan_to_num(np.maximum(f, 0), nan=0.0, posinf=0.0)
    return (f * w).sum(axis=1)


def model_spec(model) -> dict | None:
    """The table :func:`make_model` rebuilds an analytic model from, None for others."""
    if isinstance(model, BRDFModel):
        return {"model": model.name, **model.params}
    return None
