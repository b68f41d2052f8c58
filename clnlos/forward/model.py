"""Forward simulation composed from a scene: only the effects the scene asks for are built.

    I   = LightCone(elements)                 always   (kernels/lightcone.cl)
    tau = (Phi * Phi) * I                     [slab]   (clnlos.blur, physical units; I is
                                                        computed on the scan grid widened by
                                                        the blur's lateral reach, then cropped)
    tau = g_pulse * tau                       [laser] pulse_width_s (kernels/temporal.cl)
    N   ~ Poisson(eta tau + dark)             [detector] (numpy Generator seeded by `seed`)

Units: I and tau in 1/(m^2 sr) per bin (the light-cone normalisation of transient renderers:
albedo f_r cos^2 cos^2 / r^4 dA summed per bin); with a detector, photon counts, where
eta = photons emitted x efficiency x etendue (m^2 sr) and dark = rate x exposure x
bin width x repetition rate per bin.

With ``[transport] model = "bistatic"`` (or "auto" choosing it) the light cone and the slab
blur are one stage, the seed's Eq. 8 in full (:mod:`clnlos.bistatic`, kernels/bistatic.cl):
light leaves the slab's face at r1 != r2, with the full BRDF f(w1, w2); its stage is named
``lightcone:bistatic(rings=..,angles=..,texture=..)`` and no ``slab_blur`` follows.

Left out: occlusion between elements (no visibility test), interreflections.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import pyopencl as cl
import pyopencl.array as cla
import scipy.fft as sfft

from clnlos import C0
from clnlos.forward.blur import lateral_reach_m, slab_blur
from clnlos.errors import ParameterError
from clnlos.forward.pulse import PulseBlur, pulse_taps  # noqa: F401 (re-exported)
from clnlos.forward.geometry import (
    Elements,
    planar_cells,
    read_mesh,
    sample_letters,
    sample_mesh,
    sample_rectangle,
    sample_sphere,
    text_extent_bound,
    transform,
)
from clnlos.runtime.buffers import kernel_int, round_up, zeros
from clnlos.runtime.programs import get_kernels, real_defines
from clnlos.runtime.device import get_queue, require_dtype, require_memory
from clnlos.forward.scene import Scene, SceneObject, read_retro_csv

N_THETA = 256  # samples of the retro-reflection tables over [0, 90] degrees

def material_retro(obj: SceneObject, base_dir) -> np.ndarray | None:
    """The object's retro slice f(theta) on N_THETA angles, or None for Lambertian: from its
    ``brdf_retro_csv`` table, else its material (:func:`clnlos.brdf.presets.material_retro`)."""
    if obj.brdf_retro_csv is not None:
        th, f = read_retro_csv(base_dir / obj.brdf_retro_csv)
        return np.interp(np.linspace(0, np.pi / 2, N_THETA), th, f)
    from clnlos.brdf.presets import material_retro as resolve

    return resolve(obj.material, base_dir, N_THETA)


def sample_object(obj: SceneObject, density: float, base_dir) -> Elements:
    if obj.shape == "letters":
        el = sample_letters(obj.text, obj.height_m, obj.stroke_m, density)
    elif obj.shape == "rectangle":
        el = sample_rectangle(obj.size_m[0], obj.size_m[1], density)
    elif obj.shape == "sphere":
        el = sample_sphere(obj.radius_m, density)
    else:
        el = sample_mesh(*read_mesh(base_dir / obj.path), density)
    return transform(el, obj.rotate_deg, obj.translate_m)


# host bytes per surface element while a scene is sampled (positions, normals, areas,
# albedo and material, the cell grid they come from, the concatenation; 136 B measured)
HOST_BYTES_PER_ELEMENT = 160


def element_count(obj: SceneObject, density: float, base_dir) -> float:
    """The surface elements (cells of the covering grid, for planar shapes) that sampling
    ``obj`` at ``density`` allocates, from its declared size (no element built; a mesh's
    triangles are read)."""
    if obj.shape in ("letters", "rectangle"):
        half = (text_extent_bound(obj.text, obj.height_m, obj.stroke_m)
                if obj.shape == "letters" else (obj.size_m[0] / 2, obj.size_m[1] / 2))
        nx, ny = planar_cells(*half, density)
        return float(nx) * float(ny)
    if obj.shape == "sphere":
        return float(max(4, round(4 * math.pi * obj.radius_m**2 * density)))  # as sampled
    V, F = read_mesh(base_dir / obj.path)
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]),
                                axis=1)
    return float(np.sum(np.maximum(1.0, np.ceil(np.sqrt(area * density))) ** 2))


def check_scene_size(scene: Scene, device, dtype) -> None:
    """Before anything is sampled: the surface elements the scene implies (objects x area
    x sampling.density_per_m2) fit the host while they are built and the device's buffers
    (:func:`clnlos.limits.check_memory`)."""
    from clnlos.runtime.limits import check_memory

    n = sum(element_count(o, scene.density_per_m2, scene.base_dir) for o in scene.objects)
    item = np.dtype(dtype).itemsize
    check_memory(f"the scene's {len(scene.objects)} object(s) at sampling.density_per_m2 = "
                 f"{scene.density_per_m2:g} ({n:.3g} surface elements)",
                 host=int(n * HOST_BYTES_PER_ELEMENT), device=device,
                 device_total=int(n * (8 * item + 4)), device_buffer=int(n * 3 * item))


@dataclass
class SurfaceSamples:
    """Elements of all objects with per-element albedo and material index."""

    elements: Elements
    albedo: np.ndarray
    material: np.ndarray
    retro_tables: np.ndarray | None  # [n_materials, N_THETA] or None when all Lambertian


def sample_scene(scene: Scene, density: float | None = None) -> SurfaceSamples:
    density = scene.density_per_m2 if density is None else density
    parts, alb, mats, tables = [], [], [], []
    retros = [material_retro(o, scene.base_dir) for o in scene.objects]
    any_table = any(r is not None for r in retros)
    for obj, retro in zip(scene.objects, retros, strict=True):
        el = sample_object(obj, density, scene.base_dir)
        parts.append(el)
        alb.append(np.full(len(el), obj.albedo))
        if any_table:
            tables.append(np.full(N_THETA, 1 / np.pi) if retro is None else retro)
            mats.append(np.full(len(el), len(tables) - 1, np.int32))
        else:
            mats.append(np.zeros(len(el), np.int32))
    return SurfaceSamples(Elements.concat(parts), np.concatenate(alb),
                          np.concatenate(mats).astype(np.int32),
                          np.asarray(tables) if any_table else None)


class LightCone:
    """Plan: confocal light-cone accumulation on one scan/time grid, dtype and device.

    Output [bins, points, points]; ``retro`` compiles the BRDF-table path, else Lambertian.
    """

    def __init__(self, *, points: int, width_m: float, bins: int, bin_width_s: float,
                 start_s: float, retro: bool, splat_order: int = 1, dtype=np.float32,
                 queue=None, variant: str = "auto"):
        self.queue = get_queue(queue)
        self.dtype = require_dtype(self.queue.device, dtype)
        self.points, self.width_m, self.bins = points, width_m, bins
        self.bin_width_s, self.start_s = bin_width_s, start_s
        self.shape = (bins, points, points)
        require_memory(self.queue.device, int(np.prod(self.shape)) * self.dtype.itemsize,
                       f"transient {self.shape}")
        defines = {**real_defines(self.dtype), "SPLAT_ORDER": int(splat_order)}
        if retro:
            defines.update(RETRO_TABLE=True, N_THETA=N_THETA)
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
        pitch = self.width_m / self.points
        x0 = -self.width_m / 2 + pitch / 2
        r = dt.type
        args = (dev(el.pos).data, dev(el.normal).data, dev(el.area).data,
                dev(samples.albedo).data, dev(samples.material, np.int32).data, dev(table).data,
                kernel_int(len(el), "surface elements"),
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
    from clnlos.errors import DeviceCapabilityError, ParameterError

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


def group_size(kernel, device, cap: int = 256) -> int:
    """A work-group size: the kernel's preferred multiple, grown while it fits ``cap`` and the
    kernel's and device's maxima."""
    wg = cl.kernel_work_group_info
    mult = max(1, kernel.get_work_group_info(wg.PREFERRED_WORK_GROUP_SIZE_MULTIPLE, device))
    most = min(cap, kernel.get_work_group_info(wg.WORK_GROUP_SIZE, device),
               device.max_work_group_size)
    size = mult
    while size * 2 <= most:
        size *= 2
    return max(1, min(size, most))


def photon_counts(tau: np.ndarray, scene: Scene, rng: np.random.Generator) -> np.ndarray:
    det = scene.detector
    eta = det.photons_emitted() * det.efficiency * det.etendue_m2_sr
    dark = det.dark_count_rate_hz * det.exposure_s * scene.bin_width_s * det.rep_rate_hz
    lam = np.maximum(tau.astype(np.float64), 0) * eta + dark
    return rng.poisson(lam).astype(np.float32)


@lru_cache(maxsize=16)
def _blur_margin(slab, window_s, pitch_m, points, tol, n_dipoles, queue) -> tuple[int, bool]:
    """(cells per side to add so the scan grid covers the blur's reach, rounded to a
    2-3-5-smooth size; whether that covers all of it). The margin is capped at twice the
    scan; a capped margin needs a non-wrapping (zero-padded) lateral convolution."""
    reach = lateral_reach_m(slab, window_s=window_s, pitch_m=pitch_m, tol=tol,
                            n_dipoles=n_dipoles, queue=queue)
    need = int(math.ceil(reach / pitch_m - 1e-9))
    m = min(need, 2 * points)
    while sfft.next_fast_len(points + 2 * m, real=True) != points + 2 * m:
        m += 1
    return m, m >= need


def _forward_blur(slab, shape, bin_width_s, pitch_m, n_dipoles, periodic, dtype_str, queue):
    """The physical Phi * Phi operator, shared by every scene of one geometry (a study;
    cached in :data:`clnlos.plans.FORWARD_BLURS`).

    ``periodic``: the input carries the blur's reach as a margin that is cropped after the
    blur, so the lateral convolution may wrap (no lateral padding: 4x fewer FFT cells).
    """
    from clnlos.runtime.caches import FORWARD_BLURS

    key = (slab, shape, bin_width_s, pitch_m, n_dipoles, periodic, dtype_str, queue)
    return FORWARD_BLURS.get(key, lambda: slab_blur(
        slab, shape, bin_width_s=bin_width_s, pitch_m=pitch_m, mode="convolve",
        n_dipoles=n_dipoles, periodic_xy=periodic, dtype=np.dtype(dtype_str), queue=queue),
        queue)


FRONT_MIN_Z_M = 1e-6  # elements nearer the relay plane than this return no light: the light
#                      cone's cosines (z / r at both ends) vanish there (a plate at z = 0
#                      turned by 1e-298 deg sat at z ~ 1e-300 m and simulated all zero)


def check_scene_geometry(scene: Scene) -> list[str]:
    """Objects must lie in front of the relay plane (z > 0) and return light inside the time
    window: an object with no element in front, or whose every round trip falls outside
    [start, start + bins dt), is an error; one partly outside gives a warning (returned)."""
    import warnings

    w = scene.width_m / 2
    t0, t1 = scene.start_s, scene.start_s + scene.bins * scene.bin_width_s
    notes = []
    dark = []  # (field, value, why) of each object that returns no light at all
    for i, obj in enumerate(scene.objects):
        el = sample_object(obj, min(scene.density_per_m2, 1e4), scene.base_dir)
        if len(el) == 0:
            continue
        z = el.pos[:, 2]
        name = f"objects[{i}] ({obj.shape})"
        front_mask = z > FRONT_MIN_Z_M
        if not np.any(front_mask):
            raise ParameterError(f"objects[{i}].translate_m", list(obj.translate_m),
                                 f"a position in front of the relay plane (z > 0): {name} "
                                 "lies entirely behind it and returns no light")
        if not np.all(front_mask):
            notes.append(f"{name} is partly behind the relay plane (z <= 0); that part "
                         "returns no light")
        front = el.pos[front_mask]
        dx = np.maximum(np.abs(front[:, 0]) - w, 0)
        dy = np.maximum(np.abs(front[:, 1]) - w, 0)
        t_near = 2 * np.sqrt(dx**2 + dy**2 + front[:, 2] ** 2) / C0
        t_far = 2 * np.sqrt((np.abs(front[:, 0]) + w) ** 2 + (np.abs(front[:, 1]) + w) ** 2
                            + front[:, 2] ** 2) / C0
        if t_near.min() >= t1 or t_far.max() < t0:
            raise ParameterError("time", f"[{t0:.3g}, {t1:.3g}) s",
                                 f"a window that sees {name}: its light returns between "
                                 f"{t_near.min():.3g} s and {t_far.max():.3g} s")
        if t_far.max() >= t1 or t_near.min() < t0:
            notes.append(f"{name} returns light partly outside the time window "
                         f"[{t0:.3g}, {t1:.3g}) s")
        why = _no_light(i, obj, front, el.normal[front_mask], scene.scan_centres())
        if why is not None:
            dark.append(why)
            notes.append(f"{why[2]}: it returns no light")
    if dark and len(dark) == len(scene.objects):
        field, value, why, allowed = dark[0]
        raise ParameterError(field, value, f"{allowed}: {why} and no other object returns "
                             "light (the capture would be all zero)")
    for n in notes:
        warnings.warn(n, UserWarning, stacklevel=3)
    return notes


def _no_light(i: int, obj: SceneObject, pos: np.ndarray, normal: np.ndarray,
              centres: np.ndarray) -> tuple[str, object, str, str] | None:
    """(field, value, why, what would be allowed) when object ``i`` (elements in front of
    the relay plane) returns no light to the scan points (``centres`` along x and y, m, at
    z = 0): albedo 0, or every element's front turned away from every scan point (the
    light-cone kernel skips back faces); else None."""
    if obj.albedo == 0:
        return (f"objects[{i}].albedo", obj.albedo, f"objects[{i}] is black (albedo 0)",
                "> 0 for at least one object")
    lo, hi = float(centres[0]), float(centres[-1])
    corners = np.array([[x, y, 0.0] for x in (lo, hi) for y in (lo, hi)])
    # n . (q - p) is linear in the scan point q: its largest value over the grid of scan
    # points is at a corner point; > 0 there means the element's front faces that point
    facing = np.einsum("ek,cek->ce", normal, corners[:, None, :] - pos[None]).max(axis=0)
    if not np.any(facing > 0):
        return (f"objects[{i}].rotate_deg", list(obj.rotate_deg),
                f"objects[{i}] ({obj.shape}) turns its back to every scan point",
                "a rotation that turns the front of some object towards the scan points")
    return None


class ForwardModel:
    """The stages a scene asks for, built once; ``run()`` returns the capture [t, y, x]."""

    def __init__(self, scene: Scene, *, dtype=np.float32, queue=None):
        self.scene = scene
        self.queue = get_queue(queue)
        self.dtype = require_dtype(self.queue.device, dtype)
        check_scene_size(scene, self.queue.device, self.dtype)
        self.warnings = check_scene_geometry(scene)
        self.samples = sample_scene(scene)
        s = scene
        self.margin = 0
        self.blur = self.pulse = None
        self.transport, self.transport_reason = self._transport_model()
        if self.transport == "bistatic":
            self._build_bistatic()
        else:
            self._build_confocal()
        if s.pulse_width_s is not None:
            self.pulse = PulseBlur(self.lightcone.shape, s.pulse_width_s, s.bin_width_s,
                                   self.dtype, self.queue)
            self.stages.append("pulse_blur")
        if s.detector is not None:
            self.stages.append("photon_noise")

    def _transport_model(self) -> tuple[str, str]:
        """The scene's ``[transport] model``, "auto" resolved (:func:`clnlos.bistatic.
        auto_choice`): ("confocal" or "bistatic", why)."""
        from clnlos.forward.bistatic import auto_choice, face_quadrature

        s = self.scene
        model = s.transport.model
        if model != "auto":
            return model, "requested"
        if s.slab is None:
            return "confocal", "auto: no slab"
        quad = face_quadrature(s.slab, bins=s.bins, bin_width_s=s.bin_width_s, rings=1,
                               angles=1, n_dipoles=s.n_dipoles, queue=self.queue)
        choice, why = auto_choice(s, self.samples, quad.rms_m)
        return choice, f"auto: {why}"

    def _build_bistatic(self) -> None:
        """Eq. 8 (clnlos.bistatic): one stage carries the light through the slab and back."""
        from clnlos.forward.bistatic import BistaticTransport, scene_textures

        s, t = self.scene, self.scene.transport
        if s.slab is None:
            raise ParameterError("transport.model", "bistatic", "'confocal' or 'auto' without "
                                 "a [slab]")
        if s.start_s != 0:
            raise ParameterError("time.start_s", s.start_s,
                                 "0 when a [slab] is given (the slab blur is causal from t = 0)")
        self.reach_covered = True  # no lateral grid: every face sample is evaluated exactly
        self.lightcone = BistaticTransport(
            slab=s.slab, points=s.points, width_m=s.width_m, bins=s.bins,
            bin_width_s=s.bin_width_s, start_s=s.start_s, textures=scene_textures(s, t),
            rings=t.face_rings, angles=t.face_angles, n_dipoles=s.n_dipoles,
            splat_order=s.splat_order, dtype=self.dtype, queue=self.queue)
        self.stages = [self.lightcone.stage]

    def _build_confocal(self) -> None:
        """Eq. 9: the confocal light cone, then the slab blur Phi * Phi when there is a slab."""
        s = self.scene
        self.stages = ["lightcone:" + ("brdf-table" if self.samples.retro_tables is not None
                                       else "lambertian")]
        # Light diffuses through the slab sideways: a scan point also sees the hidden-side
        # transient I up to the blur's reach outside the scanned square, so I is computed
        # on a grid widened by that many cells per side (cell centres kept) and cropped
        # after the blur. Without it the border of the capture lacks that light.
        self.margin, covered = 0, False
        if s.slab is not None:
            self.margin, covered = _blur_margin(s.slab, s.bins * s.bin_width_s, s.pitch_m,
                                                s.points, s.blur_reach_tol, s.n_dipoles,
                                                self.queue)
        self.reach_covered = covered  # False: margin capped, the blur pads instead of wrapping
        n_ext = s.points + 2 * self.margin
        self.lightcone = LightCone(points=n_ext, width_m=n_ext * s.pitch_m, bins=s.bins,
                                   bin_width_s=s.bin_width_s, start_s=s.start_s,
                                   retro=self.samples.retro_tables is not None,
                                   splat_order=s.splat_order, dtype=self.dtype, queue=self.queue)
        if s.slab is not None:
            if s.start_s != 0:
                raise ParameterError("time.start_s", s.start_s,
                                     "0 when a [slab] is given (the slab blur is causal from "
                                     "t = 0)")
            self.blur = _forward_blur(s.slab, self.lightcone.shape, s.bin_width_s, s.pitch_m,
                                      s.n_dipoles, covered, self.dtype.str, self.queue)
            self.stages.append("slab_blur")

    def setup_attrs(self) -> dict:
        """What a capture of this model records about its setup (see io.Capture)."""
        import json

        from clnlos.config import slab_table

        s = self.scene
        a = {"scene": s.text, "stages": json.dumps(self.stages),
             "elements": len(self.samples.elements),
             "transport": json.dumps({"model": self.transport,
                                      "reason": self.transport_reason})}
        if s.slab is not None:
            t = slab_table(s.slab)
            if s.n_dipoles is not None:
                t["n_dipoles"] = s.n_dipoles
            a["slab"] = json.dumps(t)
        if s.pulse_width_s is not None:
            a["pulse_width_s"] = s.pulse_width_s
        return a

    def capture(self):
        """Run the model and return the capture with its recorded setup (io.Capture)."""
        from clnlos.io.files import Capture

        s = self.scene
        return Capture(self.run(), s.bin_width_s, s.start_s, s.width_m, "simulated",
                       self.setup_attrs())

    def run(self, progress=None) -> np.ndarray:
        """The capture [t, y, x]; ``progress(stage)`` is called as each stage finishes."""
        def done(stage):
            if progress is not None:
                self.queue.finish()
                progress(stage)

        x = self.lightcone(self.samples)
        done(self.stages[0])
        if self.blur is not None:
            x = self.blur(x)
            done("slab_blur")
        if self.pulse is not None:
            x = self.pulse(x)
            done("pulse_blur")
        tau = x.get()
        if self.margin:
            m = self.margin
            tau = tau[:, m:-m, m:-m]
        tau = np.maximum(tau, 0)  # FFT round-off can leave -1e-17 where tau is 0
        if not np.any(tau):  # what check_scene_geometry cannot see (a black material, ...)
            s = self.scene
            raise ParameterError("objects", f"{len(s.objects)} object(s)", "objects that "
                                 "return light to the scan points inside the time window "
                                 f"[{s.start_s:.3g}, {s.start_s + s.bins * s.bin_width_s:.3g})"
                                 " s: this scene's capture is all zero (check the objects' "
                                 "materials, rotations and positions)")
        if self.scene.detector is not None:
            tau = photon_counts(tau, self.scene, np.random.default_rng(self.scene.seed))
            done("photon_noise")
        return tau.astype(np.float32)
