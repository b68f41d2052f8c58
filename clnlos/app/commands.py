"""Sub-commands of the clnlos CLI beyond ``devices``: each one parses, checks its inputs, its
output paths and its optional dependencies before any work, calls one library function, and
prints what it wrote."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from clnlos.app.flags import DTYPES, add_force, add_precision, add_slab_flags
from clnlos.app.reconstruct import reconstruct_to_files
from clnlos.app.simulate import figure_path, simulate_to_file
from clnlos.config import (
    DEPTH_GUARD_M,
    FIELD_FLAGS,
    SLAB_MODELS,
    SNR_RULES,
    ReconstructionConfig,
    check_geometry,
    check_window,
    drop_other_methods_settings,
    load_toml,
    slab_from_table,
    slab_table,
)
from clnlos.config import ReconstructionConfig as C
from clnlos.errors import ParameterError
from clnlos.forward.scene import Scene
from clnlos.inverse.methods import METHODS as METHOD_ENTRIES
from clnlos.inverse.methods import default_falloffs, method_names
from clnlos.inverse.preprocessing import device_bytes_needed
from clnlos.inverse.reproducibility import kappa_min
from clnlos.inverse.reproducibility import LIGHTCONE_SNRS as RP_LC
from clnlos.inverse.reproducibility import SLAB_SNRS as RP_SLAB
from clnlos.inverse.reproducibility import SLAB_SNRS_SLAB_ONLY as RP_SLAB_ONLY
from clnlos.io.figures import volume_figure
from clnlos.io.files import read_capture, read_volume, save_figure
from clnlos.io.outputs import HDF5_SUFFIXES, check_outputs
from clnlos.inverse.brdf_choice import LOBE_SEARCH_BINS, LOBE_SEARCH_POINTS
from clnlos.physics.lobe import INVERSION_LOBE_TOLERANCE
from clnlos.runtime.device import get_queue
from clnlos.runtime.limits import capture_use, check_memory


# ------------------------------------------------------------------ reconstruct
# CLI flag -> ReconstructionConfig field (error messages name the flag the user typed)
RECON_FLAGS = {flag[2:].replace("-", "_"): (field, flag) for field, flag in FIELD_FLAGS.items()}


def _decades(values) -> str:
    """'1e2-1e7' for a range of powers of ten (the help texts' grids)."""
    return "-".join(f"1e{round(math.log10(v))}" for v in (values[0], values[-1]))


SLAB_FLAGS = {"slab_thickness": ("thickness_m", "--slab-thickness"), "mu_a": ("mu_a", "--mu-a"),
              "mu_s_prime": ("mu_s_prime", "--mu-s-prime"), "n": ("n", "--n")}


def number_or_auto(text: str):
    """argparse type: "auto" or a float (validated later with the flag's name)."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number or 'auto', got {text!r}") from None


def int_or_auto(text: str):
    """argparse type: "auto" or an integer (validated later with the flag's name)."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer or 'auto', got {text!r}") from None


def flag_names(args) -> dict[str, str]:
    """Config field -> the flag the user typed, for the flags given (error messages)."""
    return {field: flag for dest, (field, flag) in RECON_FLAGS.items()
            if getattr(args, dest, None) is not None}


def config_from_args(args) -> ReconstructionConfig:
    """The reconstruction config: TOML file (if any), overridden by flags; validated with
    the flags' names in error messages (:func:`clnlos.api.reconstruction_config`). Without
    slab flags, --no-slab or a [slab] in the config, :func:`clnlos.api.reconstruct` takes the
    slab a clnlos capture recorded."""
    table = load_toml(args.config) if args.config else {}
    cfg = ReconstructionConfig.from_dict(table)
    # what the user set (TOML keys, then flags): a field the method does not read is refused
    names = {**ReconstructionConfig.given_fields(table), **flag_names(args)}
    changes = {field: getattr(args, dest) for dest, (field, _) in RECON_FLAGS.items()
               if getattr(args, dest, None) is not None}
    slab_given = {k: getattr(args, dest) for dest, (k, _) in SLAB_FLAGS.items()
                  if getattr(args, dest) is not None}
    if args.no_slab:
        changes["slab"] = None
    elif slab_given:
        base = {} if cfg.slab is None else slab_table(cfg.slab)
        base.update(slab_given)
        changes["slab"], _ = slab_from_table(
            base, names={k: flag for k, flag in SLAB_FLAGS.values()})
    cfg = cfg.replace(**changes)
    if args.method is not None:  # the file's settings for its own method: unused, noted
        file_fields = {f: n for f, n in ReconstructionConfig.given_fields(table).items()
                       if f not in changes}
        cfg, unused, notes = drop_other_methods_settings(cfg, file_fields,
                                                         f"--method {args.method}")
        names = {f: n for f, n in names.items() if f not in unused}
        for note in notes:
            print(f"clnlos: note: {note}", file=sys.stderr)
    return cfg.validate(names)


def _pipeline_fits(capture, cfg, queue, dtype, names=None):
    """The check a capture reader runs with the declared size (:func:`clnlos.runtime.limits.
    capture_use`): the time window the reconstruction keeps (:func:`clnlos.config.
    check_window`: a start far past zero is named as such, on any device), then the
    reconstruction's device buffers fit the device (a time axis the file does not store, or
    stores as no valid number, is left to the later checks)."""
    def check(shape, bin_width_s, start_s):
        bw = cfg.bin_width_s if cfg.bin_width_s is not None else bin_width_s
        start = cfg.start_s if cfg.start_s is not None else start_s
        try:  # values outside the range table are named by the reader, not sized here
            check_geometry("bin_width_s", bw)
            check_geometry("start_s", start)
        except ParameterError:
            return
        check_window(shape[0], bw, start, cfg, names=names, source=str(capture))
        try:
            total, largest = device_bytes_needed(shape, bin_width_s=bw, start_s=start,
                                                 config=cfg, dtype=dtype)
        except ParameterError:  # a window that keeps nothing: reported with the capture read
            return
        check_memory(f"reconstructing {capture} (transient {' x '.join(map(str, shape))} "
                     "[t, y, x])", device=queue.device, device_total=total,
                     device_buffer=largest)

    return check


def cmd_reconstruct(args) -> int:
    out = Path(args.output)
    cfg = config_from_args(args)  # parameter errors before reading anything
    check_outputs({"-o": out, "figure": out.with_suffix(".png")},
                  inputs=[args.capture, args.config], suffixes={"-o": HDF5_SUFFIXES},
                  implied={"figure": None}, force=args.force)
    queue = get_queue(args.device, settings=args.settings)
    names = flag_names(args)
    with capture_use(_pipeline_fits(args.capture, cfg, queue, DTYPES[args.dtype], names)):
        # the pipeline's size checked before the data
        capture = read_capture(args.capture, axes=cfg.axes)
    rec = reconstruct_to_files(capture, out, cfg, dtype=DTYPES[args.dtype], queue=queue,
                               no_slab=args.no_slab, names=names,
                               log=lambda note: print(f"clnlos: note: {note}",
                                                      file=sys.stderr))
    for note in rec.notes:
        print(f"clnlos: note: {note}", file=sys.stderr)
    total = sum(rec.timings_s.values())
    print(f"wrote {out} volume {rec.volume.shape} [z, y, x], depth 0-"
          f"{rec.extents['depth_max_m']:.3f} m; stages {', '.join(rec.stages)}; "
          f"{total:.3f} s on {queue.device.name.strip()}")
    print(f"wrote {out.with_suffix('.png')}")
    return 0


def reconstruct_arguments(r, add_device) -> None:
    """The arguments of ``clnlos reconstruct`` on the parser ``r``."""
    r.add_argument("capture", help="capture: clnlos or y-tal HDF5, MATLAB .mat (CDT, LCT, "
                                   "f-k layouts), NumPy .npy [t, y, x]")
    r.add_argument("-o", "--output", required=True,
                   help="output volume (.h5; a PNG is written beside)")
    r.add_argument("--config", help="reconstruction parameters (TOML, see clnlos/config.py); "
                   "flags override its values (default: none, the built-in defaults)")
    r.add_argument("--method", choices=list(method_names()), default=None,
                   help="inversion: " + "; ".join(f"{m} ({e.summary})"
                                                  for m, e in METHOD_ENTRIES.items())
                        + f" (default: the config's [inversion] method, else {C.method}); "
                          "lct and fk invert Lambertian voxels facing the scan plane, "
                          "iterative also any reflectance (--brdf)")
    from_file = "(default: from the capture file, else the config's [capture])"
    r.add_argument("--scan-width", type=float,
                   help="side of the scanned area along x (m; the pitch is this over the "
                        f"columns, the same along y) {from_file}")
    r.add_argument("--bin-width", type=float, help=f"histogram bin width (s) {from_file}")
    r.add_argument("--axes",
                   help="the stored axes in order for a file that records no layout (.npy, "
                        ".mat, HDF5 of other tools): t, y, x each once, comma-separated, a "
                        "leading minus for a reversed axis, e.g. t,y,x, x,y,t or t,-y,x "
                        "(the order numpy gives; MATLAB's for a .mat) (default: the layout's "
                        "own, else assumed from the shape; a note names it)")
    r.add_argument("--allow-implausible", action="store_true", default=None,
                   help="accept a scan width, bin width, start or depth no NLOS capture can "
                        "have (most likely a unit slip: refused by default, before any work)")
    r.add_argument("--direct-cut", type=float,
                   help="zero the window before this round-trip time (s): the direct "
                        "reflection off the relay wall; 0 keeps everything (default: what "
                        "the capture records: the LCT release's first 2.4 ns, as the "
                        "published code; none elsewhere)")
    r.add_argument("--snr", type=number_or_auto,
                   help="Wiener SNR of the slab deconvolution (dimensionless), or auto: chosen "
                        "from the capture by --snr-rule (generalised cross-validation, at most "
                        f"the slab model's accuracy, unless a split search applies) (default "
                        f"{C.snr})")
    r.add_argument("--snr-rule", choices=SNR_RULES,
                   help="how auto SNRs are chosen: gcv (generalised cross-validation "
                        "of the slab stage), thinning (iterative only: GCV's pick, or a "
                        "deeper one where a reconstruction of half the photons, split "
                        "binomially, predicts the other half significantly better; 2-3 "
                        "extra reconstructions of half the data), reproducibility (lct and "
                        "fk only: the least regularised slab and light-cone SNRs, "
                        f"{_decades(RP_SLAB)} x {_decades(RP_LC)} (fk: the slab SNR, "
                        f"{_decades(RP_SLAB_ONLY)}), whose "
                        "two halves of the photons give thresholded images that agree, "
                        f"Cohen's kappa >= {kappa_min(True):g} (fk: "
                        f">= {kappa_min(False):g}); up to "
                        f"{2 * len(RP_SLAB) * len(RP_LC)} (fk {2 * len(RP_SLAB_ONLY)}) extra "
                        "reconstructions of half the data), or auto: reproducibility for lct "
                        "and fk on photon counts the slab model fits exactly (a capture "
                        "simulated with this slab), gcv elsewhere and for the iterative "
                        "method "
                        f"(default {C.snr_rule})")
    r.add_argument("--inversion-snr", type=number_or_auto,
                   help="Wiener SNR of the LCT filter (and of the iterative warm start), or "
                        "auto: with the slab SNR where --snr-rule reproducibility searches "
                        "both, else chosen on the deconvolved transient, for photon counts by "
                        "the unbiased predictive risk with the capture's own noise, otherwise "
                        f"by generalised cross-validation (default {C.inversion_snr})")
    r.add_argument("--falloff", type=float,
                   help="radiometric exponent p (dimensionless) of the (t/T)^p weighting "
                        "before the inversion (default: the method's own, " + ", ".join(
                            f"{m} {p:g}" for m, p in default_falloffs().items()) + "; "
                        + ", ".join(m for m in method_names() if m not in default_falloffs())
                        + ": its voxels' radial falloff 1/r^p in the model, default 4, "
                        "Lambertian; 2 a retroreflector)")
    r.add_argument("--max-path", type=float,
                   help="keep round-trip path lengths c t below this (m) (default: the "
                        "capture's whole time window)")
    r.add_argument("--bins", type=int, help="rebin the kept window to this many bins, "
                   "mass-conserving (default: keep the capture's bin width)")
    r.add_argument("--iterations", type=int,
                   help=f"iterative: iterations at most (default {C.iterations})")
    r.add_argument("--tv-weight", type=float,
                   help="iterative: total-variation weight, relative to max(L^T I) "
                        f"(default {C.tv_weight:g})")
    r.add_argument("--l1-weight", type=number_or_auto,
                   help="iterative: L1 (sparsity) weight, relative to max(L^T I), or auto: "
                        "twice max(L^T n) of the capture's own noise n "
                        f"(default {C.l1_weight})")
    r.add_argument("--depth-min", type=number_or_auto,
                   help="iterative: shallowest depth of the volume (m), or auto: the "
                        f"capture's first arrival less {DEPTH_GUARD_M:g} m "
                        f"(default {C.depth_min_m})")
    r.add_argument("--slab-model", choices=SLAB_MODELS,
                   help="iterative: influence fits (Wiener filter o slab blur) o light cone "
                        "to the deconvolved transient, modelling the smoothing the slab "
                        "deconvolution leaves; none fits the light cone alone (Wiener first) "
                        f"(default {C.slab_model})")
    r.add_argument("--brdf",
                   help="the voxels' reflectance. lct, fk: lambertian (their falloff) or "
                        "retroreflective (falloff 2, the published variant). iterative: "
                        "lambertian, a material name ("
                        "clnlos brdf presets: the seed's ten, the analytic ones and "
                        "retroreflective: the cone's falloff and acceptance), a BRDF "
                        "texture or fitted model .h5 (its retro lobe, averaged over each "
                        "voxel's cell and over the slab's footprint), or auto: the lobe "
                        "among a ladder from Lambertian to a 0.4 deg mirror, and the "
                        "retroreflective one, whose reconstruction from half the photons best "
                        "predicts the other half (3-6 reconstructions of half the data on at "
                        f"most {LOBE_SEARCH_POINTS} x {LOBE_SEARCH_POINTS} scan points and "
                        f"{LOBE_SEARCH_BINS} bins) (default {C.brdf})")
    r.add_argument("--brdf-terms", type=int_or_auto,
                   help="iterative: separable terms K of the lobe (each one more transform "
                        "along t per operator apply), or auto: the fewest within a weighted "
                        f"relative error of {INVERSION_LOBE_TOLERANCE:g} (default "
                        f"{C.brdf_terms})")
    add_slab_flags(r, "(default: the config's [slab]; with no slab flag and no [slab], the "
                      "slab a clnlos capture recorded)",
                   "skip the slab deconvolution (also of a slab the capture recorded)")
    add_force(r)
    add_precision(r)
    add_device(r)
    r.set_defaults(func=cmd_reconstruct)


# ------------------------------------------------------------------ plot
def plot_title(path, attrs) -> str:
    """The figure title of a volume file: its name and the method that made it (its params,
    as ``clnlos reconstruct`` titles its own figure)."""
    try:
        method = json.loads(attrs.get("params", "{}")).get("method")
    except (TypeError, ValueError):
        method = None
    return f"{Path(path).name}" + (f" ({method})" if isinstance(method, str) else "")


def cmd_plot(args) -> int:
    out = Path(args.output) if args.output else Path(args.volume).with_suffix(".png")
    check_outputs({"-o": out}, inputs=[args.volume], suffixes={"-o": (".png",)},
                  implied={} if args.output else {"-o": None}, force=args.force)
    if args.gamma is not None and not (np.isfinite(args.gamma) and 0 < args.gamma <= 10):
        raise ParameterError("--gamma", args.gamma, "a number > 0 and <= 10")
    volume, extents, attrs = read_volume(args.volume)
    save_figure(volume_figure(volume, extents, plot_title(args.volume, attrs),
                              gamma=args.gamma, log=args.log), out)
    print(f"wrote {out}")
    return 0


def plot_arguments(p, add_device) -> None:
    """The arguments of ``clnlos plot`` on the parser ``p`` (no device: no kernels)."""
    p.add_argument("volume", help="volume HDF5 written by clnlos reconstruct")
    p.add_argument("-o", "--output", help="PNG (default: beside the volume)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--gamma", type=float, help="display (value / max)^gamma, e.g. 0.5 to "
                   "lift faint parts (default: linear)")
    g.add_argument("--log", action="store_true", help="display log10(value / max)")
    add_force(p)
    p.set_defaults(func=cmd_plot)


# ------------------------------------------------------------------ simulate
def cmd_simulate(args) -> int:
    out = Path(args.output)
    scene = Scene.from_toml(args.scene)
    check_outputs({"-o": out, "figure": figure_path(out)},
                  inputs=[args.scene, *scene.input_paths()], suffixes={"-o": HDF5_SUFFIXES},
                  implied={"figure": None}, force=args.force)
    queue = get_queue(args.device, settings=args.settings)
    sim = simulate_to_file(scene, out, fmt=args.format, dtype=DTYPES[args.dtype], queue=queue,
                           allow_implausible=args.allow_implausible)
    print(f"wrote {out} ({args.format}) transient {sim.transient.shape} [t, y, x]; stages "
          f"{', '.join(sim.stages)}; {sim.seconds:.2f} s on {queue.device.name.strip()}")
    print(f"wrote {sim.figure}")
    return 0


def simulate_arguments(s, add_device) -> None:
    """The arguments of ``clnlos simulate`` on the parser ``s``."""
    s.add_argument("scene", help="scene description (TOML)")
    s.add_argument("-o", "--output", required=True,
                   help="output capture (.h5; a PNG is written beside)")
    s.add_argument("--format", choices=["clnlos", "tal"], default="clnlos",
                   help="capture format: clnlos (clnlos HDF5) or tal (y-tal HDF5) "
                        "(default %(default)s)")
    s.add_argument("--allow-implausible", action="store_true",
                   help="accept a scan width, bin width, pulse, start or time window no NLOS "
                        "capture can have (most likely a unit slip: refused by default, "
                        "before any work)")
    add_force(s)
    add_precision(s)
    add_device(s)
    s.set_defaults(func=cmd_simulate)
