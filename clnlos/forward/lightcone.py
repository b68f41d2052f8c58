"""The confocal light cone (seed Eq. 9): BRDF-weighted accumulation of surface elements seen
from each scan point, on one scan/time grid (kernels/lightcone.cl)."""

from __future__ import annotations

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from clnlos.errors import DeviceCapabilityError, ParameterError
from clnlos.forward.sampling import N_THETA, SurfaceSamples
from clnlos.runtime.buffers import kernel_int, round_up, zeros
from clnlos.runtime.device import get_queue, group_size, require_dtype, require_memory
from clnlos.runtime.programs import get_kernels, real_defines


class LightCone:
    """Plan: confocal light-cone accumulation on one scan/time grid, dtype and device.

    Output [bins, points, points]; ``retro`` compiles the BRDF-table path, else Lambertian;
    ``cone`` adds a retroreflector's spot-averaged cone (kernels/lightcone.cl, RETRO_CONE);
    ``describe`` names the grid in a memory error (default: its shape).
    """

    def __init__(self, *, points: int, width_m: float, bins: int, bin_width_s: float,
                 start_s: float, retro: bool, cone: bool = False, splat_order: int = 1,
                 dtype=np.float32,
                 queue=None, variant: str = "auto", describe: str | None = None):
        self.queue = get_queue(queue)
        self.dtype = require_dtype(self.queue.device, dtype)
        self.points, self.width_m, self.bins = points, width_m, bins
        self.bin_width_s, self.start_s = bin_width_s, start_s
        self.shape = (bins, points, points)
        require_memory(self.queue.device, int(np.prod(self.shape)) * self.dtype.itemsize,
                       describe or f"transient {self.shape}")
        defines = {**real_defines(self.dtype), "SPLAT_ORDER": int(splat_order)}
        if retro or cone:
            defines.update(RETRO_TABLE=True, N_THETA=N_THETA)
        if cone:
            defines["RETRO_CONE"] = True
        self.variant = choose_lightcone_variant(self.queue.device, variant, bins, self.dtype)
        if self.variant == "group":
            defines["GROUP_VARIANT"] = True
        self.defines = defines
        self._k = get_kernels(self.queue, "lightcone", defines)

    def __call__(self, samples: SurfaceSamples) -> cla.Array:
        q, dt = self.queue, self.dtype
        el = samples.elements
        out = zeros(q, self.shape, dt)
        if len(el) == 0:
            return out

        def dev(a, t=dt):
            return cla.to_device(q, np.ascontiguousarray(a, t))

        table = samples.retro_tables if samples.retro_tables is not None else np.zeros((1, 1))
        cone = samples.cone_tables if samples.cone_tables is not None else np.zeros((1, 1))
        spot = samples.spot_constants if samples.spot_constants is not None else np.zeros(1)
        pitch = self.width_m / self.points
        x0 = -self.width_m / 2 + pitch / 2
        r = dt.type
        args = (dev(el.pos).data, dev(el.normal).data, dev(el.area).data,
                dev(samples.albedo).data, dev(samples.material, np.int32).data, dev(table).data,
                dev(cone).data, dev(spot).data, kernel_int(len(el), "surface elements"),
                kernel_int(self.points), kernel_int(self.points), r(x0), r(x0), r(pitch),
                kernel_int(self.bins, "time bins"), r(self.start_s), r(self.bin_width_s),
                out.data)
        if self.variant == "group":
            kern = self._k.lightcone_accumulate_group
            lsz = group_size(kern, q.device)
            kern(q, (self.points * self.points * lsz,), (lsz,), *args,
                 cl.LocalMemory(self.bins * dt.itemsize))
        else:
            self._k.lightcone_accumulate(
                q, (round_up(self.points, 8), round_up(self.points, 8)), None, *args)
        return out


LIGHTCONE_VARIANTS = ("auto", "item", "group")


def choose_lightcone_variant(device, variant: str, bins: int, dtype) -> str:
    """``item`` (one work-item per scan point: CPUs) or ``group`` (one work-group per scan
    point with a local histogram: GPUs). ``auto`` picks ``group`` on GPUs and accelerators
    when the histogram fits local memory (and, in float64, the device has 64-bit local
    atomics); an explicit ``group`` that cannot run is an error."""
    if variant not in LIGHTCONE_VARIANTS:
        raise ParameterError("variant", variant, " or ".join(LIGHTCONE_VARIANTS))
    fits = bins * np.dtype(dtype).itemsize <= device.local_mem_size // 2
    atomics = (np.dtype(dtype) == np.float32
               or "cl_khr_int64_base_atomics" in device.extensions)
    if variant == "group" and not (fits and atomics):
        raise DeviceCapabilityError(
            f"the work-group light cone needs {bins * np.dtype(dtype).itemsize} B of local "
            f"memory (device: {device.local_mem_size} B) and, in float64, 64-bit local "
            "atomics")
    if variant != "auto":
        return variant
    on_gpu = not (device.type & cl.device_type.CPU)
    return "group" if on_gpu and fits and atomics else "item"
