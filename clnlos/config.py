"""Typed, validated configuration loaded from TOML (every error names field, value and range).

Reconstruction parameters (``clnlos reconstruct --config PARAMS.toml``); every key is
optional and its default is the field default of :class:`ReconstructionConfig`::

    [capture]                    # geometry not stored in the capture file (CDT .mat)
    scan_width_m = 0.7           # side of the scanned area along x (pitch x columns)
    bin_width_s = 16e-12         # overrides the file
    start_s = 0.0                # time of the start of bin 0
    axes = "t,y,x"               # the stored array's axes in order, for a file that records
                                 # no layout (.npy, .mat, HDF5 of other tools): t, y, x each
                                 # once, a leading minus for a reversed axis (clnlos.io.layout;
                                 # default: the layout's own or, for an unknown one, assumed
                                 # from the shape, with a note)
    allow_implausible = false    # accept a value no NLOS capture can have (a unit slip?:
                                 # clnlos.checks.PLAUSIBLE) instead of stopping
    direct_cut_s = 2.4e-9        # zero the window before this time (round trip, s): the
                                 # direct reflection off the relay wall; default: what the
                                 # capture records (the LCT release: the published 600 bins
                                 # of 4 ps), 0 keeps everything
    [preprocess]
    max_path_m = 2.0             # keep round-trip path lengths c t below this
    bins = 128                   # rebin the kept window to this many bins (mass-conserving)
    normalize = "max"            # "max", "sum" or "none"
    [slab]                       # absent = plain NLOS (no deconvolution)
    thickness_m = 0.0254
    mu_a = 0.53
    mu_s_prime = 262.0
    n = 1.12
    ze_m = 0.0036                # optional
    n_dipoles = 20               # optional (default: auto)
    [deconvolution]
    snr = "auto"                 # Wiener SNR of the slab deconvolution, or "auto": chosen
                                 # from the capture by snr_rule (below), with model_snr
    snr_rule = "auto"            # how "auto" picks it, on photon counts the slab model
                                 # fits exactly: for LCT and f-k "reproducibility" (the
                                 # least regularised slab and light-cone SNRs whose two
                                 # halves of the photons give agreeing thresholded images,
                                 # clnlos.inverse.reproducibility; up to 18 half
                                 # reconstructions more, f-k 8); "gcv" (cross-validation
                                 # of the slab stage alone) elsewhere; or any by name:
                                 # "thinning" for the iterative method with the slab's
                                 # influence in its model (GCV's pick or a deeper one,
                                 # whichever reconstruction of half the photons best
                                 # predicts the other half, clnlos.inverse.thinning; 2-3
                                 # reconstructions of half the data more)
    model_snr = "auto"           # accuracy of the slab model as an SNR; "auto": exact for a
                                 # capture clnlos simulated with this slab, else
                                 # clnlos.inverse.snr.MEASURED_MODEL_SNR
    guard_fraction = 0.25        # deconvolve this much more of the capture past max_path_m
                                 # (where it has it), then drop it: keeps edge effects out
    lateral_pad = "mirror"       # "mirror" (even extension across the scan border) or "zero"
    [inversion]
    method = "lct"               # a registered method: "lct", "fk" or "iterative"
    snr = "auto"                 # Wiener SNR of the LCT light-cone filter (and of the
                                 # iterative method's LCT warm start); "auto": with the slab
                                 # SNR where [deconvolution] snr_rule searches both (LCT),
                                 # else from the deconvolved transient by UPRE or cross-
                                 # validation (clnlos.inverse.gcv)
    falloff = 4.0                # radiometric exponent p (default: LCT 4, f-k 2; iterative:
                                 # its voxels' falloff 1/r^p, 4 Lambertian)
    iterations = 200             # iterative: FISTA iterations at most (the solver stops
                                 # earlier where the objective stops falling,
                                 # clnlos.inverse.solvers)
    l1_weight = "auto"           # iterative: L1 weight relative to max(L^T I), or "auto":
                                 # twice max(L^T n), n the capture's own noise
    tv_weight = 0.0              # iterative: TV weight relative to max(L^T I)
    depth_min_m = "auto"         # iterative: shallowest depth of the support, or "auto"
                                 # (the capture's first arrival minus DEPTH_GUARD_M)
    slab_model = "influence"     # iterative: "influence" fits Phi o L to the deconvolved
                                 # transient (Phi the slab Wiener filter's own smoothing,
                                 # clnlos.inverse.iterative), "none" fits L (Wiener first)
    brdf = "lambertian"          # iterative: the voxels' reflectance: "lambertian", a
                                 # material name, a BRDF texture or fitted model .h5, or
                                 # "auto" (the lobe chosen from the capture by held-out
                                 # photons, clnlos.inverse.brdf_choice; it tries the
                                 # "retroreflective" lobe too); LCT and f-k: "lambertian"
                                 # (their falloff) or "retroreflective" (falloff 2, the
                                 # published variant; an explicit falloff wins)
    brdf_terms = "auto"          # iterative: separable terms K of the lobe, or "auto" (the
                                 # fewest within clnlos.physics.lobe.
                                 # INVERSION_LOBE_TOLERANCE)

A field that only some methods read (clnlos.inverse.methods.MethodEntry.reads: falloff for
lct, fk and iterative, [inversion] snr for lct and iterative, iterations, l1_weight, tv_weight,
depth_min_m, slab_model and brdf_terms for iterative; brdf for iterative, and for lct and fk
its "lambertian" and "retroreflective") is refused when the user sets it
-- as a key of the TOML or as a flag -- for a method that does not read it; where a flag
(``--method``) or keyword (``method=``) changes the method over a TOML written for another,
the TOML's settings for its own method are left unused instead, with a note
(:func:`drop_other_methods_settings`).
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import asdict, dataclass

import numpy as np

from clnlos.brdf.catalog import LAMBERTIAN, check_brdf_spec
from clnlos.checks import (  # noqa: F401 (the capture checks: read from here too)
    ALLOW_IMPLAUSIBLE,
    GEOMETRY_LIMITS,
    PLAUSIBLE,
    auto_or_positive,
    check_geometry,
    check_keys,
    choice,
    did_you_mean,
    input_file,
    integer,
    parse_toml,
    plausibility,
    positive,
    real,
    shown_quantity,
)
from clnlos.errors import ImplausibleValueError, InputFileError, ParameterError
from clnlos.io.layout import parse_axes
from clnlos.physics.constants import C0
from clnlos.physics.lobe import MAX_TERMS
from clnlos.physics.slab import SLAB_KEYS, Slab, slab_from_table, slab_table  # noqa: F401


# ------------------------------------------------------------------ the methods
@dataclass(frozen=True)
class MethodEntry:
    """A registered method: where its class lives, its default radiometric falloff (the
    power of 1/r applied per bin before the inversion; None: the method has its own model),
    a one-line summary for the CLI help, the split search that can choose its SNRs on
    photon counts its slab model fits exactly (``split_rule``): "thinning" (a forward model
    scores held-out photons, :mod:`clnlos.inverse.thinning`) or "reproducibility" (the
    halves' thresholded images must agree, :mod:`clnlos.inverse.reproducibility`), and
    what ``snr_rule = "auto"`` stands for there (``auto_snr_rule``: that search, or "gcv"
    where the search does not earn its cost: the iterative method, whose thinning search
    costs 2-3 more reconstructions for +0.001 mean IoU on the oracle table,
    :mod:`clnlos.inverse.thinning`)."""

    module: str
    cls: str
    falloff: float | None
    summary: str
    split_rule: str = "reproducibility"  # a method without a forward model has only this
    auto_snr_rule: str = "gcv"
    # the config fields of the inversion that only some methods read which this one reads
    # (a user who sets one for a method that does not read it is told so: clnlos.config)
    reads: tuple[str, ...] = ()
    # where ``bins`` is not set, a capture of photon counts longer than this many bins has its
    # bins summed in pairs while the frequency band a sum removes holds only noise
    # (clnlos.inverse.preprocessing.bandwidth_bins: the method's cost is per bin; a note says
    # so); None: every bin kept
    sum_bins_above: int | None = None

    def __post_init__(self):
        if self.split_rule not in ("thinning", "reproducibility"):
            raise ValueError(f"split_rule {self.split_rule!r}: \"thinning\" or "
                             "\"reproducibility\"")
        if self.auto_snr_rule not in ("gcv", self.split_rule):
            raise ValueError(f"auto_snr_rule {self.auto_snr_rule!r}: \"gcv\" or "
                             f"{self.split_rule!r}")


# the iterative method's time grid: a capture of more bins is summed in pairs while the band
# each sum removes holds only photon noise (down to this many at most; each iteration costs
# light-cone FFTs on a grid twice the bins deep: a 64 x 64 x 2048 capture took minutes), the
# published LCT code's 512 bins of the 2048-bin captures of O'Toole et al.
ITERATIVE_SUM_BINS_ABOVE = 512

METHODS: dict[str, MethodEntry] = {
    "lct": MethodEntry("clnlos.inverse.lct", "LCTMethod", 4.0,
                       "light-cone transform with a Wiener filter (O'Toole et al. 2018)",
                       "reproducibility", "reproducibility",
                       ("falloff", "inversion_snr", "brdf")),
    "fk": MethodEntry("clnlos.inverse.fk", "FKMethod", 2.0,
                      "f-k (Stolt) migration (Lindell et al. 2019)", "reproducibility",
                      "reproducibility", ("falloff", "brdf")),
    "iterative": MethodEntry("clnlos.inverse.iterative", "IterativeMethod", None,
                             "FISTA on the light-cone transport, L1 + TV, warm-started by "
                             "LCT", "thinning", "gcv",
                             ("inversion_snr", "iterations", "l1_weight", "tv_weight",
                              "depth_min_m", "slab_model", "brdf", "brdf_terms", "falloff"),
                             ITERATIVE_SUM_BINS_ABOVE),
}

# LCT's and f-k's retroreflective variant (O'Toole et al. 2018, cnlos_reconstruction.m
# ``isdiffuse = 0``): the radiometric exponent of a retroreflector whose cone the scanned spot
# holds (1/r^2; clnlos.physics.retroreflector); ``brdf = "retroreflective"`` asks for it
RETROREFLECTIVE_FALLOFF = 2.0
# the reflectances LCT and f-k take (``brdf``): their falloff is all they model of it
CLOSED_FORM_BRDFS = ("lambertian", "retroreflective")


def method_names() -> tuple[str, ...]:
    return tuple(METHODS)


def auto_snr_rule(name: str) -> str:
    """The rule ``snr_rule = "auto"`` stands for with the registered method ``name`` (on
    photon counts its slab model fits exactly; :class:`MethodEntry`)."""
    return METHODS[name].auto_snr_rule


def methods_reading(field: str) -> tuple[str, ...]:
    """The registered methods that read the method-specific config ``field``
    (:attr:`MethodEntry.reads`; every method when no method lists it: a common field)."""
    listed = tuple(n for n, e in METHODS.items() if field in e.reads)
    if not listed and not any(field in e.reads for e in METHODS.values()):
        return tuple(METHODS)
    return listed


def split_rule(name: str) -> str:
    """The split search valid for the registered method ``name`` (``snr_rule`` by name;
    :class:`MethodEntry`)."""
    return METHODS[name].split_rule


def default_falloffs() -> dict[str, float]:
    """The falloff of each method that has one (``--falloff`` default per method)."""
    return {name: e.falloff for name, e in METHODS.items() if e.falloff is not None}


# falloff = None: the method's own radiometric exponent p of (t/T)^p (its registry entry):
# LCT's suits diffuse (Lambertian) surfaces; for f-k the square root of the weighted
# measurement is the wave. The iterative method models the falloff itself: its Lambertian
# voxels fall off as 1/r^4 unless ``falloff`` sets their exponent (clnlos.forward.transport).
METHOD_FALLOFF = default_falloffs()
# ranges of the inversion parameters: the config and the plans (clnlos.inverse) check these
FALLOFF_RANGE = (0.0, 8.0)        # radiometric exponent p
ITERATIONS_RANGE = (0, 100_000)   # iterative: FISTA iterations
WEIGHT_RANGE = (0.0, 1e3)         # iterative: relative L1 / TV weights, TV depth scale
DEPTH_GUARD_M = 0.15  # "auto" support: first-arrival depth minus this (slab delay + noise)
# how "auto" SNRs are chosen (clnlos.inverse.pipeline; "auto": the method's, MethodEntry)
SNR_RULES = ("auto", "gcv", "thinning", "reproducibility")
SLAB_MODELS = ("influence", "none")  # iterative: how the slab deconvolution enters the model
DIRECT_CUT_RANGE = (0.0, 1e-6)  # direct_cut_s: the window zeroed before this time (s)
MAX_BINS = 1 << 16    # time bins of a reconstructed volume at most (--bins and the window)

def snr_rule_applies(rule: str, method: str) -> bool:
    """Whether ``snr_rule = rule`` is valid for the registered ``method`` ("auto" and "gcv"
    for any; a split search for the methods it can choose the SNRs of, its
    :func:`clnlos.inverse.methods.split_rule`: "thinning" for the iterative method,
    "reproducibility" for the closed forms): where a caller sets one rule for several
    methods (the study), the methods it is not valid for keep their default."""
    if rule in ("auto", "gcv"):
        return True
    return rule == split_rule(method)


# a value the user gives that differs from the one the capture gives by more than this
# (relative) is said to contradict it
CONTRADICTION_RTOL = 1e-3

# config field -> its ``clnlos reconstruct`` flag (the CLI's RECON_FLAGS derive from it)
FIELD_FLAGS: dict[str, str] = {
    "scan_width_m": "--scan-width", "bin_width_s": "--bin-width", "axes": "--axes",
    "allow_implausible": ALLOW_IMPLAUSIBLE,
    "direct_cut_s": "--direct-cut", "snr": "--snr",
    "snr_rule": "--snr-rule", "inversion_snr": "--inversion-snr", "falloff": "--falloff",
    "max_path_m": "--max-path", "bins": "--bins", "method": "--method",
    "iterations": "--iterations", "tv_weight": "--tv-weight", "l1_weight": "--l1-weight",
    "depth_min_m": "--depth-min", "slab_model": "--slab-model", "brdf": "--brdf",
    "brdf_terms": "--brdf-terms"}
# CLI words of the notes and their Python keyword (clnlos.reconstruct's) spelling
FLAG_WORDS_PYTHON = {"--no-slab": "no_slab=True", "--slab-* flags": "slab={...}",
                     ALLOW_IMPLAUSIBLE: "allow_implausible=True",
                     "[capture] start_s": "start_s="}


def python_keywords(text: str) -> str:
    """A note written with CLI flags (``--max-path 2.26``) as a Python caller of
    :func:`clnlos.reconstruct` spells it (``max_path_m=2.26``)."""
    for word, keyword in FLAG_WORDS_PYTHON.items():
        text = text.replace(word, keyword)
    for field, flag in sorted(FIELD_FLAGS.items(), key=lambda kv: -len(kv[1])):
        text = re.sub(re.escape(flag) + r"(?![\w-])(?: ([^\s,;:()]+))?",
                      lambda m, f=field: f"{f}={m.group(1)}" if m.group(1) else f"{f}=", text)
    return text


def accepted_by(how: str | None, python: bool = False) -> str:
    """How the user accepts an impossible value, spelled as they gave it (``how``: a flag, a
    TOML key or a keyword; None: the capture gave it, ``python`` for a Python caller)."""
    if how is None:
        return "allow_implausible=True" if python else ALLOW_IMPLAUSIBLE
    if how.startswith("--"):
        return ALLOW_IMPLAUSIBLE
    if "." in how:  # a TOML key: the flag or the file's own key
        return f"{ALLOW_IMPLAUSIBLE} or [capture] allow_implausible = true"
    return "allow_implausible=True"


def judged(kind: str, value: float, head: str, subject: str, *, allow: bool, accept: str
           ) -> str | None:
    """The line the plausibility rule (:func:`clnlos.checks.plausibility`) says of a value:
    None where usual, a warning line where unusual or impossible and accepted (``allow``),
    else an ImplausibleValueError naming ``head`` (how it was given), ``subject`` (what it
    means) and ``accept`` (how to accept it)."""
    level, clause = plausibility(kind, value)
    if level == "usual":
        return None
    line = f"{head}: {subject}, {clause}"
    if level == "impossible":
        if not allow:
            raise ImplausibleValueError(head, value, line, accept)
        return f"{line} (accepted: {accept})"
    return line


def window_depth_m(nt: int, bin_width_s: float, start_s: float) -> float:
    """Where a time window of ``nt`` bins of ``bin_width_s`` from ``start_s`` ends, as a depth
    behind the scan plane: c (start + nt dt) / 2 (m)."""
    return C0 * (start_s + nt * bin_width_s) / 2


def plausibility_warnings(*, nt: int, bin_width_s: float, start_s: float, scan_width_m: float,
                          recorded: dict, given: dict[str, str], allow: bool = False,
                          python: bool = False) -> list[str]:
    """The plausibility rule (:data:`clnlos.checks.PLAUSIBLE`) on the geometry a
    reconstruction resolved: the scan width, the bin width, the start and the depth the time
    window of ``nt`` bins reaches; one line each for unusual values and for values the user
    gave (``given``: field -> how, a flag, a TOML key or a keyword) that contradict the value
    the capture gives (``recorded``: field -> value or None). A value no NLOS capture can have
    is an ImplausibleValueError naming how it was given (or the capture), unless ``allow``
    (then a warning line); ``python``: the capture's values are accepted by keyword."""
    out = []
    units = {"scan_width_m": lambda v: f"{v:g} m", "bin_width_s": lambda v:
             shown_quantity(v, "s"), "start_s": lambda v: shown_quantity(v, "s")}

    def said(field, value):
        rec = recorded.get(field)
        how = given.get(field)
        head = spelled(how, value) if how else f"{field} = {value:g} (from the capture)"
        tail = (f"; the capture gives {units[field](rec)}" if how and rec is not None
                else "")
        return head, tail, accepted_by(how, python)

    depth = window_depth_m(nt, bin_width_s, start_s)
    window_field = "bin_width_s" if "bin_width_s" in given or "start_s" not in given \
        else "start_s"
    checks = (("scan_width_m", "scan_width_m", scan_width_m,
               f"a scan {scan_width_m:g} m wide"),
              ("time_step_s", "bin_width_s", bin_width_s,
               f"a bin of {shown_quantity(bin_width_s, 's')}"),
              ("depth_m", "start_s", C0 * start_s / 2,
               f"the window starts {C0 * start_s / 2:.4g} m deep"),
              ("depth_m", window_field, depth,
               f"the time window ({nt} bins) reaches {depth:.4g} m deep"))
    for kind, field, value, subject in checks:
        head, tail, accept = said(field, bin_width_s if field == "bin_width_s" else
                                  start_s if field == "start_s" else value)
        line = judged(kind, value, head, subject, allow=allow, accept=accept)
        if line is not None and not any(o.startswith(head) for o in out):
            out.append(line + tail)
    for field, value in (("scan_width_m", scan_width_m), ("bin_width_s", bin_width_s),
                         ("start_s", start_s)):
        rec, how = recorded.get(field), given.get(field)
        if how is None or rec is None or any(line.startswith(spelled(how, value))
                                             for line in out):
            continue
        if not math.isclose(value, rec, rel_tol=CONTRADICTION_RTOL,
                            abs_tol=1e-15 if field == "start_s" else 0.0):
            out.append(f"{spelled(how, value)} contradicts the {units[field](rec)} the "
                       "capture gives (the value given is used)")
    return out


def scene_plausibility(*, width_m: float, bin_width_s: float, bins: int, start_s: float,
                       pulse_width_s: float | None, allow: bool = False,
                       accept: str = ALLOW_IMPLAUSIBLE) -> list[str]:
    """The plausibility rule (:data:`clnlos.checks.PLAUSIBLE`) on a scene's capture geometry
    (its TOML keys): the scan width, the bin width, the laser pulse, the start and the depth
    its window reaches. One warning line per unusual value; a value no NLOS capture can have
    is an ImplausibleValueError naming the key, unless ``allow`` (``accept`` says how)."""
    depth = window_depth_m(bins, bin_width_s, start_s)
    checks = [("scan_width_m", "scan.width_m", width_m, width_m, f"a scan {width_m:g} m wide"),
              ("time_step_s", "time.bin_width_s", bin_width_s, bin_width_s,
               f"a bin of {shown_quantity(bin_width_s, 's')}"),
              ("depth_m", "time.start_s", start_s, C0 * start_s / 2,
               f"the window starts {C0 * start_s / 2:.4g} m deep"),
              ("depth_m", "time.bin_width_s", bin_width_s, depth,
               f"the time window ({bins} bins) reaches {depth:.4g} m deep")]
    if pulse_width_s is not None:
        checks.append(("time_step_s", "laser.pulse_width_s", pulse_width_s, pulse_width_s,
                       f"a pulse of {shown_quantity(pulse_width_s, 's')}"))
    out: list[str] = []
    for kind, key, given, value, subject in checks:
        head = spelled(key, given)
        line = judged(kind, value, head, subject, allow=allow, accept=accept)
        if line is not None and not any(o.startswith(head) for o in out):
            out.append(line)
    return out


def check_given_plausible(config: ReconstructionConfig, names: dict[str, str]) -> None:
    """The values a config sets that no NLOS capture can have (the plausibility rule, each on
    its own: scan width, bin width, start, max_path_m / 2 and depth_min_m as depths) are an
    ImplausibleValueError naming how they were given, before any capture is read, unless
    ``allow_implausible``."""
    def nm(f):
        return names.get(f, FIELD_NAMES.get(f, f))

    items = (("scan_width_m", "scan_width_m", lambda v: v, lambda v: f"a scan {v:g} m wide"),
             ("bin_width_s", "time_step_s", lambda v: v,
              lambda v: f"a bin of {shown_quantity(v, 's')}"),
             ("start_s", "depth_m", lambda v: C0 * v / 2,
              lambda v: f"the window starts {C0 * v / 2:.4g} m deep"),
             ("max_path_m", "depth_m", lambda v: v / 2,
              lambda v: f"a path of {v:g} m reaches {v / 2:.4g} m deep"),
             ("depth_min_m", "depth_m", lambda v: v, lambda v: f"a depth of {v:g} m"))
    for field, kind, measure, subject in items:
        v = getattr(config, field)
        if v is None or isinstance(v, str):
            continue
        how = nm(field)
        judged(kind, measure(v), spelled(how, v), subject(v),
               allow=config.allow_implausible, accept=accepted_by(how))


def spelled(how: str, value) -> str:
    """A value as the user gave it: ``--scan-width 60`` (a flag), ``capture.scan_width_m =
    60`` (a TOML key), ``scan_width_m=60`` (a Python keyword)."""
    v = f"{value:g}" if isinstance(value, float | int) else repr(value)
    if how.startswith("--"):
        return f"{how} {v}"
    return f"{how} = {v}" if "." in how else f"{how}={v}"


# TOML (section, key) -> config field; the one table both directions use.
TOML_FIELDS: dict[tuple[str, str], str] = {
    ("capture", "scan_width_m"): "scan_width_m",
    ("capture", "bin_width_s"): "bin_width_s",
    ("capture", "start_s"): "start_s",
    ("capture", "axes"): "axes",
    ("capture", "allow_implausible"): "allow_implausible",
    ("capture", "direct_cut_s"): "direct_cut_s",
    ("preprocess", "max_path_m"): "max_path_m",
    ("preprocess", "bins"): "bins",
    ("preprocess", "normalize"): "normalize",
    ("deconvolution", "snr"): "snr",
    ("deconvolution", "snr_rule"): "snr_rule",
    ("deconvolution", "model_snr"): "model_snr",
    ("deconvolution", "guard_fraction"): "guard_fraction",
    ("deconvolution", "lateral_pad"): "lateral_pad",
    ("inversion", "method"): "method",
    ("inversion", "snr"): "inversion_snr",
    ("inversion", "falloff"): "falloff",
    ("inversion", "iterations"): "iterations",
    ("inversion", "l1_weight"): "l1_weight",
    ("inversion", "tv_weight"): "tv_weight",
    ("inversion", "depth_min_m"): "depth_min_m",
    ("inversion", "slab_model"): "slab_model",
    ("inversion", "brdf"): "brdf",
    ("inversion", "brdf_terms"): "brdf_terms",
}
FIELD_NAMES = {f: f"{sec}.{key}" for (sec, key), f in TOML_FIELDS.items()}


def load_toml(path) -> dict:
    p = input_file(path)
    try:
        return parse_toml(p.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError) as exc:  # TOMLDecodeError is a ValueError
        raise InputFileError(f"{p}: invalid TOML ({exc})") from None


def check_window(nt_in: int, bin_width_s: float, start_s: float, config, *,
                 names: dict[str, str] | None = None, source: str = "the capture") -> None:
    """The time window a reconstruction keeps, checked before any allocation: the capture's
    ``nt_in`` bins of ``bin_width_s`` (s) from ``start_s`` (s) must reach past t = 0 and past
    the start of ``max_path_m``; aligned to t = 0 they need at most MAX_BINS bins (unless
    ``bins`` rebins them); a numeric ``depth_min_m`` lies inside the volume. ``names`` map
    fields to how the user gave them (flags); a value the capture gave is named with
    ``source``."""
    names = names or {}

    def nm(f):
        if getattr(config, f) is None and f in GEOMETRY_LIMITS:
            return f"{f} (from {source})"
        return names.get(f, FIELD_NAMES.get(f, f))

    t_end = start_s + nt_in * bin_width_s
    if t_end <= 0:
        raise ParameterError(nm("start_s"), start_s, f"> {-nt_in * bin_width_s:.4g} s: the "
                             f"window ({nt_in} bins of {bin_width_s:g} s) must end after "
                             "t = 0, where the volume begins")
    if config.max_path_m is not None:
        if config.max_path_m <= C0 * start_s:
            raise ParameterError(nm("max_path_m"), config.max_path_m,
                                 f"> {C0 * start_s:.4g} m, the path where the window begins "
                                 f"(start_s = {start_s:g} s)")
        t_end = min(t_end, config.max_path_m / C0)
    n_keep = max(1, int(round(t_end / bin_width_s)))
    if config.bins is None and n_keep > max(MAX_BINS, nt_in):
        raise ParameterError(nm("start_s"), start_s, f"a start the volume can reach: from "
                             f"t = 0 to the window's end at {t_end:.4g} s it needs {n_keep} "
                             f"bins of {bin_width_s:g} s, at most {MAX_BINS} (rebin with "
                             f"{names.get('bins', FIELD_NAMES['bins'])} or crop with "
                             f"{names.get('max_path_m', FIELD_NAMES['max_path_m'])})")
    depth_max = C0 * n_keep * bin_width_s / 2
    d = config.depth_min_m
    if d != "auto" and d is not None and d >= depth_max:
        raise ParameterError(nm("depth_min_m"), d, f"a depth from 0 to below {depth_max:.4g} "
                             "m, where the volume (its time window) ends")


def check_light_in_window(transient, bin_width_s: float, start_s: float, config, *,
                          names: dict[str, str] | None = None, source: str = "the capture"
                          ) -> None:
    """The capture's light (bins with any count, ``transient`` [t, y, x]) must fall after
    t = 0 and, with ``max_path_m``, start before that path: else the ParameterError names
    the start or the max path that puts all of it outside the kept window (an all-zero
    capture is left to the caller)."""
    names = names or {}
    lit = np.flatnonzero(np.asarray(transient).reshape(len(transient), -1).max(axis=1) > 0)
    if lit.size == 0:
        return
    t_first = start_s + lit[0] * bin_width_s
    t_last = start_s + (lit[-1] + 1) * bin_width_s
    if t_last <= 0:
        name = (names.get("start_s", FIELD_NAMES["start_s"]) if config.start_s is not None
                else f"start_s (from {source})")
        raise ParameterError(name, start_s, f"a start that puts the capture's light after "
                             f"t = 0: it is in bins {lit[0]}-{lit[-1]}, from {t_first:.4g} to "
                             f"{t_last:.4g} s, before the volume begins")
    if config.max_path_m is not None and config.max_path_m <= C0 * t_first:
        raise ParameterError(names.get("max_path_m", FIELD_NAMES["max_path_m"]),
                             config.max_path_m, f"> {C0 * t_first:.4g} m, the shortest path "
                             f"with light in the capture (bin {lit[0]})")


def drop_other_methods_settings(config: ReconstructionConfig, file_fields: dict[str, str],
                                method_said: str
                                ) -> tuple[ReconstructionConfig, dict[str, str], list[str]]:
    """(config, unused, notes) where a method given over a config file (``method_said``: how
    the user set it, ``--method fk`` or ``method='fk'``) does not read some of the file's
    settings (``file_fields``: field -> "section.key" the file set): those (``unused``) go
    back to their defaults, with one note naming them, instead of the error
    :meth:`ReconstructionConfig.validate` gives a setting the user asked for a method that
    does not read it (the file was written for its own method). A ``snr_rule`` the new
    method cannot use goes back to "auto" too, a ``brdf`` LCT and f-k cannot model (other
    than :data:`CLOSED_FORM_BRDFS`) to "lambertian"."""
    method = config.method
    if method not in method_names():
        return config, {}, []  # validate names the unknown method
    unused = {f: sec for f, sec in file_fields.items() if method not in methods_reading(f)}
    if "snr_rule" in file_fields and not snr_rule_applies(str(config.snr_rule), method):
        unused["snr_rule"] = file_fields["snr_rule"]
    if ("brdf" in file_fields and method in ("lct", "fk")
            and str(config.brdf).lower() not in CLOSED_FORM_BRDFS):
        unused["brdf"] = file_fields["brdf"]  # a BRDF only the iterative method models
    if not unused:
        return config, {}, []
    defaults = ReconstructionConfig()

    def shown(v):
        return f"{v:g}" if isinstance(v, float) else repr(v)

    said = ", ".join(f"{sec} = {shown(getattr(config, f))}" for f, sec in unused.items())
    note = (f"{method_said}: the config's {said} left unused (set for another method; "
            f"{method!r} does not read {'it' if len(unused) == 1 else 'them'})")
    return config.replace(**{f: getattr(defaults, f) for f in unused}), unused, [note]


@dataclass(frozen=True)
class ReconstructionConfig:
    """Reconstruction parameters; the field defaults are the defaults (stated once here)."""

    scan_width_m: float | None = None
    bin_width_s: float | None = None
    start_s: float | None = None
    axes: str | None = None
    allow_implausible: bool = False
    direct_cut_s: float | None = None
    max_path_m: float | None = None
    bins: int | None = None
    normalize: str = "max"
    slab: Slab | None = None
    n_dipoles: int | None = None
    snr: float | str = "auto"
    snr_rule: str = "auto"
    model_snr: float | str = "auto"
    guard_fraction: float = 0.25
    lateral_pad: str = "mirror"
    method: str = "lct"
    inversion_snr: float | str = "auto"
    falloff: float | None = None
    iterations: int = 200
    l1_weight: float | str = "auto"
    tv_weight: float = 0.0
    depth_min_m: float | str = "auto"
    slab_model: str = "influence"
    brdf: str = LAMBERTIAN
    brdf_terms: int | str = "auto"
    # the fields the user set (validate's ``names``; not a parameter: defaults that depend on
    # the capture, clnlos.inverse.capture_defaults, leave these alone)
    user_fields: frozenset = dataclasses.field(default=frozenset(), compare=False, repr=False)

    def validate(self, names: dict[str, str] | None = None) -> ReconstructionConfig:
        """A validated copy. ``names`` maps field names to how the user gave them (a CLI
        flag such as ``--scan-width``), for error messages; else the TOML name. With
        ``names`` (the final config: a file's own validation passes none, the flags may still
        accept what it sets) a value no NLOS capture can have is an error unless
        ``allow_implausible`` (:func:`check_given_plausible`)."""
        given = names
        names = names or {}

        def nm(f):
            return names.get(f, FIELD_NAMES.get(f, f))

        v = {}
        for f in GEOMETRY_LIMITS:
            if getattr(self, f) is not None:
                v[f] = check_geometry(f, getattr(self, f), nm(f))
        if self.axes is not None:
            v["axes"] = str(parse_axes(self.axes, nm("axes")))
        if not isinstance(self.allow_implausible, bool):
            raise ParameterError(nm("allow_implausible"), self.allow_implausible,
                                 "true or false")
        if self.direct_cut_s is not None:
            v["direct_cut_s"] = real(nm("direct_cut_s"), self.direct_cut_s, *DIRECT_CUT_RANGE)
        if self.max_path_m is not None:
            v["max_path_m"] = positive(nm("max_path_m"), self.max_path_m, upper=1e4)
        if self.bins is not None:
            v["bins"] = integer(nm("bins"), self.bins, 1, MAX_BINS)
        if self.slab is not None and not isinstance(self.slab, Slab):
            raise ParameterError("slab", self.slab, "a Slab")
        if self.n_dipoles is not None:
            v["n_dipoles"] = integer(nm("n_dipoles"), self.n_dipoles, 0, 10000)
        v["normalize"] = choice(nm("normalize"), self.normalize, ("max", "sum", "none"))
        v["snr"] = auto_or_positive(nm("snr"), self.snr, upper=1e30)
        v["snr_rule"] = choice(nm("snr_rule"), self.snr_rule, SNR_RULES)
        if v["snr_rule"] == "thinning" and (self.method != "iterative"
                                            or self.slab_model != "influence"):
            raise ParameterError(nm("snr_rule"), self.snr_rule,
                                 f"{self._rules_for_method()} (\"thinning\" scores the model "
                                 "the method fits on the held-out photons: method "
                                 "\"iterative\" with slab_model \"influence\")")
        if (v["snr_rule"] == "reproducibility" and self.method in method_names()
                and not snr_rule_applies("reproducibility", self.method)):
            raise ParameterError(nm("snr_rule"), self.snr_rule,
                                 f"{self._rules_for_method()} (\"reproducibility\" chooses "
                                 "the SNRs of the closed-form methods \"lct\" and \"fk\")")
        v["model_snr"] = auto_or_positive(nm("model_snr"), self.model_snr, upper=1e30)
        v["guard_fraction"] = positive(nm("guard_fraction"), self.guard_fraction,
                                       allow_zero=True, upper=4.0)
        v["lateral_pad"] = choice(nm("lateral_pad"), self.lateral_pad, ("mirror", "zero"))
        v["method"] = choice(nm("method"), self.method, method_names())  # the registry now
        v["inversion_snr"] = auto_or_positive(nm("inversion_snr"), self.inversion_snr,
                                              upper=1e30)
        if self.falloff is not None:
            v["falloff"] = real(nm("falloff"), self.falloff, *FALLOFF_RANGE)
        v["iterations"] = integer(nm("iterations"), self.iterations, *ITERATIONS_RANGE)
        v["l1_weight"] = ("auto" if self.l1_weight == "auto"
                          else real(nm("l1_weight"), self.l1_weight, *WEIGHT_RANGE))
        v["tv_weight"] = real(nm("tv_weight"), self.tv_weight, *WEIGHT_RANGE)
        if self.depth_min_m != "auto":
            if isinstance(self.depth_min_m, str):
                raise ParameterError(nm("depth_min_m"), self.depth_min_m,
                                     "\"auto\" or a depth in m from 0 to 1000")
            v["depth_min_m"] = real(nm("depth_min_m"), self.depth_min_m, 0.0, 1e3)
        v["slab_model"] = choice(nm("slab_model"), self.slab_model, SLAB_MODELS)
        v["brdf"] = check_brdf_spec(self.brdf, nm("brdf"))
        if v["brdf"] not in CLOSED_FORM_BRDFS and self.method in ("lct", "fk"):
            raise ParameterError(nm("brdf"), self.brdf, " or ".join(
                f"\"{b}\"" for b in CLOSED_FORM_BRDFS) + f" with method {self.method!r} "
                "(LCT and f-k model a reflectance by their falloff alone: 4 and 2 for "
                "Lambertian, 2 for retroreflective; any other BRDF, and \"auto\", needs "
                "method \"iterative\")")
        v["brdf_terms"] = ("auto" if self.brdf_terms == "auto"
                           else integer(nm("brdf_terms"), self.brdf_terms, 1, MAX_TERMS))
        for field in names:  # what the user set for a method that does not read it
            readers = methods_reading(field)
            if self.method in method_names() and self.method not in readers:
                raise ParameterError(nm(field), getattr(self, field), "only with method "
                                     + " or ".join(f"\"{m}\"" for m in readers)
                                     + f" (method \"{self.method}\" does not use it)")
        out = dataclasses.replace(self, **v, user_fields=self.user_fields | frozenset(names))
        if given is not None:  # the whole config, flags over the file: accepted or not
            check_given_plausible(out, names)
        return out

    def _rules_for_method(self) -> str:
        """The snr_rule values that apply with this config's method, quoted."""
        rules = [r for r in SNR_RULES if r in ("auto", "gcv") or (
            self.method in method_names() and snr_rule_applies(r, self.method)
            and (r != "thinning" or self.slab_model == "influence"))]
        return ", ".join(f"\"{r}\"" for r in rules[:-1]) + f" or \"{rules[-1]}\""

    def replace(self, **changes) -> ReconstructionConfig:
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_toml(cls, path) -> ReconstructionConfig:
        return cls.from_dict(load_toml(path))

    @staticmethod
    def given_fields(d: dict) -> dict[str, str]:
        """Field -> "section.key" for the keys a TOML table (parsed) sets (what the user
        asked for, e.g. for :meth:`validate`'s check of fields a method does not read)."""
        return {TOML_FIELDS[(sec, key)]: f"{sec}.{key}" for sec, table in d.items()
                if isinstance(table, dict) for key in table if (sec, key) in TOML_FIELDS}

    @classmethod
    def from_dict(cls, d: dict) -> ReconstructionConfig:
        sections = {sec for sec, _ in TOML_FIELDS} | {"slab"}
        check_keys("", d, sections)
        kw = {}
        for sec in sections - {"slab"}:
            table = d.get(sec, {})
            if not isinstance(table, dict):
                raise ParameterError(sec, table, "a table")
            check_keys(sec, table, {k for s, k in TOML_FIELDS if s == sec})
            for key, value in table.items():
                kw[TOML_FIELDS[(sec, key)]] = value
        if "slab" in d:
            kw["slab"], kw["n_dipoles"] = slab_from_table(d["slab"])
        cfg = cls(**kw).validate()  # the fields the file set: user_fields (not checked
        return dataclasses.replace(cfg, user_fields=frozenset(cls.given_fields(d)))  # here)

    @property
    def thinning(self) -> bool:
        """Whether the rule for an "auto" slab SNR is thinning (:mod:`clnlos.inverse.thinning`):
        ``snr_rule`` "thinning", or "auto" with a method whose "auto" rule it is
        (:class:`clnlos.inverse.methods.MethodEntry`: none today, the iterative method's is
        GCV) and its slab model "influence" (the model the held-out photons score). Whether
        it then acts depends on the capture as well
        (:meth:`clnlos.inverse.pipeline.ReconstructionPipeline.run`)."""
        if self.snr_rule == "auto":
            return auto_snr_rule(self.method) == "thinning" and self.slab_model == "influence"
        return self.snr_rule == "thinning"

    @property
    def reproducibility(self) -> bool:
        """Whether "auto" SNRs are chosen by split-half reproducibility
        (:mod:`clnlos.inverse.reproducibility`): ``snr_rule`` "reproducibility" (LCT or
        f-k), or "auto" with a method whose rule it is (LCT, f-k). Whether it then acts
        depends on the capture as well
        (:meth:`clnlos.inverse.pipeline.ReconstructionPipeline.run`)."""
        if self.snr_rule == "auto":
            return auto_snr_rule(self.method) == "reproducibility"
        return self.snr_rule == "reproducibility"

    def as_attrs(self) -> dict:
        d = asdict(self)
        d.pop("user_fields")
        d["slab"] = None if self.slab is None else {**asdict(self.slab), "ze_used_m":
                                                    self.slab.ze}
        return d
