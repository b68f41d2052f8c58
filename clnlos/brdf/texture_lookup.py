"""A BRDF texture looked up on an OpenCL device (kernels/brdf.cl): the device side of
:mod:`clnlos.brdf.texture`, which stays free of OpenCL (scene parsing reads textures)."""

from __future__ import annotations

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from clnlos.brdf.texture import BRDFTexture
from clnlos.errors import ParameterError
from clnlos.runtime.buffers import kernel_int, round_up
from clnlos.runtime.device import get_queue, require_dtype
from clnlos.runtime.programs import get_kernels, real_defines


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
