"""Scene description for ``clnlos simulate`` (TOML, typed, validated).

Every error names the field, its value and the allowed range; numbers must be TOML numbers
(not strings), counts integers. A complete example (every section but [scan], [time] and
[[objects]] optional)::

    seed = 0
    [scan]                  # confocal scan points on the relay / slab exit plane z = 0
    width_m = 0.3           # side of the square scanned area (points at cell centres)
    points = 32             # points per side
    [time]
    bin_width_s = 16e-12
    bins = 512
    start_s = 0.0           # start of bin 0 (round trip from the scan point); 0 with a slab
    [[objects]]             # one table per object; objects must lie at z > 0
    shape = "letters"       # "letters" (text, height_m, stroke_m), "rectangle" (size_m = [w, h]),
                            # "sphere" (radius_m), "mesh" (path = ASCII PLY or OBJ), "mask"
                            # (path = PNG or 2-D .npy, its bright part cut out of a plane of
                            # size_m = [w, h]; optional: depth_path = .npy of per-pixel
                            # offsets along the normal, m; albedo_path = .npy of per-pixel
                            # albedo factors)
    text = "UT"
    height_m = 0.15
    stroke_m = 0.04
    translate_m = [0.0, 0.0, 0.5]
    rotate_deg = [0.0, 30.0, 0.0]   # about x, y, z: R = Rz Ry Rx
    material = "lambertian"         # see below
    albedo = 1.0
    [slab]                  # absent = plain NLOS relay wall, no diffusion
    thickness_m = 0.0254
    mu_a = 0.53
    mu_s_prime = 262.0
    n = 1.12
    [laser]
    pulse_width_s = 35e-12  # FWHM of a Gaussian pulse -> temporal blur
    [detector]              # a photon budget -> Poisson noise
    power_w = 0.4
    rep_rate_hz = 10e6
    exposure_s = 1.0        # per scan point: each point's histogram collects photons this
                            # long (s); the whole scan takes points^2 times it
    efficiency = 0.3
    wavelength_m = 532e-9
    etendue_m2_sr = 1e-8
    dark_count_rate_hz = 0.0
    [sampling]              # accuracy knobs
    density_per_m2 = 4e5    # surface elements per square metre
    splat_order = 1         # 0: nearest bin, 1: linear between bin centres
    blur_reach_tol = 1e-3   # with a slab: I is computed past the scan border as far as the
                            # blur carries more than this fraction of its energy
    [transport]             # how light crosses the slab and meets the target
                            # (clnlos.forward.bistatic)
    model = "confocal"      # "confocal": seed Eq. 9, tau = (Phi * Phi) * I, I read at r1 = r2
                            # (the retro slice f(w, w)); "bistatic": Eq. 8 in full (light leaves
                            # the face at r1, returns at r2, full BRDF f(w1, w2); needs a [slab]);
                            # "auto": bistatic where a material's lobe is narrower than the
                            # angular spread of the slab's footprint seen from the target
                            # (clnlos.forward.bistatic.auto_choice), else confocal
    face_rings = 4          # bistatic: annuli of equal slab energy on the face
    face_angles = 8         # bistatic: samples per annulus (cost ~ (rings x angles)^2)
    texture_theta = 64      # bistatic: BRDF texture nodes over theta_i, theta_s in [0, 90] deg
    texture_dphi = 64       # bistatic: ... over delta_phi in [0, 180] deg

Materials (``material``, case-insensitive): "lambertian"; the analytic presets "matte-dark",
"glossy-paint", "brushed-metal", "mirror-like"; the ten measured-data presets of the seed
("gold-plated polyester film", "quartz glass", "aluminium alloy sample", "painted steel
plate", "black anode plate", "fuchsia lacquer board", "aluminium diffuse reflection plate",
"glass fibre", "standard white plate", "cement board"); a BRDF texture file
(``material = "tex.h5"``, written by ``clnlos brdf texture``, path relative to the scene);
an analytic model table (``material = { model = "phong", kd = 0.2, ks = 0.8, shininess = 40
}``); "retroreflective" (:mod:`clnlos.physics.retroreflector`; its fields overridden by a
table ``{ model = "retroreflective", spot_radius_m = 0.02, ... }``, fields and ranges:
``RETRO_LIMITS``; confocal transport only); or ``brdf_retro_csv = "f.csv"`` (columns
theta_deg, brdf: the confocal slice).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from clnlos.brdf.data import TEXT_ENCODING
from clnlos.brdf.presets import material_names, retroreflector
from clnlos.checks import choice, did_you_mean, input_file, integer, positive
from clnlos.config import check_keys, load_toml, slab_from_table
from clnlos.errors import InputFileError, ParameterError
from clnlos.physics.slab import Slab

SHAPES = ("letters", "rectangle", "sphere", "mesh", "mask")
# string sizes: the stroke font's cost grows with characters x covered cells; a file name
# longer than Linux's PATH_MAX cannot be opened
MAX_TEXT_CHARS = 256
MAX_PATH_CHARS = 4096

# [transport] (clnlos.forward.bistatic): models, defaults and limits of the bistatic quadrature
TRANSPORT_MODELS = ("confocal", "bistatic", "auto")
FACE_RINGS = 4        # annuli of the face quadrature (default)
FACE_ANGLES = 8       # samples per annulus (default); compiled in (private arrays)
MAX_FACE_ANGLES = 32
MAX_FACE_RINGS = 16
TEXTURE_THETA = 64    # BRDF texture nodes over theta_i and theta_s in [0, pi/2] (default)
TEXTURE_DPHI = 64     # ... over delta_phi in [0, pi]


@dataclass(frozen=True)
class TransportSettings:
    """The scene's ``[transport]`` table (defaults: this module's constants)."""

    model: str = "confocal"
    face_rings: int = FACE_RINGS
    face_angles: int = FACE_ANGLES
    texture_theta: int = TEXTURE_THETA
    texture_dphi: int = TEXTURE_DPHI

    @classmethod
    def from_table(cls, t: dict) -> TransportSettings:
        if not isinstance(t, dict):
            raise ParameterError("transport", t, "a table")
        check_keys("transport", t, set(cls.__dataclass_fields__))
        return cls(
            model=choice("transport.model", t.get("model", cls.model), TRANSPORT_MODELS),
            face_rings=integer("transport.face_rings", t.get("face_rings", cls.face_rings), 1,
                               MAX_FACE_RINGS),
            face_angles=integer("transport.face_angles", t.get("face_angles", cls.face_angles),
                                1, MAX_FACE_ANGLES),
            texture_theta=integer("transport.texture_theta",
                                  t.get("texture_theta", cls.texture_theta), 2, 1024),
            texture_dphi=integer("transport.texture_dphi", t.get("texture_dphi", cls.texture_dphi),
                                 2, 1024))


MAX_ROTATE_DEG = 360.0  # |rotate_deg| per axis at most (a turn; beyond it sin/cos lose digits)
MAX_TRANSLATE_M = 1e7   # |translate_m| per axis at most (past the reach of any time window:
                        # 65536 bins of 1 us, 9.8e6 m of depth)


def _vec3(name, v, bound: float | None = None) -> tuple[float, float, float]:
    """Three finite numbers (each within [-bound, bound] when given)."""
    if not isinstance(v, list | tuple) or len(v) != 3:
        raise ParameterError(name, v, "a list of three numbers")
    out = []
    rng = "three finite numbers" + (f" from {-bound:g} to {bound:g}" if bound else "")
    for x in v:
        if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x) or (
                bound is not None and abs(x) > bound):
            raise ParameterError(name, v, rng)
        out.append(float(x))
    return tuple(out)


@dataclass
class SceneObject:
    shape: str
    translate_m: tuple[float, float, float] = (0.0, 0.0, 0.5)
    rotate_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    material: str | dict = "lambertian"
    albedo: float = 1.0
    text: str = "UT"
    height_m: float = 0.2
    stroke_m: float = 0.04
    size_m: tuple[float, float] = (0.1, 0.1)
    radius_m: float = 0.05
    path: str | None = None
    brdf_retro_csv: str | None = None
    depth_path: str | None = None
    albedo_path: str | None = None


@dataclass
class Detector:
    """The photon budget of a capture: laser power (W), repetition rate (Hz), exposure per scan
    point (s: every scan point's histogram collects for ``exposure_s``, so a scan of N x N
    points takes N^2 ``exposure_s``), detection efficiency, wavelength (m), etendue (m^2 sr)
    and dark-count rate (Hz)."""

    power_w: float = 0.4
    rep_rate_hz: float = 10e6
    exposure_s: float = 1.0
    efficiency: float = 0.3
    wavelength_m: float = 532e-9
    etendue_m2_sr: float = 1e-8
    dark_count_rate_hz: float = 0.0

    def photons_emitted(self) -> float:
        """Photons leaving the laser while one scan point is exposed, P lambda / (h c) * T
        (T = ``exposure_s``, per scan point)."""
        h, c = 6.62607015e-34, 299_792_458.0
        return self.power_w * self.wavelength_m / (h * c) * self.exposure_s


@dataclass
class Scene:
    width_m: float
    points: int
    bin_width_s: float
    bins: int
    start_s: float
    objects: list[SceneObject]
    slab: Slab | None = None
    n_dipoles: int | None = None
    pulse_width_s: float | None = None
    detector: Detector | None = None
    density_per_m2: float = 4e5
    splat_order: int = 1
    seed: int = 0
    blur_reach_tol: float = 1e-3
    base_dir: Path = field(default_factory=Path.cwd)
    text: str = ""
    transport: TransportSettings = field(default_factory=TransportSettings)

    @property
    def pitch_m(self) -> float:
        return self.width_m / self.points

    def scan_centres(self) -> np.ndarray:
        return (np.arange(self.points) + 0.5) * self.pitch_m - self.width_m / 2

    def input_paths(self) -> list[Path]:
        """The files the scene names (meshes, retro CSVs, BRDF texture materials), resolved
        against its folder: read by a simulation, so never its outputs."""
        out = []
        for o in self.objects:
            out += [self.base_dir / p for p in (o.path, o.brdf_retro_csv, o.depth_path,
                                                o.albedo_path) if p is not None]
        return out + self.texture_paths()

    def texture_paths(self) -> list[Path]:
        """The BRDF texture files the scene's materials name, resolved against its folder."""
        return [self.base_dir / o.material for o in self.objects
                if isinstance(o.material, str) and o.material.endswith((".h5", ".hdf5"))]

    @classmethod
    def from_toml(cls, path) -> Scene:
        p = Path(path)
        d = load_toml(p)
        return cls.from_dict(d, base_dir=p.parent, text=p.read_text(encoding="utf-8"))

    @classmethod
    def from_dict(cls, d: dict, *, base_dir: Path | None = None, text: str = "") -> Scene:
        check_keys("", d, {"scan", "time", "objects", "slab", "laser", "detector", "sampling",
                           "seed", "transport"})
        for sec in ("scan", "time", "objects"):
            if sec not in d:
                raise ParameterError(sec, None, "a required section")
        scan, tm = d["scan"], d["time"]
        check_keys("scan", scan, {"width_m", "points"})
        check_keys("time", tm, {"bin_width_s", "bins", "start_s"})
        width = positive("scan.width_m", scan.get("width_m"), upper=100.0)
        points = integer("scan.points", scan.get("points"), 1, 4096)
        bw = positive("time.bin_width_s", tm.get("bin_width_s"), upper=1e-6)
        bins = integer("time.bins", tm.get("bins"), 1, 1 << 16)
        start = tm.get("start_s", 0.0)
        if isinstance(start, bool) or not isinstance(start, int | float) or not (
                math.isfinite(start) and 0 <= start <= 1e-3):
            raise ParameterError("time.start_s", start, "0 to 1e-3 s")
        objs = d["objects"]
        if not isinstance(objs, list) or not objs:
            raise ParameterError("objects", objs, "one or more [[objects]] tables")
        objects = [_object(i, o) for i, o in enumerate(objs)]
        slab, nd = slab_from_table(d["slab"]) if "slab" in d else (None, None)
        pulse = None
        if "laser" in d:
            check_keys("laser", d["laser"], {"pulse_width_s", "wavelength_m"})
            if "pulse_width_s" in d["laser"]:
                pulse = positive("laser.pulse_width_s", d["laser"]["pulse_width_s"], upper=1e-6)
        det = None
        if "detector" in d:
            t = d["detector"]
            check_keys("detector", t, set(Detector.__dataclass_fields__))
            det = Detector(**{k: positive(f"detector.{k}", v, allow_zero=k ==
                                          "dark_count_rate_hz", upper=1e12)
                              for k, v in t.items()})
            if det.efficiency > 1:
                raise ParameterError("detector.efficiency", det.efficiency, "0 to 1")
        smp = d.get("sampling", {})
        check_keys("sampling", smp, {"density_per_m2", "splat_order", "blur_reach_tol"})
        dens = positive("sampling.density_per_m2",
                        smp.get("density_per_m2", cls.density_per_m2), upper=1e10)
        splat = integer("sampling.splat_order", smp.get("splat_order", cls.splat_order), 0, 1)
        reach_tol = positive("sampling.blur_reach_tol",
                             smp.get("blur_reach_tol", cls.blur_reach_tol), upper=1.0)
        seed = integer("seed", d.get("seed", cls.seed), 0, 2**63 - 1)
        transport = TransportSettings.from_table(d.get("transport", {}))
        if transport.model == "bistatic" and slab is None:
            raise ParameterError("transport.model", "bistatic", "'confocal' or 'auto' without "
                                 "a [slab] (Eq. 8 needs the slab's face; without one r1 = r2 "
                                 "and it is the confocal model)")
        return cls(width, points, bw, bins, float(start), objects, slab, nd, pulse, det, dens,
                   splat, seed, blur_reach_tol=reach_tol, base_dir=base_dir or Path.cwd(),
                   text=text, transport=transport)


def _object(i: int, o: dict) -> SceneObject:
    sec = f"objects[{i}]"
    if not isinstance(o, dict):
        raise ParameterError(sec, o, "a table")
    check_keys(sec, o, set(SceneObject.__dataclass_fields__))
    shape = choice(f"{sec}.shape", o.get("shape"), SHAPES)
    kw = {"shape": shape}
    if "translate_m" in o:
        kw["translate_m"] = _vec3(f"{sec}.translate_m", o["translate_m"], MAX_TRANSLATE_M)
    if "rotate_deg" in o:
        kw["rotate_deg"] = _vec3(f"{sec}.rotate_deg", o["rotate_deg"], MAX_ROTATE_DEG)
    if "albedo" in o:
        kw["albedo"] = positive(f"{sec}.albedo", o["albedo"], allow_zero=True, upper=1e3)
    if "material" in o:
        m = o["material"]
        if not isinstance(m, str | dict):
            raise ParameterError(f"{sec}.material", m, "a preset name or a model table")
        if isinstance(m, str) and len(m) > MAX_PATH_CHARS:
            raise ParameterError(f"{sec}.material", m, "a preset name or a texture file of "
                                 f"at most {MAX_PATH_CHARS} characters")
        if isinstance(m, str) and not m.lower().endswith((".h5", ".hdf5")) \
                and m.lower() not in material_names():
            names = material_names()
            raise ParameterError(f"{sec}.material", m, ", ".join(names) + ", a BRDF texture "
                                 ".h5 or a model table" + did_you_mean(m.lower(), names))
        retroreflector(m, f"{sec}.material")  # a retroreflective table's fields, checked
        kw["material"] = m
    for k in ("height_m", "stroke_m", "radius_m"):
        if k in o:
            kw[k] = positive(f"{sec}.{k}", o[k], upper=100.0)
    if "text" in o:
        if not isinstance(o["text"], str) or not o["text"].strip():
            raise ParameterError(f"{sec}.text", o["text"], "a non-empty string")
        if len(o["text"]) > MAX_TEXT_CHARS:
            raise ParameterError(f"{sec}.text", o["text"],
                                 f"at most {MAX_TEXT_CHARS} characters")
        kw["text"] = o["text"]
    if "size_m" in o:
        s = o["size_m"]
        if not isinstance(s, list) or len(s) != 2:
            raise ParameterError(f"{sec}.size_m", s, "[width, height] in m")
        kw["size_m"] = (positive(f"{sec}.size_m", s[0], upper=100.0),
                        positive(f"{sec}.size_m", s[1], upper=100.0))
    for k in ("path", "brdf_retro_csv", "depth_path", "albedo_path"):
        if k in o:
            if not isinstance(o[k], str) or len(o[k]) > MAX_PATH_CHARS:
                raise ParameterError(f"{sec}.{k}", o[k],
                                     f"a file path of at most {MAX_PATH_CHARS} characters")
            kw[k] = o[k]
    if shape == "mesh" and "path" not in kw:
        raise ParameterError(f"{sec}.path", None, "an ASCII PLY or OBJ file for shape = mesh")
    if shape == "mask":
        for k, what in (("path", "a PNG or 2-D .npy mask"), ("size_m", "[width, height] in m")):
            if k not in kw:
                raise ParameterError(f"{sec}.{k}", None, f"{what} for shape = mask")
    else:
        for k in ("depth_path", "albedo_path"):
            if k in kw:
                raise ParameterError(f"{sec}.{k}", kw[k], "no value but with shape = mask")
    obj = SceneObject(**kw)
    if shape == "letters" and not obj.stroke_m < obj.height_m:
        raise ParameterError(f"{sec}.stroke_m", obj.stroke_m, f"< height_m = {obj.height_m}")
    return obj


def read_retro_csv(path) -> tuple[np.ndarray, np.ndarray]:
    """(theta_rad, f) of a confocal retro-reflection slice CSV with columns theta_deg,brdf."""
    p = input_file(path, "brdf_retro_csv ")
    rows = []
    with p.open(newline="", encoding=TEXT_ENCODING) as f:  # a BOM (Excel) is skipped
        lines = [ln for ln in f if ln.strip() and not ln.lstrip().startswith("#")]
    reader = csv.reader(lines)
    header = [h.strip() for h in next(reader, [])]
    if header[:2] != ["theta_deg", "brdf"]:
        raise InputFileError(f"{p}: header must be 'theta_deg,brdf', got {','.join(header)}")
    for k, row in enumerate(reader, start=2):
        try:
            th, fv = float(row[0]), float(row[1])
        except (ValueError, IndexError):
            raise InputFileError(f"{p}: line {k}: two numbers expected") from None
        if not (math.isfinite(th) and math.isfinite(fv)):
            raise InputFileError(f"{p}: line {k}: NaN or Inf")
        if not 0 <= th <= 90:
            raise InputFileError(f"{p}: line {k}: theta_deg {th} outside 0..90")
        if fv < 0:
            raise InputFileError(f"{p}: line {k}: negative BRDF {fv}")
        rows.append((th, fv))
    if len(rows) < 2:
        raise InputFileError(f"{p}: at least two rows needed")
    a = np.asarray(sorted(rows))
    return np.radians(a[:, 0]), a[:, 1]
