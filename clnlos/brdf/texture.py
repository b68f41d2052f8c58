"""Tabulated BRDF textures: export any model (the MLP included) and look it up on the device.

File (HDF5, ``format = "clnlos-brdf-texture"``, ``version = 1``): dataset ``texture``
float32 [n_theta_i, n_theta_s, n_dphi] on nodes theta = i (pi/2)/(n-1), delta_phi =
k pi/(n_dphi - 1); dataset ``retro`` float32 [n_retro], the confocal slice f(w, w) on nodes
theta = i (pi/2)/(n_retro - 1) (what the light-cone kernel reads); attributes with the
grid, the resolution and the model's provenance (JSON).

Lookup: ``kernels/brdf.cl``, trilinear; through a 3D image with a linear sampler where the
device supports images (float32), else from a buffer (any precision). :func:`lookup_numpy`
is the float64 reference.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import h5py
import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from clnlos.brdf.catalog import TEXTURE_FORMAT
from clnlos.checks import input_file
from clnlos.errors import InputFileError, ParameterError
from clnlos.io.files import write_h5
from clnlos.runtime.buffers import kernel_int, round_up
from clnlos.runtime.device import get_queue, require_dtype
from clnlos.runtime.limits import check_memory
from clnlos.runtime.programs import get_kernels, real_defines

FORMAT, VERSION = TEXTURE_FORMAT, 1
# tabulate: nodes per model evaluation (bounds its temporaries), host bytes per node of the
# texture (float32, and its compressed copy while written) and of one evaluation (the
# MLP's activations, the analytic models' intermediates; generous)
TABULATE_CHUNK = 1 << 18
TEXTURE_BYTES_PER_NODE = 4 + 4
MODEL_BYTES_PER_NODE = 2048
MIN_NODES, MAX_NODES = 2, 4096  # nodes per texture axis (and of the retro slice)


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
    """Evaluate ``model(ti, pi, ts, ps)`` on the texture grid (phi_i = 0, phi_s = delta_phi)."""
    for name, v in (("n_theta", n_theta), ("n_dphi", n_dphi), ("n_retro", n_retro)):
        if int(v) != v or not MIN_NODES <= v <= MAX_NODES:
            raise ParameterError(name, v, f"an integer from {MIN_NODES} to {MAX_NODES}")
    shape = (int(n_theta), int(n_theta), int(n_dphi))
    check_memory(f"BRDF texture {shape[0]} x {shape[1]} x {shape[2]} [theta_i, theta_s, "
                 "dphi] (n_theta = --resolution, n_dphi = --dphi)",
                 host=int(np.prod(shape, dtype=float)) * TEXTURE_BYTES_PER_NODE
                 + TABULATE_CHUNK * MODEL_BYTES_PER_NODE)
    th = np.linspace(0, np.pi / 2, n_theta)
    th_eval = np.minimum(th, np.pi / 2 - 1e-6)  # cosines vanish exactly at grazing
    dp = np.linspace(0, np.pi, n_dphi)
    tex = np.empty(shape, np.float32)
    flat = tex.reshape(-1)
    for a in range(0, flat.size, TABULATE_CHUNK):
        i, j, k = np.unravel_index(np.arange(a, min(a + TABULATE_CHUNK, flat.size)), shape)
        f = np.asarray(model(th_eval[i], np.zeros(i.size), th_eval[j], dp[k]), float)
        flat[a:a + i.size] = np.nan_to_num(np.maximum(f, 0), nan=0.0, posinf=0.0)
    r = np.minimum(np.linspace(0, np.pi / 2, n_retro), np.pi / 2 - 1e-6)
    retro = np.asarray(model(r, np.zeros_like(r), r, np.zeros_like(r)), float)
    retro = np.nan_to_num(np.maximum(retro, 0), nan=0.0, posinf=0.0)
    return BRDFTexture(tex, retro.astype(np.float32), provenance or {})


def write_texture(path, tex: BRDFTexture) -> None:
    write_h5(path, {"texture": tex.texture, "retro": tex.retro},
             {"format": FORMAT, "version": VERSION, "theta_range_rad": [0.0, np.pi / 2],
              "dphi_range_rad": [0.0, np.pi], "resolution": list(tex.shape),
              "n_retro": len(tex.retro), "provenance": json.dumps(tex.provenance)})


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


class TextureLookup:
    """Plan: look up one texture on one device; ``path="image"|"buffer"|"auto"``."""

    def __init__(self, tex: BRDFTexture, *, path: str = "auto", dtype=np.float32, queue=None):
        self.queue = get_queue(queue)
        self.dtype = require_dtype(self.queue.device, dtype)
        dev = self.queue.device
        if path not in ("auto", "image", "buffer"):
            raise ParameterError("path", path, "'auto', 'image' or 'buffer'")
        n_ti, n_ts, n_dp = tex.shape
        can_image = (bool(dev.image_support) and self.dtype == np.float32
                     and n_dp <= dev.image3d_max_width and n_ts <= dev.image3d_max_height
                     and n_ti <= dev.image3d_max_depth)
        if path == "image" and not can_image:
            raise ParameterError("path", path, "'buffer' on this device/precision (no 3D "
                                 "float images)")
        self.path = "image" if (path == "image" or (path == "auto" and can_image)) else "buffer"
        self.shape = tex.shape
        defines = real_defines(self.dtype)
        if self.path == "image":
            defines["USE_IMAGE"] = True
            self.image = cl.image_from_array(self.queue.context,
                                             np.ascontiguousarray(tex.texture, np.float32),
                                             num_channels=1, mode="r")
        else:
            self.buf = cla.to_device(self.queue, np.ascontiguousarray(tex.texture, self.dtype))
        self._k = get_kernels(self.queue, "brdf", defines)

    def __call__(self, angles) -> np.ndarray:
        """BRDF (1/sr) at ``angles`` (..., 4) = (theta_i, phi_i, theta_s, phi_s) in radians."""
        a = np.asarray(angles, float).reshape(-1, 4)
        if not np.all(np.isfinite(a)):
            bad = a[~np.all(np.isfinite(a), axis=1)][0]
            raise ParameterError("angles", bad.tolist(), "finite angles in radians (NaN or "
                                 "Inf cannot be looked up)")
        a = np.ascontiguousarray(a, self.dtype)
        n = len(a)
        out = cla.empty(self.queue, n, self.dtype)
        if n:
            a_g = cla.to_device(self.queue, a)
            n_ti, n_ts, n_dp = (kernel_int(s) for s in self.shape)
            src = self.image if self.path == "image" else self.buf.data
            kern = self._k.brdf_lookup_image if self.path == "image" else \
                self._k.brdf_lookup_buffer
            kern(self.queue, (round_up(n, 64),), None, src, n_ti, n_ts, n_dp, a_g.data,
                 out.data, np.uint64(n))
        return out.get()
