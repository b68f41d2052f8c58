"""What a legibility judge knows and how sure it is (pure numpy): the domain of the data it
was trained on, and the interval of its P(legible).

The domain of a model, recorded with it at training:

* *descriptors* of a capture (DESCRIPTORS: the scan points per side the recipe
  reconstructs, the photons per scan point, the time bin of the reconstruction (s), the scan
  width (m), the slab's thickness (m; 0: none); of a volume: the points per side of its
  MIP, averaged to the recipe's grid) and their training ranges, [min, max] of the twins'
  values (for the slab: the set of thicknesses, a capture's within SLAB_TOLERANCE of one of
  them);
* *image statistics*: per feature its training range [q_lo, q_hi] at the quantiles
  (1 -/+ DOMAIN_LEVEL) / 2, and the Mahalanobis distance of a feature vector x from the
  training set,

      d(x) = sqrt((x - m)^T S^-1 (x - m)),

  m and S the training features' mean and covariance (S regularised by 1e-6 of its trace),
  with d_q, the DOMAIN_LEVEL quantile of the training rows' own distances.

An input is *outside* the domain where a descriptor lies outside its range or d(x) > d_q;
each reason is one note. The interval of P comes from the judge's *spread models*: B
bootstrap refits (the twins resampled by scene with replacement) and the models of every
held-out fold (trained without one kind, rig or material of twins). Inside the domain it is
the central INTERVAL_LEVEL of the bootstrap models' P; outside it runs from the least to
the largest P of all the spread models, each at the features as they are and at the
features clamped to their training ranges: how far P moves when the data it was trained on
moves, where the input is unlike any of it.
"""

from __future__ import annotations

import numpy as np

DESCRIPTORS = ("points", "photons_per_point", "bin_width_s", "scan_width_m",
               "slab_thickness_m")
DESCRIPTOR_WORDS = {"points": "scan points per side", "photons_per_point":
                    "photons per scan point", "bin_width_s": "time bin (s)",
                    "scan_width_m": "scan width (m)", "slab_thickness_m": "slab thickness (m)"}
DOMAIN_LEVEL = 0.99      # the training quantile of the distance (and the features' ranges)
INTERVAL_LEVEL = 0.9     # the central share of the bootstrap P inside the domain
SLAB_TOLERANCE = 0.1     # a slab within this relative thickness of a twin's is the twins'


def feature_domain(X: np.ndarray, features) -> dict:
    """The image statistics of training features X [n, k] (module docstring)."""
    X = np.asarray(X, np.float64)
    m = X.mean(axis=0)
    S = np.cov(X, rowvar=False).reshape(X.shape[1], X.shape[1])
    S = S + 1e-6 * max(float(np.trace(S)), 1e-12) * np.eye(len(m))
    inv = np.linalg.inv(S)
    d = np.sqrt(np.einsum("ij,jk,ik->i", X - m, inv, X - m))
    lo, hi = (1 - DOMAIN_LEVEL) / 2, (1 + DOMAIN_LEVEL) / 2
    return {"features": list(features), "mean": m.tolist(), "inverse_covariance": inv.tolist(),
            "distance_limit": float(np.quantile(d, DOMAIN_LEVEL)),
            "low": np.quantile(X, lo, axis=0).tolist(),
            "high": np.quantile(X, hi, axis=0).tolist(), "level": DOMAIN_LEVEL}


def descriptor_domain(rows: list[dict], keys=DESCRIPTORS) -> dict:
    """The training ranges of the descriptors ``keys`` of rows holding them (the slab: its
    thicknesses)."""
    out = {}
    for k in keys:
        v = np.array([float(r[k]) for r in rows if r.get(k) is not None])
        if not v.size:
            continue
        out[k] = (sorted({round(float(x), 6) for x in v}) if k == "slab_thickness_m"
                  else [float(v.min()), float(v.max())])
    return out


def mahalanobis(x: np.ndarray, domain: dict) -> float:
    d = np.asarray(x, np.float64) - np.asarray(domain["mean"])
    return float(np.sqrt(max(d @ np.asarray(domain["inverse_covariance"]) @ d, 0.0)))


def descriptor_notes(values: dict, domain: dict) -> list[str]:
    """One note per descriptor of ``values`` outside its training range in ``domain``."""
    notes = []
    for k, v in values.items():
        if k not in domain or v is None:
            continue
        v = float(v)
        if k == "slab_thickness_m":
            if not any(abs(v - t) <= SLAB_TOLERANCE * max(t, 1e-12) or (v == t == 0)
                       for t in domain[k]):
                seen = ", ".join("none" if t == 0 else f"{t:g} m" for t in domain[k])
                notes.append(f"slab {'none' if v == 0 else f'{v:g} m'}: the twins had "
                             f"{seen}")
            continue
        lo, hi = domain[k]
        if not lo <= v <= hi:
            notes.append(f"{DESCRIPTOR_WORDS[k]} {v:.3g} outside the twins' "
                         f"{lo:.3g}-{hi:.3g}")
    return notes


def feature_notes(x: np.ndarray, domain: dict) -> list[str]:
    """A note when the features' distance exceeds the training limit, naming the features
    outside their training ranges."""
    d = mahalanobis(x, domain)
    if d <= domain["distance_limit"]:
        return []
    out = [f for f, v, lo, hi in zip(domain["features"], x, domain["low"], domain["high"],
                                     strict=True) if not lo <= v <= hi]
    which = f" ({', '.join(out)} outside their training range)" if out else ""
    return [f"image statistics unlike the twins': distance {d:.1f} from their mean, "
            f"{domain['distance_limit']:.1f} holds {domain['level']:.0%} of them{which}"]


def clamped(x: np.ndarray, domain: dict) -> np.ndarray:
    """The features clamped to their training ranges."""
    return np.clip(np.asarray(x, np.float64), domain["low"], domain["high"])


def interval(x: np.ndarray, bootstrap, held_out, domain: dict | None,
             outside: bool) -> list[float] | None:
    """[lo, hi] of P (module docstring) over ``bootstrap`` and ``held_out`` models (objects
    with ``predict_proba(X)``); None without bootstrap models."""
    if not bootstrap:
        return None
    x = np.asarray(x, np.float64).reshape(1, -1)
    p = np.array([float(m.predict_proba(x)[0]) for m in bootstrap])
    if not outside:
        a = (1 - INTERVAL_LEVEL) / 2
        return [float(np.quantile(p, a)), float(np.quantile(p, 1 - a))]
    xs = [x] if domain is None else [x, clamped(x[0], domain).reshape(1, -1)]
    allp = [float(m.predict_proba(v)[0]) for m in list(bootstrap) + list(held_out) for v in xs]
    return [float(min(allp)), float(max(allp))]
