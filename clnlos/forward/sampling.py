"""Scene sampling: surface elements with albedo and material, their retro-reflection tables,
and the checks of a scene made before anything is simulated (size, geometry, light)."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from clnlos.physics.constants import C0
from clnlos.brdf.presets import material_retro as preset_retro
from clnlos.brdf.presets import retroreflector
from clnlos.errors import ParameterError
from clnlos.forward.geometry import (
    Elements,
    planar_cells,
    mask_albedo,
    read_albedo_map,
    read_depth_map,
    read_mask,
    read_mesh,
    sample_letters,
    sample_mask,
    sample_mesh,
    sample_rectangle,
    sample_sphere,
    text_extent_bound,
    transform,
)
from clnlos.forward.scene import Scene, SceneObject, read_retro_csv
from clnlos.runtime.limits import check_memory

N_THETA = 256  # samples of the retro-reflection tables over [0, 90] degrees


def material_retro(obj: SceneObject, base_dir) -> np.ndarray | None:
    """The object's retro slice f(theta) on N_THETA angles, or None for Lambertian: from its
    ``brdf_retro_csv`` table, else its material (:func:`clnlos.brdf.presets.material_retro`)."""
    if obj.brdf_retro_csv is not None:
        th, f = read_retro_csv(base_dir / obj.brdf_retro_csv)
        return np.interp(np.linspace(0, np.pi / 2, N_THETA), th, f)
    return preset_retro(obj.material, base_dir, N_THETA)


def object_albedo(obj: SceneObject, density: float, base_dir) -> tuple[Elements, np.ndarray]:
    """(the object's elements, each one's albedo): the object's ``albedo``, times a mask's
    per-pixel ``albedo_path`` factors where it has them."""
    el = sample_object(obj, density, base_dir)
    albedo = np.full(len(el), float(obj.albedo))
    if obj.shape == "mask" and obj.albedo_path is not None:
        mask = read_mask(base_dir / obj.path)
        local = sample_mask(mask, obj.size_m[0], obj.size_m[1], density)
        albedo *= mask_albedo(read_albedo_map(base_dir / obj.albedo_path, mask.shape),
                              obj.size_m[0], obj.size_m[1], local)
    return el, albedo


def sample_object(obj: SceneObject, density: float, base_dir) -> Elements:
    if obj.shape == "letters":
        el = sample_letters(obj.text, obj.height_m, obj.stroke_m, density)
    elif obj.shape == "rectangle":
        el = sample_rectangle(obj.size_m[0], obj.size_m[1], density)
    elif obj.shape == "sphere":
        el = sample_sphere(obj.radius_m, density)
    elif obj.shape == "mask":
        mask = read_mask(base_dir / obj.path)
        depth = (None if obj.depth_path is None
                 else read_depth_map(base_dir / obj.depth_path, mask.shape))
        el = sample_mask(mask, obj.size_m[0], obj.size_m[1], density, depth)
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
    if obj.shape in ("letters", "rectangle", "mask"):
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
    (:func:`clnlos.runtime.limits.check_memory`)."""
    n = sum(element_count(o, scene.density_per_m2, scene.base_dir) for o in scene.objects)
    item = np.dtype(dtype).itemsize
    check_memory(f"the scene's {len(scene.objects)} object(s) at sampling.density_per_m2 = "
                 f"{scene.density_per_m2:g} ({n:.3g} surface elements)",
                 host=int(n * HOST_BYTES_PER_ELEMENT), device=device,
                 device_total=int(n * (8 * item + 4)), device_buffer=int(n * 3 * item))


def material_cone(obj: SceneObject) -> tuple[np.ndarray, float] | None:
    """(the cone's peak slice f0(theta) on N_THETA angles (1/sr), the spot constant c (m^2))
    of a retroreflective object (:mod:`clnlos.physics.retroreflector`, Eq. 3: its return
    f_eff = f(theta) + f0(theta) S(c / r^2)); None for any other material."""
    retro = None if obj.brdf_retro_csv is not None else retroreflector(obj.material)
    if retro is None:
        return None
    return retro.cone_slice(np.linspace(0, np.pi / 2, N_THETA)), retro.spot_constant_m2


@dataclass
class SurfaceSamples:
    """Elements of all objects with per-element albedo and material index."""

    elements: Elements
    albedo: np.ndarray
    material: np.ndarray
    retro_tables: np.ndarray | None  # [n_materials, N_THETA] or None when all Lambertian
    # retroreflective objects (material_cone): [n_materials, N_THETA] cone slices and
    # [n_materials] spot constants (m^2; 0 and an all-zero slice for the other materials),
    # or None when no object is retroreflective
    cone_tables: np.ndarray | None = None
    spot_constants: np.ndarray | None = None


def sample_scene(scene: Scene, density: float | None = None) -> SurfaceSamples:
    density = scene.density_per_m2 if density is None else density
    parts, alb, mats, tables = [], [], [], []
    retros = [material_retro(o, scene.base_dir) for o in scene.objects]
    cones = [material_cone(o) for o in scene.objects]
    any_table = any(r is not None for r in retros)
    any_cone = any(c is not None for c in cones)
    for obj, retro in zip(scene.objects, retros, strict=True):
        el, albedo = object_albedo(obj, density, scene.base_dir)
        parts.append(el)
        alb.append(albedo)
        if any_table:
            tables.append(np.full(N_THETA, 1 / np.pi) if retro is None else retro)
            mats.append(np.full(len(el), len(tables) - 1, np.int32))
        else:
            mats.append(np.zeros(len(el), np.int32))
    cone_tables = spot = None
    if any_cone:
        cone_tables = np.stack([np.zeros(N_THETA) if c is None else c[0] for c in cones])
        spot = np.array([0.0 if c is None else c[1] for c in cones])
    return SurfaceSamples(Elements.concat(parts), np.concatenate(alb),
                          np.concatenate(mats).astype(np.int32),
                          np.asarray(tables) if any_table else None, cone_tables, spot)


FRONT_MIN_Z_M = 1e-6  # elements nearer the relay plane than this return no light: the light


def check_scene_geometry(scene: Scene, *, emit: bool = True) -> list[str]:
    """Objects must lie in front of the relay plane (z > 0) and return light inside the time
    window: an object with no element in front, or whose every round trip falls outside
    [start, start + bins dt), is an error; one partly outside gives a warning (returned;
    also issued now with ``emit``)."""
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
                                 f"a window that sees {name}, {front[:, 2].min():.4g} m "
                                 f"behind the relay plane: its light returns between "
                                 f"{t_near.min():.4g} s and {t_far.max():.4g} s (round trip); "
                                 "set [time] start_s before and start_s + bins * "
                                 "bin_width_s after these")
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
    if emit:
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
