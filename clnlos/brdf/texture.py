"""Tabulated BRDF textures: export any model (the MLP included) and look it up on the device.

File (HDF5, ``format = "clnlos-brdf-texture"``, ``version = 1``): dataset ``texture``
float32 [n_theta_i, n_theta_s, n_dphi] on nodes theta = i (pi/2)/(n-1), delta_phi =
k pi/(n_dphi - 1); dataset ``retro`` float32 [n_retro], the confocal slice f(w, w) on nodes
theta = i (pi/2)/(n_retro - 1) (what the light-cone kernel reads); attributes with the
grid, the resolution and the model's provenance (JSON).

Nodes: a point sample of the model where it is smooth on the grid; where it is not -- a
lobe narrower than the node spacing, whose point samples would spread a peak over whole
cells -- the hat-weighted mean over the node's neighbourhood (:func:`tabulate`), so that
the trilinear interpolant keeps the model's energy at any resolution. A texture is checked
against its model when it is used (:func:`checked_texture`): the model's table is stored in
the file (``provenance["model_spec"]``, analytic models) or named (``model_file``).

Lookup: ``kernels/brdf.cl``, trilinear; through a 3D image with a linear sampler where the
device supports images (float32), else from a buffer (any precision). :func:`lookup_numpy`
is the float64 reference.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from clnlos.brdf.catalog import TEXTURE_FORMAT
from clnlos.brdf.mlp import CHECK_QUADRATURE, albedo_quadrature
from clnlos.brdf.models import GRAZING, hat_samples, make_model, retro_slice
from clnlos.brdf.store import fit_warning, load_model
from clnlos.checks import input_file
from clnlos.errors import InputFileError, ParameterError
from clnlos.io.files import write_h5
from clnlos.runtime.limits import check_memory

FORMAT, VERSION = TEXTURE_FORMAT, 1
# tabulate: nodes per model evaluation (bounds its temporaries), host bytes per node of the
# texture (float32, and its compressed copy while written) and of one evaluation (the
# MLP's activations, the analytic models' intermediates; generous)
TABULATE_CHUNK = 1 << 18
TEXTURE_BYTES_PER_NODE = 4 + 4
MODEL_BYTES_PER_NODE = 2048
MIN_NODES, MAX_NODES = 2, 4096  # nodes per texture axis (and of the retro slice)
SHARP_D2 = 0.1  # a node whose second difference exceeds this fraction of its 3-node sum
#                 along an axis (or an end node 3x off its neighbour) does not resolve f there
NODE_SUB = 4    # incidence samples per theta_i node averaging such a node (hat-weighted)
FALLBACK_SUB = 2  # samples per axis of a node the lobe quadrature does not resolve
TEXTURE_TOL = 0.05  # a texture whose directional albedo or retro-slice energy departs from
#                     its model's by more (relative to the largest) is re-tabulated


@dataclass
class BRDFTexture:
    texture: np.ndarray  # [n_ti, n_ts, n_dp]
    retro: np.ndarray  # [n_retro]
    provenance: dict

    @property
    def shape(self):
        return self.texture.shape


def tabulate(model, n_theta: int = 64, n_dphi: int = 64, n_retro: int = 256,
             provenance: dict | None = None) -> BRDFTexture:
    """Evaluate ``model(ti, pi, ts, ps)`` on the texture grid (phi_i = 0, phi_s = delta_phi):
    point samples, then the hat-weighted mean (NODE_SUB samples per axis) at the nodes where
    the point samples are not smooth (:func:`sharp_nodes`, grown by one node); the retro
    slice by :func:`clnlos.brdf.models.retro_slice`."""
    for name, v in (("n_theta", n_theta), ("n_dphi", n_dphi), ("n_retro", n_retro)):
        if int(v) != v or not MIN_NODES <= v <= MAX_NODES:
            raise ParameterError(name, v, f"an integer from {MIN_NODES} to {MAX_NODES}")
    shape = (int(n_theta), int(n_theta), int(n_dphi))
    check_memory(f"BRDF texture {shape[0]} x {shape[1]} x {shape[2]} [theta_i, theta_s, "
                 "dphi] (n_theta = --resolution, n_dphi = --dphi)",
                 host=int(np.prod(shape, dtype=float)) * TEXTURE_BYTES_PER_NODE
                 + TABULATE_CHUNK * MODEL_BYTES_PER_NODE)
    th = np.minimum(np.linspace(0, np.pi / 2, n_theta), np.pi / 2 - GRAZING)
    dp = np.linspace(0, np.pi, n_dphi)
    tex = np.empty(shape, np.float32)
    flat = tex.reshape(-1)
    for a in range(0, flat.size, TABULATE_CHUNK):
        i, j, k = np.unravel_index(np.arange(a, min(a + TABULATE_CHUNK, flat.size)), shape)
        flat[a:a + i.size] = _positive(model(th[i], np.zeros(i.size), th[j], dp[k]))
    _average_nodes(model, tex, grow(sharp_nodes(tex)))
    retro = retro_slice(model, int(n_retro))
    prov = dict(provenance or {})
    prov["node_values"] = "hat-averaged where point samples do not resolve the model"
    return BRDFTexture(tex, retro.astype(np.float32), prov)


def _positive(f) -> np.ndarray:
    return np.nan_to_num(np.maximum(np.asarray(f, float), 0), nan=0.0, posinf=0.0)


def sharp_nodes(tex: np.ndarray) -> np.ndarray:
    """Nodes [n_ti, n_ts, n_dp] where the table is not smooth along some axis: its second
    difference above SHARP_D2 of the sum of the three nodes, or, at an end, a value more
    than 3x off its neighbour's (either way)."""
    t = np.asarray(tex, np.float64)
    out = np.zeros(t.shape, bool)
    for ax in range(3):
        a = np.moveaxis(t, ax, 0)
        o = np.moveaxis(out, ax, 0)
        if a.shape[0] >= 3:
            d2 = np.abs(a[:-2] - 2 * a[1:-1] + a[2:])
            o[1:-1] |= d2 > SHARP_D2 * (a[:-2] + a[1:-1] + a[2:])
        for end, nb in ((0, 1), (-1, -2)):
            hi, lo = np.maximum(a[end], a[nb]), np.minimum(a[end], a[nb])
            o[end] |= hi > 3 * lo + 1e-30
    return out


def grow(mask: np.ndarray) -> np.ndarray:
    """``mask`` with every node's six neighbours added (a lobe between nodes feeds both)."""
    out = mask.copy()
    for ax in range(mask.ndim):
        a, o = np.moveaxis(mask, ax, 0), np.moveaxis(out, ax, 0)
        o[1:] |= a[:-1]
        o[:-1] |= a[1:]
    return out


LOBE_THETA_H = (96, 64, 1e-5)  # half-vector quadrature of a sharp node: log-spaced theta_h
#                                 nodes from the last value (rad) to pi/2, phi_h nodes
RESOLVED_HAT = 0.1  # the quadrature resolves a node's hat where it integrates it this well


def _average_nodes(model, tex: np.ndarray, nodes: np.ndarray) -> None:
    """tex[nodes] <- the mean of the model over each node's neighbourhood, weighted by the
    hats and the projected solid angle: for each incidence sample (NODE_SUB per theta_i
    node), the model on a half-vector quadrature (:data:`LOBE_THETA_H`: dense at the
    mirror direction, where a narrow lobe lies) scattered into the (theta_s, delta_phi)
    hats and divided by the hats' exact integrals -- so the nodes' interpolant keeps the
    model's directional albedo; a node whose hat that quadrature does not resolve (far from
    the mirror direction) takes NODE_SUB^3 hat-weighted samples instead."""
    if not nodes.any():
        return
    n_t, _, n_d = tex.shape
    pt, wt = hat_samples(n_t, np.pi / 2, NODE_SUB, polar=True)
    hat_t = _hat_integrals(n_t, np.pi / 2, polar=True)
    hat_d = 2.0 * _hat_integrals(n_d, np.pi)  # phi_s over [0, 2 pi) folds onto [0, pi]
    exact = hat_t[:, None] * hat_d[None, :]
    fallback = np.zeros(nodes.shape, bool)
    for i in np.nonzero(nodes.any(axis=(1, 2)))[0]:
        num, qden = np.zeros((n_t, n_d)), np.zeros((n_t, n_d))
        quads = [(_half_vector_quadrature(float(ti)), ti, w_i) for ti, w_i in
                 zip(np.minimum(pt[i], np.pi / 2 - GRAZING), wt[i], strict=True)]
        ts = np.concatenate([q[0][0] for q in quads])
        ps = np.concatenate([q[0][1] for q in quads])
        ti = np.concatenate([np.full(q[0][0].size, q[1]) for q in quads])
        w = np.concatenate([q[0][2] * q[2] for q in quads])
        f = _positive(model(ti, np.zeros(ts.size), ts, ps))
        _scatter_hats(num, ts, np.abs(ps), w * f, n_t, n_d)
        _scatter_hats(qden, ts, np.abs(ps), w, n_t, n_d)
        row = nodes[i]
        ok = row & (np.abs(qden / exact - 1.0) <= RESOLVED_HAT)
        tex[i][ok] = num[ok] / exact[ok]
        fallback[i] = row & ~ok
    _sample_nodes(model, tex, fallback)


def _hat_integrals(n: int, amax: float, polar: bool = False) -> np.ndarray:
    """int hat_i(t) m(t) dt over [0, amax] for the n nodes' linear hats, m = sin t cos t
    (``polar``) or 1 (midpoint rule, 64 points per node spacing)."""
    pos, w = hat_samples(n, amax, 64)
    h = amax / (n - 1)
    raw = 1.0 - np.abs(pos - np.arange(n)[:, None] * h) / h
    m = np.sin(pos) * np.cos(pos) if polar else np.ones_like(pos)
    span = np.where((np.arange(n) == 0) | (np.arange(n) == n - 1), h, 2 * h)
    return (raw * m).mean(axis=1) * span


def _half_vector_quadrature(theta_i: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(theta_s, phi_s, weight cos theta_s dw_s) over the hemisphere for light from
    (theta_i, phi_i = 0), through the half vector h (dw_s = 4 (w_i . h) dw_h): theta_h
    log-spaced (midpoints in log theta_h), phi_h uniform (:data:`LOBE_THETA_H`)."""
    n_h, n_p, lo = LOBE_THETA_H
    span = np.log((np.pi / 2) / lo)
    th = lo * np.exp((np.arange(n_h) + 0.5) / n_h * span)
    dth = th * span / n_h
    ph = (np.arange(n_p) + 0.5) / n_p * 2 * np.pi
    TH, PH = np.meshgrid(th, ph, indexing="ij")
    wi = np.array([np.sin(theta_i), 0.0, np.cos(theta_i)])
    h = np.stack([np.sin(TH) * np.cos(PH), np.sin(TH) * np.sin(PH), np.cos(TH)], -1)
    ih = h @ wi
    wo = 2 * ih[..., None] * h - wi
    ok = (ih > 0) & (wo[..., 2] > GRAZING)
    w = 4 * ih * wo[..., 2] * np.sin(TH) * dth[:, None] * (2 * np.pi / n_p)
    ts = np.arccos(np.clip(wo[..., 2], -1, 1))
    return ts[ok], np.arctan2(wo[..., 1], wo[..., 0])[ok], w[ok]


def _scatter_hats(out: np.ndarray, ts, dp, values, n_t: int, n_d: int) -> None:
    """out[j, k] += values hat_j(ts) hat_k(dp) (linear hats of the texture grid)."""
    u = np.clip(ts, 0, np.pi / 2) / (np.pi / 2) * (n_t - 1)
    v = np.clip(dp, 0, np.pi) / np.pi * (n_d - 1)
    j0, k0 = np.minimum(u.astype(int), n_t - 2), np.minimum(v.astype(int), n_d - 2)
    fu, fv = u - j0, v - k0
    flat = out.reshape(-1)
    for dj, wu in ((0, 1 - fu), (1, fu)):
        for dk, wv in ((0, 1 - fv), (1, fv)):
            flat += np.bincount((j0 + dj) * n_d + k0 + dk, weights=values * wu * wv,
                                minlength=flat.size)


def _sample_nodes(model, tex: np.ndarray, nodes: np.ndarray) -> None:
    """tex[nodes] <- FALLBACK_SUB^3 samples of the model weighted by the hats (and the
    projected solid angle over theta)."""
    idx = np.argwhere(nodes)
    if not idx.size:
        return
    n_t, _, n_d = tex.shape
    pt, wt = hat_samples(n_t, np.pi / 2, FALLBACK_SUB, polar=True)
    pd, wd = hat_samples(n_d, np.pi, FALLBACK_SUB)
    pt = np.minimum(pt, np.pi / 2 - GRAZING)
    s3 = FALLBACK_SUB ** 3
    a, b, c = (g.ravel() for g in np.meshgrid(*(np.arange(FALLBACK_SUB),) * 3, indexing="ij"))
    per = max(1, TABULATE_CHUNK // s3)
    for n0 in range(0, len(idx), per):
        i, j, k = (v[:, None] for v in idx[n0:n0 + per].T)
        f = _positive(model(pt[i, a], np.zeros((len(i), s3)), pt[j, b], pd[k, c]))
        w = wt[i, a] * wt[j, b] * wd[k, c]
        tex[idx[n0:n0 + per, 0], idx[n0:n0 + per, 1], idx[n0:n0 + per, 2]] = \
            (f * w).sum(axis=1)


def lobe_errors(texture: np.ndarray, model) -> tuple[float, float]:
    """(albedo error, shape error) of the texture's trilinear interpolant against the model
    on the half-vector quadrature of :func:`clnlos.brdf.mlp.directional_albedo` (it resolves
    narrow lobes), per incidence angle: the largest difference of the directional albedos
    over the largest albedo, and the largest int |f_tex - f| cos dw / int f cos dw (the lobe
    in the wrong directions)."""
    ang, w, g = albedo_quadrature(**CHECK_QUADRATURE)
    f = _positive(model(ang[:, 0], ang[:, 1], ang[:, 2], ang[:, 3]))
    ft = lookup_numpy(texture, ang)
    a_model = np.bincount(g, weights=w * f)
    albedo = float(np.max(np.abs(np.bincount(g, weights=w * ft) - a_model))
                   / max(float(np.max(a_model)), 1e-30))
    shape = np.bincount(g, weights=w * np.abs(ft - f)) / np.maximum(a_model, 1e-30)
    return albedo, float(np.max(shape))


def retro_errors(retro: np.ndarray, model) -> tuple[float, float]:
    """(energy error, shape error) of a retro slice read linearly between its nodes against
    the model, with the weight sin t cos t on 4096 angles log-spaced from 1e-6 rad (a lobe at
    normal incidence is resolved): the relative difference of int f(t, t) sin t cos t dt and
    int |f_slice - f| sin t cos t dt over the model's."""
    edges = np.concatenate([[0.0], np.geomspace(1e-6, np.pi / 2, 4096)])
    t = 0.5 * (edges[1:] + edges[:-1])
    w = np.sin(t) * np.cos(t) * np.diff(edges)
    f_model = _positive(model(t, 0 * t, t, 0 * t))
    f_tex = np.interp(t, np.linspace(0, np.pi / 2, len(retro)), np.asarray(retro, float))
    e_model = max(float((f_model * w).sum()), 1e-30)
    return (abs(float((f_tex * w).sum()) - e_model) / e_model,
            float((np.abs(f_tex - f_model) * w).sum()) / e_model)


def write_texture(path, tex: BRDFTexture) -> None:
    write_h5(path, {"texture": tex.texture, "retro": tex.retro},
             {"format": FORMAT, "version": VERSION, "theta_range_rad": [0.0, np.pi / 2],
              "dphi_range_rad": [0.0, np.pi], "resolution": list(tex.shape),
              "n_retro": len(tex.retro), "provenance": json.dumps(tex.provenance)})


def texture_fit_warning(tex: BRDFTexture, path) -> str | None:
    """The warning of the fit a texture tabulates, carried from its model file's metrics
    (:func:`clnlos.brdf.store.fit_warning`), naming the texture; None for a usable fit."""
    model = tex.provenance.get("model_file")
    return fit_warning(tex.provenance.get("metrics", {}),
                       f"{path}" + (f" (a texture of {model})" if model else ""))


def read_texture(path) -> BRDFTexture:
    path = input_file(path, "BRDF texture ")
    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") != FORMAT:
                raise InputFileError(f"{path}: not a clnlos BRDF texture")
            if int(f.attrs.get("version", 0)) != VERSION:
                raise InputFileError(f"{path}: texture version {f.attrs.get('version')} "
                                     f"not supported (expected {VERSION})")
            for name in ("texture", "retro"):
                ds = f.get(name)
                if isinstance(ds, h5py.Dataset) and ds.shape:  # the declared size first
                    check_memory(f"{path}: reading its {name} "
                                 f"({' x '.join(map(str, ds.shape))}, {ds.dtype.itemsize} B "
                                 "per value)", host=ds.size * (ds.dtype.itemsize + 4))
            tex = f["texture"][()]
            retro = f["retro"][()]
            prov = json.loads(f.attrs.get("provenance", "{}"))
    except OSError as exc:
        raise InputFileError(f"{path}: unreadable ({exc})") from None
    if tex.ndim != 3 or min(tex.shape) < 2 or retro.ndim != 1 or retro.size < 2:
        raise InputFileError(f"{path}: texture or retro slice has a wrong shape")
    if not (np.all(np.isfinite(tex)) and np.all(tex >= 0)):
        raise InputFileError(f"{path}: texture holds NaN or negative values")
    return BRDFTexture(tex, retro, prov)


def _grid_pos(a, amax, n):
    return np.clip(a, 0, amax) / amax * (n - 1)


def lookup_numpy(tex: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Float64 trilinear lookup (the reference of kernels/brdf.cl)."""
    a = np.asarray(angles, float).reshape(-1, 4)
    n_ti, n_ts, n_dp = tex.shape
    d = np.abs(a[:, 3] - a[:, 1]) % (2 * np.pi)
    d = np.where(d > np.pi, 2 * np.pi - d, d)
    u, v, w = (_grid_pos(a[:, 0], np.pi / 2, n_ti), _grid_pos(a[:, 2], np.pi / 2, n_ts),
               _grid_pos(d, np.pi, n_dp))
    i0 = np.minimum(u.astype(int), n_ti - 2)
    j0 = np.minimum(v.astype(int), n_ts - 2)
    k0 = np.minimum(w.astype(int), n_dp - 2)
    fu, fv, fw = u - i0, v - j0, w - k0
    t = tex.astype(float)
    out = np.zeros(len(a))
    for di in (0, 1):
        for dj in (0, 1):
            for dk in (0, 1):
                wt = ((fu if di else 1 - fu) * (fv if dj else 1 - fv) * (fw if dk else 1 - fw))
                out += wt * t[i0 + di, j0 + dj, k0 + dk]
    return out


def texture_model(tex: BRDFTexture, path):
    """The model a texture tabulates: its stored table (``provenance["model_spec"]``), else
    the model file it names (``model_file``, as given or beside the texture) when that file
    is there; None otherwise."""
    spec = tex.provenance.get("model_spec")
    if isinstance(spec, dict):
        return make_model(spec)
    name = tex.provenance.get("model_file")
    if isinstance(name, str) and name:
        for cand in (Path(name), Path(path).parent / name, Path(path).parent / Path(name).name):
            if cand.is_file():
                return load_model(cand)[0]
    return None


def _unchecked(tex: BRDFTexture, path, what: str, sharp: bool):
    """A texture no model can check: usable when tabulated by :func:`tabulate` (its sharp
    nodes averaged) or smooth on its grid; else a ParameterError."""
    if sharp and "node_values" not in tex.provenance:
        raise ParameterError("objects.material", str(path), "a BRDF texture whose model is "
                             f"stored or at hand: its {what} changes faster than its nodes "
                             "(a lobe narrower than a node) and the model it tabulates is "
                             "not stored in it nor at its model_file, so its energy cannot "
                             "be checked (tabulate it again with clnlos brdf texture)")


def checked_texture(tex: BRDFTexture, path, n_theta: int, n_dphi: int
                    ) -> tuple[np.ndarray, str, str | None]:
    """(texture on the [n_theta, n_theta, n_dphi] grid of a transport, the resolution it
    really has, a note or None). Against its model (:func:`lobe_errors`) a texture is
    tabulated again on that grid, with a note, where its directional albedo is off by more
    than TEXTURE_TOL (point samples of a lobe narrower than its nodes), or where it is
    coarser than that grid and puts more than TEXTURE_TOL more of its lobe in the wrong
    directions than the grid's own tabulation does; else it is read on that grid
    (trilinear, as the kernels read it)."""
    model = texture_model(tex, path)
    shape = "x".join(map(str, tex.shape))
    want = (int(n_theta), int(n_theta), int(n_dphi))
    label = "x".join(map(str, want))
    if model is not None:
        albedo, lobe = lobe_errors(tex.texture, model)
        new, why = None, None
        if albedo > TEXTURE_TOL:
            why = f"directional albedo is off its model's by {100 * albedo:.3g}%"
        elif tex.shape[0] < want[0] or tex.shape[2] < want[2]:
            new = tabulate(model, n_theta, n_dphi, MIN_NODES).texture
            own = lobe_errors(new, model)[1]
            if lobe > own + TEXTURE_TOL:
                why = (f"lobe is {100 * lobe:.3g}% off its model's ({100 * own:.2g}% at "
                       f"{label})")
        if why:
            new = tabulate(model, n_theta, n_dphi, MIN_NODES).texture if new is None else new
            a, lo = lobe_errors(new, model)
            return new, label, (f"{path}: its {shape} texture is too coarse for its lobe (its "
                                f"{why}): tabulated again from the model at {label} (albedo "
                                f"off by {100 * a:.2g}%, lobe by {100 * lo:.2g}%)")
    else:
        _unchecked(tex, path, "texture", bool(sharp_nodes(tex.texture).any()))
    if tex.shape == want:
        return tex.texture, shape, None
    th = np.linspace(0, np.pi / 2, n_theta)
    TI, TS, DP = np.meshgrid(th, th, np.linspace(0, np.pi, n_dphi), indexing="ij")
    ang = np.column_stack([TI.ravel(), 0 * TI.ravel(), TS.ravel(), DP.ravel()])
    return lookup_numpy(tex.texture, ang).reshape(TI.shape), shape, None


def checked_retro(tex: BRDFTexture, path, n_theta: int) -> tuple[np.ndarray, str | None]:
    """(the texture's retro slice on ``n_theta`` nodes, a note or None): against its model
    (:func:`retro_errors`) a slice is taken from the model on ``n_theta`` nodes
    (:func:`clnlos.brdf.models.retro_slice`), with a note, where its energy is off by more
    than TEXTURE_TOL, or where it has fewer nodes and puts more than TEXTURE_TOL more of
    its energy at the wrong angles than the model's slice on ``n_theta`` nodes."""
    model = texture_model(tex, path)
    r = tex.retro.astype(float)
    if model is not None:
        energy, lobe = retro_errors(r, model)
        new = retro_slice(model, n_theta)
        own = retro_errors(new, model)[1]
        why = None
        if energy > TEXTURE_TOL:
            why = f"energy is off its model's by {100 * energy:.3g}%"
        elif len(r) < n_theta and lobe > own + TEXTURE_TOL:
            why = f"lobe is {100 * lobe:.3g}% off its model's ({100 * own:.2g}% on {n_theta})"
        if why:
            return new, (f"{path}: its {len(r)}-node retro slice is too coarse for its lobe "
                         f"(its {why}): taken from the model on {n_theta} nodes")
    else:
        d2 = np.abs(r[:-2] - 2 * r[1:-1] + r[2:]) > SHARP_D2 * (r[:-2] + r[1:-1] + r[2:])
        _unchecked(tex, path, "retro slice", bool(d2.any() or max(r[:2]) > 3 * min(r[:2])))
    return np.interp(np.linspace(0, 1, n_theta), np.linspace(0, 1, len(r)), r), None
