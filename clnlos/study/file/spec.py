"""A study file, parsed and checked before any work: the typed :class:`Study` every part of a
study reads (pure: no OpenCL; the rig's tables are checked by the scene parser itself).

A study file is TOML (docs/study-file.md documents every key)::

    [study]                 # optional: name, seed, realisations, legible_fraction, refine_ratio
    [scan] [time] [laser] [detector] [slab] [sampling]   # the rig: a scene file's tables
    [reconstruction]        # optional: iterations, snr_rule (every inversion's)
    [inversions]            # methods = ["lct", "iterative"]; reflectance = ["lambertian", "known"]
    [[materials]]           # name, brdf, albedo
    [[targets]]             # text | glyphs | pattern | mask (+ width_m); height_m, depth_m, ...
    [sweep]                 # exposure_s, letter_height_m, depth_m, ...: one grid over all of them
    [[sweeps]]              # the same, each for chosen targets, materials, glyphs, inversions
    [table]                 # optional: every material x target at the rig's exposure
    [judge] [classifier] [transport_comparison]   # optional sections of the material study
    [[real]]                # optional: real captures of the rig, each beside its twin

``[detector] exposure_s`` is the exposure *per scan point* (s): a capture of N x N points
takes N^2 times as long. Files a study names (BRDF files, masks, captures) are found relative
to the study file's folder. Every error names the key, its value and what is allowed
(:class:`~clnlos.errors.ParameterError`), or the file and what is wrong with it
(:class:`~clnlos.errors.InputFileError`).
"""

from __future__ import annotations

import importlib.resources
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any


from clnlos.brdf.catalog import (
    MODEL_FORMAT,
    TEXTURE_FORMAT,
    file_format,
    material_names,
)
from clnlos.brdf.data import read_gonio_csv
from clnlos.checks import (
    check_keys,
    choice,
    did_you_mean,
    input_file,
    integer,
    parse_toml,
    positive,
    real,
)
from clnlos.config import METHODS, SNR_RULES, ReconstructionConfig
from clnlos.errors import ClnlosError, InputFileError, ParameterError
from clnlos.forward.geometry import GLYPHS as FONT
from clnlos.forward.geometry import MASK_FORMATS, read_mask
from clnlos.forward.scene import Detector, Scene
from clnlos.io.files import file_sha256
from clnlos.physics.slab import CDT_SLAB, Slab
from clnlos.study.score.patterns import CHART_SCALE
from clnlos.study.score.legibility import LEGIBLE_ACCURACY

BUILTIN_STUDIES = {"quick": "study_quick.toml", "full": "study_full.toml",
                   "template": "study_template.toml"}
REFLECTANCES = ("lambertian", "known", "auto")
REAL_DATA_PLANS = ("quick", "full")  # clnlos.study.real.materials.RealPlan.quick() or ()
LABELS = ("legibility", "nr", "fft")
PATTERNS = {"bars": "bars_v", "bars_v": "bars_v", "bars_h": "bars_h", "dots": "dots_3x3",
            "dots_3x3": "dots_3x3", "dots_2x2": "dots_2x2"}
# a sweep's variables and the range of each value (low, high, low allowed)
SWEEP_RANGES = {"exposure_s": (0.0, 1e4, False), "letter_height_m": (0.0, 10.0, False),
                "depth_m": (0.0, 100.0, False), "scan_width_m": (0.0, 100.0, False),
                "slab_thickness_m": (0.0, 1.0, True), "tilt_deg": (0.0, 80.0, True)}
GEOMETRY_VARIABLES = ("depth_m", "scan_width_m", "slab_thickness_m")
MAX_SWEEP_VALUES = 64
MAX_TEXT = 16                 # characters of a text target
STROKE_PER_HEIGHT = 1 / 6   # a letter's default stroke: a bold sans-serif's stem
REFINE_RATIO = 1.5            # the exposure needed: refined until bracketed within this
BRDF_FILE_SUFFIXES = (".h5", ".hdf5", ".csv")
FROM_CAPTURE = "from-capture"
RIG_TABLES = ("scan", "time", "laser", "detector", "slab", "sampling")
TOP_KEYS = ("study", *RIG_TABLES, "reconstruction", "inversions", "materials", "targets",
            "sweep", "sweeps", "table", "judge", "classifier", "transport_comparison", "real")


@dataclass(frozen=True)
class Material:
    """A target material: ``brdf`` a preset name (lower case), "retroreflective", or a file
    (absolute path: a BRDF texture or fitted model .h5, or a measured gonio CSV), with the
    SHA-256 of the file's bytes (so a study's cache never serves another file's result)."""

    name: str
    brdf: str
    albedo: float = 1.0
    kind: str = "preset"        # "preset", "texture", "model" or "measured"
    sha256: str = ""


@dataclass(frozen=True)
class Target:
    """A hidden target: ``kind`` "text" (read among the font's 26 capitals, each letter of a
    word on its own), "glyphs" (each glyph of a set, read among the set), "pattern" (a chart,
    read among the charts) or "mask" (a shape whose overlap must beat its filled box)."""

    name: str
    kind: str
    depth_m: float
    text: str = ""
    glyphs: tuple[str, ...] = ()
    pattern: str = ""
    mask: str = ""              # absolute path of a PNG or .npy
    mask_sha256: str = ""
    width_m: float = 0.0        # a mask's width (its height follows its aspect)
    height_m: float = 0.0       # letter height; a chart's side; a mask's height
    stroke_m: float = 0.0
    tilt_deg: float = 0.0
    scan_width_m: float | None = None   # this target's own scan width (None: the rig's)

    @property
    def letters(self) -> tuple[str, ...]:
        """The samples' texts of a target: each glyph of a set, else the one text."""
        return self.glyphs if self.kind == "glyphs" else (self.text,) if self.kind == "text" \
            else ()


@dataclass(frozen=True)
class Sweep:
    """One grid of swept values (every combination of ``values``), on ``targets`` x
    ``materials`` (names; all by default) with ``reflectance`` x ``methods``; ``glyphs``
    narrows a glyph set; ``realisations`` noise realisations per point."""

    values: tuple[tuple[str, tuple[float, ...]], ...]
    targets: tuple[str, ...]
    materials: tuple[str, ...]
    methods: tuple[str, ...]
    reflectance: tuple[str, ...]
    realisations: int
    glyphs: tuple[str, ...] | None = None
    name: str = ""

    @property
    def variables(self) -> tuple[str, ...]:
        return tuple(k for k, _ in self.values)

    def grid(self) -> list[dict[str, float]]:
        """Every combination of the swept values, as {variable: value}."""
        out = [{}]
        for var, vals in self.values:
            out = [{**d, var: v} for d in out for v in vals]
        return out


@dataclass(frozen=True)
class Table:
    """The material table (the seed's question at the rig's exposure): every material x
    target in ``targets`` (glyph sets), ``realisations`` each; the BRDF-aware reflectances
    on ``aware_glyphs`` only, "auto" at ``auto_targets`` only; the roles the findings read
    (``legible_target``: where a Lambertian glyph reads, ``seed_target``: the seed's Table 1)."""

    targets: tuple[str, ...]
    realisations: int
    reflectance: tuple[str, ...]
    aware_glyphs: tuple[str, ...] | None
    auto_targets: tuple[str, ...] | None
    legible_target: str
    seed_target: str | None


@dataclass(frozen=True)
class Classifier:
    labels: str = "legibility"
    extras: int = 0                 # random extra samples (metric validation, CNN)
    epochs: int | None = None
    held_out_glyphs: tuple[str, ...] = ("U", "X")
    held_out_height_m: float = 0.2


# the transport comparison's face samples, against 4 x 8 (tools/results/
# study_transport_faces.csv): 2 x 4 is 4.9% off in relative L2 and 5% in total signal for
# quartz glass (the sharpest lobe, 0.75 deg; 3 x 6: 0.7%, 0.0%; the confocal model: 16.5%),
# 0.9% and 0.0% for the aluminium alloy (2.6 deg; confocal 11%); 3 x 6 costs 4-6x more
COMPARE_RINGS = 2
COMPARE_ANGLES = 4


@dataclass(frozen=True)
class TransportComparison:
    glyphs: tuple[str, ...] | None = None
    face_rings: int = COMPARE_RINGS
    face_angles: int = COMPARE_ANGLES


@dataclass(frozen=True)
class RealEntry:
    """A real capture of the rig (absolute path), its material and target (a Target, or
    None for "from-capture": the mask of its own full-photon reconstruction)."""

    capture: str
    material: Material
    target: Target | None
    method: str = "lct"
    label: str = ""
    config: str = ""            # a reconstruction TOML (absolute path): the capture's own


@dataclass(frozen=True)
class StudyGrid:
    """The rig and the reconstruction every sample shares: the scan (default width, points),
    the time axis (bin width; ``bins`` and ``start_s`` as recorded, None: a window that holds
    the target), the pulse, the detector (``exposure_s`` per scan point), the slab
    (thickness, mu_a, mu_s', n; None: no slab), the surface sampling, the default inversion
    and the reconstruction's iterations and SNR rule."""

    scan_width_m: float = 0.3
    points: int = 32
    bin_width_s: float = 48e-12
    bins: int | None = None
    start_s: float = 0.0
    max_path_m: float = 1.6          # the shortest reconstruction window (round trip), m
    density_per_m2: float = 4e4
    method: str = "iterative"
    iterations: int = 30
    snr_rule: str = "gcv"
    reconstruction_bin_width_s: float | None = None  # None: the inversion's own default
    pulse_width_s: float | None = 35e-12
    power_w: float = Detector.power_w
    rep_rate_hz: float = Detector.rep_rate_hz
    exposure_s: float = 0.1
    wavelength_m: float = Detector.wavelength_m
    etendue_m2_sr: float = 1e-9
    efficiency: float = Detector.efficiency
    dark_count_rate_hz: float = 1000.0
    slab: tuple[float, float, float, float] | None = (   # thickness_m, mu_a, mu_s', n
        CDT_SLAB.thickness_m, CDT_SLAB.mu_a, CDT_SLAB.mu_s_prime, CDT_SLAB.n)


def rig_slab(grid: StudyGrid, thickness_m: float | None = None) -> Slab | None:
    """The rig's slab (its thickness replaced where given; None without one or at 0 m)."""
    if grid.slab is None:
        return None
    t, mu_a, mu_s_prime, n = grid.slab
    t = t if thickness_m is None else thickness_m
    return Slab(thickness_m=t, mu_a=mu_a, mu_s_prime=mu_s_prime, n=n) if t > 0 else None


@dataclass(frozen=True)
class Study:
    """A checked study file: everything a study run reads (:func:`load_study`)."""

    name: str
    grid: StudyGrid
    materials: tuple[Material, ...]
    targets: tuple[Target, ...]
    methods: tuple[str, ...] = ("iterative",)
    reflectance: tuple[str, ...] = ("lambertian",)
    sweeps: tuple[Sweep, ...] = ()
    table: Table | None = None
    judge_twins: int = 0            # the legibility judge's twins per geometry (0: no judge)
    classifier: Classifier | None = None
    transport: TransportComparison | None = None
    real: tuple[RealEntry, ...] = ()
    seed: int = 0
    realisations: int = 4
    legible_fraction: float = LEGIBLE_ACCURACY
    refine_ratio: float = REFINE_RATIO
    real_data_plan: str = "full"    # the shared captures' section (--real-data): its ladder
    source: str = ""                # the study file's path ("" for a dict)
    text: str = ""                  # its TOML text, recorded in results.json
    real_data: Path | None = None   # --real-data: the shared captures' folder

    def material(self, name: str) -> Material:
        return next(m for m in self.materials if m.name == name)

    def target(self, name: str) -> Target:
        return next(t for t in self.targets if t.name == name)

    def with_options(self, **changes) -> Study:
        return replace(self, **changes)

    def summary(self) -> dict:
        """JSON-able form for results.json."""
        d = asdict(self)
        d["real_data"] = None if self.real_data is None else str(self.real_data)
        d.pop("text")
        return d


# ---------------------------------------------------------------------------------- parsing


def _table(d: dict, key: str) -> dict:
    t = d.get(key, {})
    if not isinstance(t, dict):
        raise ParameterError(key, t, "a table")
    return t


def _tables(d: dict, key: str) -> list[dict]:
    t = d.get(key, [])
    if isinstance(t, dict):
        t = [t]
    if not isinstance(t, list) or any(not isinstance(x, dict) for x in t):
        raise ParameterError(key, t, f"[[{key}]] tables")
    return t


def _names(name: str, v: Any, allowed, *, empty_ok: bool = False) -> tuple[str, ...]:
    """A list of strings, each one of ``allowed``, no repeats."""
    if isinstance(v, str):
        v = [v]
    if not isinstance(v, list) or (not v and not empty_ok) or any(
            not isinstance(x, str) for x in v):
        raise ParameterError(name, v, "a list of " + ", ".join(map(repr, allowed)))
    for x in v:
        if x not in allowed:
            raise ParameterError(name, x, ", ".join(map(repr, allowed))
                                 + did_you_mean(x, list(allowed)))
    if len(set(v)) != len(v):
        raise ParameterError(name, v, "a list without repeats")
    return tuple(v)


def _label(name: str, v: Any) -> str:
    if not isinstance(v, str) or not v.strip() or len(v) > 80 or "\n" in v:
        raise ParameterError(name, v, "a one-line name of 1 to 80 characters")
    return v.strip()


def _file(base: Path, name: str, v: Any, what: str, suffixes=None) -> Path:
    if not isinstance(v, str) or not v.strip():
        raise ParameterError(name, v, f"the path of a {what}")
    p = (base / v).resolve() if not Path(v).is_absolute() else Path(v)
    if suffixes and p.suffix.lower() not in suffixes:
        raise ParameterError(name, v, f"a {what} ({', '.join(suffixes)})")
    try:
        return input_file(p, what + " ")
    except InputFileError as exc:
        raise InputFileError(f"{name}: {exc}") from None



def parse_material(i: int, t: dict, base: Path) -> Material:
    sec = f"materials[{i}]"
    check_keys(sec, t, {"name", "brdf", "albedo"})
    if "brdf" not in t:
        raise ParameterError(f"{sec}.brdf", None, "a preset name, \"retroreflective\", a BRDF "
                             "file (.h5 of clnlos brdf fit / brdf texture) or a measured CSV")
    spec = t["brdf"]
    albedo = positive(f"{sec}.albedo", t.get("albedo", 1.0), upper=10.0)
    if not isinstance(spec, str) or not spec.strip():
        raise ParameterError(f"{sec}.brdf", spec, "a preset name or a BRDF file")
    if spec.lower().endswith(BRDF_FILE_SUFFIXES):
        path = _file(base, f"{sec}.brdf", spec, "BRDF", BRDF_FILE_SUFFIXES)
        if path.suffix.lower() == ".csv":
            read_gonio_csv(path)  # the columns of ../shared/data/brdf, checked now
            kind = "measured"
        else:
            fmt = file_format(path)
            kind = "texture" if fmt == TEXTURE_FORMAT else "model"
            assert fmt in (TEXTURE_FORMAT, MODEL_FORMAT)
        name = t.get("name", path.stem)
        return Material(_label(f"{sec}.name", name), str(path), albedo, kind,
                        file_sha256(path))
    key = spec.lower()
    names = material_names()
    if key not in names:
        raise ParameterError(f"{sec}.brdf", spec, "a preset (" + ", ".join(names) + "), a "
                             "BRDF .h5 or a measured .csv" + did_you_mean(key, names))
    return Material(_label(f"{sec}.name", t.get("name", key)), key, albedo)


def _letters(name: str, v: Any, *, word: bool) -> str:
    if not isinstance(v, str) or not v.strip():
        raise ParameterError(name, v, "capital letters A-Z")
    s = v.strip().upper() if word else v.strip()
    bad = [c for c in s if c not in FONT or (not word and c == " ")]
    if bad or len(s) > (MAX_TEXT if word else 1):
        raise ParameterError(name, v, f"capital letters A-Z (at most {MAX_TEXT}, spaces "
                             "between words)" if word else "one capital letter A-Z")
    return s


def parse_target(i: int | str, t: dict, base: Path, scan_width_m: float | None) -> Target:
    sec = f"targets[{i}]" if isinstance(i, int) else i
    check_keys(sec, t, {"name", "text", "glyphs", "pattern", "mask", "width_m", "height_m",
                        "stroke_m", "depth_m", "tilt_deg", "scan_width_m"})
    kinds = [k for k in ("text", "glyphs", "pattern", "mask") if k in t]
    if len(kinds) != 1:
        raise ParameterError(sec, ", ".join(kinds) or "none of text, glyphs, pattern, mask",
                             "exactly one of text, glyphs, pattern or mask")
    kind = kinds[0]
    if "depth_m" not in t:
        raise ParameterError(f"{sec}.depth_m", None, "the target's depth behind the scan "
                             "plane (m), > 0")
    depth = positive(f"{sec}.depth_m", t["depth_m"], upper=100.0)
    tilt = real(f"{sec}.tilt_deg", t.get("tilt_deg", 0.0), 0.0, 79.0)
    scan = None if "scan_width_m" not in t else positive(f"{sec}.scan_width_m",
                                                          t["scan_width_m"], upper=100.0)
    kw: dict = {"kind": kind, "depth_m": depth, "tilt_deg": tilt, "scan_width_m": scan}
    if kind == "mask":
        path = _file(base, f"{sec}.mask", t["mask"], "mask image", MASK_FORMATS)
        try:
            m = read_mask(path)
        except InputFileError as exc:
            raise InputFileError(f"{sec}.mask: {exc}") from None
        if "width_m" not in t:
            raise ParameterError(f"{sec}.width_m", None, "the mask's width (m) with mask")
        width = positive(f"{sec}.width_m", t["width_m"], upper=100.0)
        extra = sorted({"height_m", "stroke_m"} & set(t))
        if extra:
            raise ParameterError(f"{sec}.{extra[0]}", t[extra[0]], "no value with mask (its "
                                 "height follows width_m and the image's aspect)")
        kw.update(mask=str(path), mask_sha256=file_sha256(path), width_m=width,
                  height_m=width * m.shape[0] / m.shape[1])
        default = path.stem
    else:
        if "width_m" in t:
            raise ParameterError(f"{sec}.width_m", t["width_m"], "no value without mask "
                                 "(letters and charts take height_m)")
        if "height_m" not in t:
            raise ParameterError(f"{sec}.height_m", None, "the letter height or the chart's "
                                 "side (m), > 0")
        h = positive(f"{sec}.height_m", t["height_m"], upper=10.0)
        stroke = positive(f"{sec}.stroke_m", t.get("stroke_m", STROKE_PER_HEIGHT * h),
                          upper=10.0)
        if kind != "pattern" and not stroke < h:
            raise ParameterError(f"{sec}.stroke_m", stroke, f"< height_m = {h:g}")
        kw.update(height_m=h, stroke_m=stroke)
        if kind == "text":
            kw["text"] = default = _letters(f"{sec}.text", t["text"], word=True)
        elif kind == "glyphs":
            g = t["glyphs"]
            if not isinstance(g, list) or len(g) < 2:
                raise ParameterError(f"{sec}.glyphs", g, "a list of two or more capital "
                                     "letters, each read among the others")
            kw["glyphs"] = tuple(_letters(f"{sec}.glyphs", x, word=False) for x in g)
            if len(set(kw["glyphs"])) != len(g):
                raise ParameterError(f"{sec}.glyphs", g, "a list without repeats")
            default = "".join(kw["glyphs"])
        else:
            p = t["pattern"]
            if p not in PATTERNS:
                raise ParameterError(f"{sec}.pattern", p, ", ".join(map(repr, PATTERNS))
                                     + did_you_mean(p, list(PATTERNS)))
            kw["pattern"] = default = PATTERNS[p]
    name = _label(f"{sec}.name", t.get("name", default))
    out = Target(name=name, **kw)
    check_target_fits(sec, out, scan if scan is not None else scan_width_m)
    return out


def check_target_fits(sec: str, t: Target, scan_width_m: float | None) -> None:
    """A target larger than twice its scan sees little of itself: refused."""
    if scan_width_m is None:
        return
    size = max(t.height_m * (CHART_SCALE if t.kind == "pattern" else 1.0), t.width_m)
    if size > 2 * scan_width_m:
        raise ParameterError(f"{sec}.height_m" if t.kind != "mask" else f"{sec}.width_m",
                             size, f"at most twice the scan width ({scan_width_m:g} m)")


def parse_rig(d: dict, base: Path) -> StudyGrid:
    """The rig's tables through the scene parser (a probe object at 1 m), into a StudyGrid."""
    for k in ("scan", "time"):
        if k not in d:
            raise ParameterError(k, None, f"a required table of the rig ([{k}])")
    time = dict(_table(d, "time"))
    probe = {k: d[k] for k in RIG_TABLES if k in d}
    probe["time"] = {"bins": 1, **time}
    probe["objects"] = [{"shape": "rectangle", "size_m": [0.1, 0.1]}]
    scene = Scene.from_dict(probe, base_dir=base)
    recon = _table(d, "reconstruction")
    check_keys("reconstruction", recon, {"iterations", "snr_rule", "max_path_m",
                                         "bin_width_s"})
    rbw = recon.get("bin_width_s")
    if rbw is not None:
        rbw = positive("reconstruction.bin_width_s", rbw, upper=1e-9)
        if rbw < scene.bin_width_s:
            raise ParameterError("reconstruction.bin_width_s", rbw, f">= the capture's "
                                 f"time.bin_width_s = {scene.bin_width_s:g} s (bins are "
                                 "summed, never split)")
    det = scene.detector or Detector()
    kw = {} if scene.detector is not None else {
        "exposure_s": StudyGrid.exposure_s, "etendue_m2_sr": StudyGrid.etendue_m2_sr,
        "dark_count_rate_hz": StudyGrid.dark_count_rate_hz}
    return StudyGrid(
        scan_width_m=scene.width_m, points=scene.points, bin_width_s=scene.bin_width_s,
        bins=scene.bins if "bins" in time else None, start_s=scene.start_s,
        max_path_m=positive("reconstruction.max_path_m",
                            recon.get("max_path_m", StudyGrid.max_path_m), upper=1e4),
        density_per_m2=scene.density_per_m2,
        iterations=integer("reconstruction.iterations",
                           recon.get("iterations", StudyGrid.iterations), 1, 10000),
        snr_rule=choice("reconstruction.snr_rule",
                        recon.get("snr_rule", StudyGrid.snr_rule), SNR_RULES),
        reconstruction_bin_width_s=rbw,
        pulse_width_s=scene.pulse_width_s, power_w=det.power_w, rep_rate_hz=det.rep_rate_hz,
        wavelength_m=det.wavelength_m, efficiency=det.efficiency,
        **{"exposure_s": det.exposure_s, "etendue_m2_sr": det.etendue_m2_sr,
           "dark_count_rate_hz": det.dark_count_rate_hz, **kw},
        slab=None if scene.slab is None else (scene.slab.thickness_m, scene.slab.mu_a,
                                              scene.slab.mu_s_prime, scene.slab.n))


def _values(name: str, var: str, v: Any) -> tuple[float, ...]:
    lo, hi, lo_ok = SWEEP_RANGES[var]
    if not isinstance(v, list) or not v:
        raise ParameterError(name, v, "a non-empty list of numbers")
    if len(v) > MAX_SWEEP_VALUES:
        raise ParameterError(name, v, f"at most {MAX_SWEEP_VALUES} values")
    out = []
    for x in v:
        out.append(real(name, x, lo, hi) if lo_ok else positive(name, x, upper=hi))
    if len(set(out)) != len(out):
        raise ParameterError(name, v, "a list without repeats")
    return tuple(sorted(out))


def parse_sweep(sec: str, t: dict, study_names: dict, defaults: dict, grid: StudyGrid,
                *, selectors: bool) -> Sweep:
    sel = {"name", "targets", "materials", "glyphs", "methods", "reflectance", "realisations"}
    check_keys(sec, t, set(SWEEP_RANGES) | (sel if selectors else set()))
    values = tuple((var, _values(f"{sec}.{var}", var, t[var])) for var in SWEEP_RANGES
                   if var in t)
    if not values:
        raise ParameterError(sec, t, "one or more of " + ", ".join(SWEEP_RANGES)
                             + " with a list of values")
    targets = _names(f"{sec}.targets", t.get("targets", list(study_names["targets"])),
                     study_names["targets"])
    if any(var == "slab_thickness_m" and any(x > 0 for x in vals) for var, vals in values) \
            and grid.slab is None:
        raise ParameterError(f"{sec}.slab_thickness_m", dict(values)["slab_thickness_m"],
                             "0 only: the rig has no [slab] to thicken")
    glyphs = None
    if "glyphs" in t:
        glyphs = _names(f"{sec}.glyphs", t["glyphs"], tuple(FONT))
    return Sweep(
        values=values, targets=targets,
        materials=_names(f"{sec}.materials", t.get("materials", list(study_names["materials"])),
                         study_names["materials"]),
        methods=_names(f"{sec}.methods", t.get("methods", list(defaults["methods"])),
                       tuple(METHODS)),
        reflectance=_names(f"{sec}.reflectance",
                           t.get("reflectance", list(defaults["reflectance"])), REFLECTANCES),
        realisations=integer(f"{sec}.realisations",
                             t.get("realisations", defaults["realisations"]), 1, 1000),
        glyphs=glyphs, name=_label(f"{sec}.name", t["name"]) if "name" in t else "")


def check_sweep_targets(sec: str, s: Sweep, targets: dict[str, Target]) -> Sweep:
    """A height sweep needs letters or charts; a glyph subset needs glyph sets holding it. A
    mask target in the one [sweep] table is left out of a height sweep (say so in a note)."""
    keep = []
    for name in s.targets:
        t = targets[name]
        if "letter_height_m" in s.variables and t.kind == "mask":
            if sec != "sweep":
                raise ParameterError(f"{sec}.targets", name, "letters or charts: a mask's "
                                     "size is its width_m (sweep its depth instead)")
            continue
        if s.glyphs is not None and not (t.kind == "glyphs" and set(s.glyphs) <= set(t.glyphs)):
            raise ParameterError(f"{sec}.glyphs", list(s.glyphs), f"glyphs of the target "
                                 f"{name!r}'s set ({''.join(t.glyphs) or 'none: not a set'})")
        keep.append(name)
    if not keep:
        raise ParameterError(f"{sec}.targets", list(s.targets), "one or more targets the "
                             "sweep can vary")
    return replace(s, targets=tuple(keep))


def parse_table(t: dict, targets: dict[str, Target], reflectance, realisations) -> Table:
    check_keys("table", t, {"targets", "realisations", "reflectance", "aware_glyphs",
                            "auto_targets", "legible_target", "seed_target"})
    sets = [n for n, x in targets.items() if x.kind == "glyphs"]
    names = _names("table.targets", t.get("targets", sets), tuple(sets))
    refl = _names("table.reflectance", t.get("reflectance", list(reflectance)), REFLECTANCES)
    if refl[0] != "lambertian":
        raise ParameterError("table.reflectance", list(refl), "\"lambertian\" first, then any "
                             "of " + ", ".join(REFLECTANCES[1:]))
    glyphs = sorted({g for n in names for g in targets[n].glyphs})
    aware = (None if "aware_glyphs" not in t
             else _names("table.aware_glyphs", t["aware_glyphs"], tuple(glyphs)))
    auto = (None if "auto_targets" not in t
            else _names("table.auto_targets", t["auto_targets"], names))
    legible = choice("table.legible_target", t.get("legible_target", names[0]), names)
    seed_t = t.get("seed_target")
    return Table(names, integer("table.realisations", t.get("realisations", realisations), 1,
                                1000), refl, aware, auto, legible,
                 None if seed_t is None else choice("table.seed_target", seed_t, names))


def parse_real(i: int, t: dict, base: Path, materials: dict[str, Material],
               scan_width_m: float) -> RealEntry:
    sec = f"real[{i}]"
    check_keys(sec, t, {"capture", "material", "target", "method", "name", "config"})
    for k in ("capture", "material"):
        if k not in t:
            raise ParameterError(f"{sec}.{k}", None, "a capture file" if k == "capture" else
                                 "a [[materials]] name or a brdf value")
    path = _file(base, f"{sec}.capture", t["capture"], "capture")
    m = t["material"]
    if isinstance(m, str) and m in materials:
        mat = materials[m]
    else:
        mat = parse_material(i, {"brdf": m}, base) if isinstance(m, str) else None
        if mat is None:
            raise ParameterError(f"{sec}.material", m, "a [[materials]] name or a brdf value")
    tgt = t.get("target", FROM_CAPTURE)
    target = None
    if isinstance(tgt, dict):
        target = parse_target(f"{sec}.target", tgt, base, scan_width_m)
        if target.kind == "glyphs":
            raise ParameterError(f"{sec}.target.glyphs", list(target.glyphs), "no value: a "
                                 "real capture holds one target (text, pattern or mask)")
    elif tgt != FROM_CAPTURE:
        raise ParameterError(f"{sec}.target", tgt, f"{FROM_CAPTURE!r} or a target table "
                             "(the keys of [[targets]])")
    method = choice(f"{sec}.method", t.get("method", "lct"), tuple(METHODS))
    config = ""
    if "config" in t:
        config = str(_file(base, f"{sec}.config", t["config"], "reconstruction TOML",
                           (".toml",)))
        ReconstructionConfig.from_toml(config)  # checked now, not after the minutes
    return RealEntry(str(path), mat, target, method,
                     _label(f"{sec}.name", t.get("name", path.stem)), config)


def parse_study(d: dict, *, base_dir=".", source: str = "", text: str = "") -> Study:
    """A study file's dict, every key and value checked (the first bad one raised), into a
    :class:`Study`; files are found relative to ``base_dir``."""
    base = Path(base_dir)
    if not isinstance(d, dict):
        raise ParameterError("study file", d, "a TOML table")
    check_keys("", d, set(TOP_KEYS))
    meta = _table(d, "study")
    check_keys("study", meta, {"name", "seed", "realisations", "legible_fraction",
                               "refine_ratio", "real_data_plan"})
    grid = parse_rig(d, base)
    inv = _table(d, "inversions")
    check_keys("inversions", inv, {"methods", "reflectance"})
    methods = _names("inversions.methods", inv.get("methods", ["iterative"]), tuple(METHODS))
    reflectance = _names("inversions.reflectance", inv.get("reflectance", ["lambertian"]),
                         REFLECTANCES)
    grid = replace(grid, method=methods[0])
    realisations = integer("study.realisations", meta.get("realisations", 4), 1, 1000)
    mats = _tables(d, "materials")
    if not mats:
        raise ParameterError("materials", None, "one or more [[materials]] tables (name, "
                             "brdf, albedo)")
    materials = tuple(parse_material(i, t, base) for i, t in enumerate(mats))
    _unique("materials", [m.name for m in materials])
    tgts = _tables(d, "targets")
    if not tgts:
        raise ParameterError("targets", None, "one or more [[targets]] tables (text, glyphs, "
                             "pattern or mask; height_m, depth_m)")
    targets = tuple(parse_target(i, t, base, grid.scan_width_m) for i, t in enumerate(tgts))
    _unique("targets", [t.name for t in targets])
    by_target = {t.name: t for t in targets}
    names = {"targets": tuple(by_target), "materials": tuple(m.name for m in materials)}
    defaults = {"methods": methods, "reflectance": reflectance, "realisations": realisations}
    sweeps = []
    if "sweep" in d:
        s = parse_sweep("sweep", _table(d, "sweep"), names, defaults, grid, selectors=False)
        sweeps.append(check_sweep_targets("sweep", s, by_target))
    for i, t in enumerate(_tables(d, "sweeps")):
        s = parse_sweep(f"sweeps[{i}]", t, names, defaults, grid, selectors=True)
        sweeps.append(check_sweep_targets(f"sweeps[{i}]", s, by_target))
    table = None
    if "table" in d:
        if not any(t.kind == "glyphs" for t in targets):
            raise ParameterError("table", d["table"], "a study with one or more glyph-set "
                                 "targets (glyphs = [...]) to tabulate")
        table = parse_table(_table(d, "table"), by_target, reflectance, realisations)
    if not sweeps and table is None and not _tables(d, "real"):
        raise ParameterError("sweep", None, "a [sweep] (e.g. exposure_s = [1e-4, 1e-3, 1e-2]),"
                             " [[sweeps]], a [table] or [[real]] captures: the study has "
                             "nothing to measure")
    judge = _table(d, "judge")
    check_keys("judge", judge, {"twins"})
    if judge and table is None:
        raise ParameterError("judge", judge, "a [table] beside it (the judge learns from the "
                             "table's reconstructions too)")
    twins = integer("judge.twins", judge.get("twins", 16), 1, 1000) if judge else 0
    classifier = None
    if "classifier" in d:
        c = _table(d, "classifier")
        check_keys("classifier", c, {"labels", "extras", "epochs", "held_out_glyphs",
                                     "held_out_height_m"})
        if table is None:
            raise ParameterError("classifier", c, "a [table] beside it")
        classifier = Classifier(
            labels=choice("classifier.labels", c.get("labels", "legibility"), LABELS),
            extras=integer("classifier.extras", c.get("extras", 0), 0, 100000),
            epochs=None if "epochs" not in c else integer("classifier.epochs", c["epochs"], 1,
                                                          10000),
            held_out_glyphs=_names("classifier.held_out_glyphs",
                                   c.get("held_out_glyphs", ["U", "X"]), tuple(FONT)),
            held_out_height_m=positive("classifier.held_out_height_m",
                                       c.get("held_out_height_m", 0.2), upper=10.0))
    transport = None
    if "transport_comparison" in d:
        c = _table(d, "transport_comparison")
        check_keys("transport_comparison", c, {"glyphs", "face_rings", "face_angles"})
        if table is None or grid.slab is None:
            raise ParameterError("transport_comparison", c, "a [table] and a [slab] beside "
                                 "it (Eq. 8 differs from Eq. 9 only through a slab)")
        transport = TransportComparison(
            glyphs=None if "glyphs" not in c else _names(
                "transport_comparison.glyphs", c["glyphs"], tuple(FONT)),
            face_rings=integer("transport_comparison.face_rings",
                               c.get("face_rings", COMPARE_RINGS), 1, 16),
            face_angles=integer("transport_comparison.face_angles",
                                c.get("face_angles", COMPARE_ANGLES),
                                1, 32))
    by_material = {m.name: m for m in materials}
    real_entries = tuple(parse_real(i, t, base, by_material, grid.scan_width_m)
                         for i, t in enumerate(_tables(d, "real")))
    refine = meta.get("refine_ratio", REFINE_RATIO)
    if refine != 0:
        refine = real("study.refine_ratio", refine, 1.05, 100.0)
    return Study(
        name=_label("study.name", meta.get("name", Path(source).stem if source else "study")),
        grid=grid, materials=materials, targets=targets, methods=methods,
        reflectance=reflectance, sweeps=tuple(sweeps), table=table, judge_twins=twins,
        classifier=classifier, transport=transport, real=real_entries,
        seed=integer("study.seed", meta.get("seed", 0), 0, 2**31 - 1),
        realisations=realisations,
        legible_fraction=real("study.legible_fraction",
                              meta.get("legible_fraction", LEGIBLE_ACCURACY), 0.5, 1.0),
        refine_ratio=float(refine),
        real_data_plan=choice("study.real_data_plan", meta.get("real_data_plan", "full"),
                              REAL_DATA_PLANS),
        source=source, text=text)


def _unique(section: str, names: list[str]) -> None:
    seen = set()
    for i, n in enumerate(names):
        if n in seen:
            raise ParameterError(f"{section}[{i}].name", n, f"a name no other {section[:-1]} "
                                 "has (give each its own name)")
        seen.add(n)


def builtin_text(name: str) -> str:
    """The TOML text of a built-in study file (``quick``, ``full``, ``template``)."""
    res = importlib.resources.files("clnlos.data").joinpath(BUILTIN_STUDIES[name])
    return res.read_text(encoding="utf-8")


def load_study(study, *, base_dir=None) -> Study:
    """A :class:`Study` from a study file's path, a built-in's name (``"quick"``, ``"full"``)
    or a dict (files relative to ``base_dir``, default the current folder); every problem is
    one ClnlosError naming the file, the key and its value, raised before any work."""
    if isinstance(study, Study):
        return study
    if isinstance(study, dict):
        return parse_study(study, base_dir=base_dir or ".")
    if isinstance(study, str) and study in BUILTIN_STUDIES and not Path(study).exists():
        text = builtin_text(study)
        return parse_study(parse_toml(text), base_dir=base_dir or ".", source=study, text=text)
    path = input_file(Path(study), "study ")
    try:
        text = path.read_text(encoding="utf-8")
        d = parse_toml(text)
    except (ValueError, UnicodeDecodeError) as exc:
        raise InputFileError(f"{path}: invalid TOML ({exc})") from None
    try:
        return parse_study(d, base_dir=base_dir or path.parent, source=str(path), text=text)
    except ClnlosError as exc:  # the same error, its message led by the file's name
        exc.args = (f"{path}: {exc.args[0] if exc.args else exc}",)
        raise
