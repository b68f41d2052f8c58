"""Sub-commands of the clnlos CLI beyond ``devices``: each one parses, checks its inputs, its
output paths and its optional dependencies before any work, calls one library function, and
prints what it wrote."""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from clnlos.app.demo import demo_files, demo_inputs, run_demo
from clnlos.io.progress import counter, progress_bar
from clnlos.app.reconstruct import reconstruct_to_files
from clnlos.app.simulate import figure_path, simulate_to_file
from clnlos.bench import ONLY_HELP, sections_of
from clnlos.bench import main as bench_main
from clnlos.brdf.data import CSV_COLUMNS
from clnlos.brdf.evaluate import MODELS as EVAL_MODELS
from clnlos.brdf.evaluate import MODES as EVAL_MODES
from clnlos.brdf.evaluate import (
    TRAIN_FRACTION,
    evaluate,
    is_rows_json,
    measured_files,
    summary_table,
    write_rows,
)
from clnlos.brdf.fit import fit_to_file
from clnlos.brdf.models import model_spec
from clnlos.brdf.plot import brdf_figure, read_samples
from clnlos.brdf.store import load_model
from clnlos.brdf.texture import MAX_NODES, MIN_NODES, tabulate, write_texture
from clnlos.checks import integer
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
from clnlos.errors import InputFileError, MissingDependencyError, OutputFileError, ParameterError
from clnlos.forward.scene import Scene
from clnlos.inverse.methods import METHODS as METHOD_ENTRIES
from clnlos.inverse.methods import default_falloffs, method_names
from clnlos.inverse.pipeline import device_bytes_needed
from clnlos.inverse.reproducibility import kappa_min
from clnlos.inverse.reproducibility import LIGHTCONE_SNRS as RP_LC
from clnlos.inverse.reproducibility import SLAB_SNRS as RP_SLAB
from clnlos.inverse.reproducibility import SLAB_SNRS_SLAB_ONLY as RP_SLAB_ONLY
from clnlos.io.figures import volume_figure
from clnlos.io.files import read_capture, read_volume, save_figure
from clnlos.io.outputs import HDF5_SUFFIXES, check_outputs
from clnlos.physics.lobe import LOBE_TOLERANCE
from clnlos.runtime.device import get_queue
from clnlos.runtime.limits import capture_use, check_memory
import clnlos.study as study  # the package (study.run: the function)
from clnlos.study.dataset import MAX_WORKERS, StudyGrid, check_scheduler_address
from clnlos.study.run import (
    LABEL_METRICS,
    TRANSPORT_CHOICES,
    StudyOptions,
)

DTYPES = {"float32": np.float32, "float64": np.float64}

# optional dependencies: import name -> (extra, what needs it)
EXTRAS = {"torch": ("ml", "the torch CPU wheel: pip install torch==2.13.0"),
          "dask": ("study", "dask[distributed]"),
          "distributed": ("study", "dask[distributed]")}


def require(module: str, what: str) -> None:
    """One line naming the extra when an optional dependency is missing."""
    if importlib.util.find_spec(module) is None:
        extra, hint = EXTRAS[module]
        raise MissingDependencyError(
            f"{what} needs {module!r}, which is not installed: pip install 'clnlos[{extra}]' "
            f"({hint})")


def _add_force(p) -> None:
    p.add_argument("--force", action="store_true",
                   help="replace an existing file at a path written beside the output (or "
                        "in the output folder) that clnlos did not write; inputs are never "
                        "replaced")


def _add_precision(p) -> None:
    p.add_argument("--dtype", choices=sorted(DTYPES), default="float32",
                   help="kernel precision (default %(default)s)")


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
        capture = read_capture(args.capture)  # the pipeline's size checked before the data
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


def register_reconstruct(sub, add_device) -> None:
    r = sub.add_parser("reconstruct", help="reconstruct a hidden volume from a capture")
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
                        + " models the falloff itself: not with it)")
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
                        "predicts the other half (3-6 extra reconstructions of half the data) "
                        f"(default {C.brdf})")
    r.add_argument("--brdf-terms", type=int_or_auto,
                   help="iterative: separable terms K of the lobe (each one more FFT per "
                        "operator apply), or auto: the fewest within a relative error of "
                        f"{LOBE_TOLERANCE:g} (default {C.brdf_terms})")
    slab = ("(default: the config's [slab]; with no slab flag and no [slab], the slab a "
            "clnlos capture recorded)")
    r.add_argument("--slab-thickness", type=float, help=f"slab thickness (m) {slab}")
    r.add_argument("--mu-a", type=float, help=f"slab absorption coefficient (1/m) {slab}")
    r.add_argument("--mu-s-prime", type=float,
                   help=f"slab reduced scattering coefficient (1/m) {slab}")
    r.add_argument("--n", type=float, help=f"slab refractive index (relative) {slab}")
    r.add_argument("--no-slab", action="store_true",
                   help="skip the slab deconvolution (also of a slab the capture recorded)")
    _add_force(r)
    _add_precision(r)
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


def register_plot(sub) -> None:
    p = sub.add_parser("plot", help="re-render the figure of a reconstructed volume")
    p.add_argument("volume", help="volume HDF5 written by clnlos reconstruct")
    p.add_argument("-o", "--output", help="PNG (default: beside the volume)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--gamma", type=float, help="display (value / max)^gamma, e.g. 0.5 to "
                   "lift faint parts (default: linear)")
    g.add_argument("--log", action="store_true", help="display log10(value / max)")
    _add_force(p)
    p.set_defaults(func=cmd_plot)


# ------------------------------------------------------------------ simulate, demo
def cmd_simulate(args) -> int:
    out = Path(args.output)
    scene = Scene.from_toml(args.scene)
    check_outputs({"-o": out, "figure": figure_path(out)},
                  inputs=[args.scene, *scene.input_paths()], suffixes={"-o": HDF5_SUFFIXES},
                  implied={"figure": None}, force=args.force)
    queue = get_queue(args.device, settings=args.settings)
    sim = simulate_to_file(scene, out, fmt=args.format, dtype=DTYPES[args.dtype], queue=queue)
    print(f"wrote {out} ({args.format}) transient {sim.transient.shape} [t, y, x]; stages "
          f"{', '.join(sim.stages)}; {sim.seconds:.2f} s on {queue.device.name.strip()}")
    print(f"wrote {sim.figure}")
    return 0


def cmd_demo(args) -> int:
    out = Path(args.output)
    if out.exists() and not out.is_dir():
        raise OutputFileError(f"-o {out}: is a file; the demo writes a folder")
    scene, cfg = demo_inputs(args.scene, args.config)
    outs = {f"-o {name}": out / name for name in demo_files()}
    check_outputs(outs, inputs=[args.scene, args.config, *scene.input_paths()],
                  implied=dict.fromkeys(outs), force=args.force)
    run_demo(out, scene, cfg, queue=get_queue(args.device, settings=args.settings))
    return 0


def register_forward(sub, add_device) -> None:
    s = sub.add_parser("simulate", help="simulate a confocal capture from a scene TOML")
    s.add_argument("scene", help="scene description (TOML)")
    s.add_argument("-o", "--output", required=True,
                   help="output capture (.h5; a PNG is written beside)")
    s.add_argument("--format", choices=["clnlos", "tal"], default="clnlos",
                   help="capture format: clnlos (clnlos HDF5) or tal (y-tal HDF5) "
                        "(default %(default)s)")
    _add_force(s)
    _add_precision(s)
    add_device(s)
    s.set_defaults(func=cmd_simulate)
    d = sub.add_parser("demo", help="simulate 'UT' behind the slab, reconstruct with LCT, f-k "
                                    "and the iterative method, score")
    d.add_argument("-o", "--output", default="out/demo",
                   help="output folder (default %(default)s)")
    d.add_argument("--scene", help="scene TOML with letters as objects[0] (default: built-in)")
    d.add_argument("--config", help="reconstruction TOML (default: built-in; its slab "
                   "defaults to the scene's)")
    _add_force(d)
    add_device(d)
    d.set_defaults(func=cmd_demo)


# ------------------------------------------------------------------ brdf
BRDF_MODELS = ["mlp", "mlp-seed", "five-param", "torrance-sparrow", "phong", "minnaert",
               "lambert"]


def cmd_brdf_fit(args) -> int:
    if args.model in ("mlp", "mlp-seed"):
        require("torch", f"brdf fit --model {args.model}")
    outs = {"-o": Path(args.output)}
    if args.metrics_json:
        outs["--metrics-json"] = Path(args.metrics_json)
    check_outputs(outs, inputs=[args.data, args.test], suffixes={"-o": HDF5_SUFFIXES})

    train = read_samples(args.data)
    test = read_samples(args.test) if args.test else None
    unit = "epoch" if args.model in ("mlp", "mlp-seed") else "start"
    with progress_bar(None, f"brdf fit {args.model}", unit) as bar:
        metrics = fit_to_file(args.model, train, test, args.output, seed=args.seed,
                              metrics_json=args.metrics_json, progress=counter(bar))
    for k, v in metrics.items():
        if k != "loss_log":
            print(f"{k}: {v:.4g}" if isinstance(v, float) else f"{k}: {v}")
    print(f"wrote {args.output}")
    return 0


def cmd_brdf_texture(args) -> int:
    for flag, v in (("--resolution", args.resolution), ("--dphi", args.dphi),
                    ("--retro", args.retro)):
        if v is not None:
            integer(flag, v, MIN_NODES, MAX_NODES)
    check_outputs({"-o": Path(args.output)}, inputs=[args.model],
                  suffixes={"-o": HDF5_SUFFIXES})
    model, meta = load_model(args.model)
    spec = model_spec(model)  # stored so the texture can be checked against it when used
    tex = tabulate(model, args.resolution, args.dphi or args.resolution, args.retro,
                   provenance={"model_file": str(args.model), **meta,
                               **({} if spec is None else {"model_spec": spec})})
    write_texture(args.output, tex)
    print(f"wrote {args.output} texture {tex.shape} [theta_i, theta_s, dphi], "
          f"retro slice {len(tex.retro)}")
    return 0


def cmd_brdf_plot(args) -> int:
    out = Path(args.output) if args.output else Path(args.model).with_suffix(".png")
    check_outputs({"-o": out}, inputs=[args.model, args.data], suffixes={"-o": (".png",)},
                  implied={} if args.output else {"-o": None}, force=args.force)
    model, meta = load_model(args.model)
    data = read_samples(args.data) if args.data else None
    save_figure(brdf_figure(model, f"{args.model}: {meta['metrics'].get('model', '')}", data),
                out)
    print(f"wrote {out}")
    return 0


def cmd_brdf_evaluate(args) -> int:
    if any(m in ("mlp", "mlp-seed") for m in args.models):
        require("torch", "brdf evaluate with an MLP model")
    if args.splits < 1 or args.splits > 100:
        raise ParameterError("--splits", args.splits, "an integer from 1 to 100")
    out = Path(args.output)
    outs = {"-o": out, "(json)": out.with_suffix(".json")}
    check_outputs(outs, inputs=measured_files(args.directory), suffixes={"-o": (".csv",)},
                  implied={"(json)": is_rows_json}, force=args.force)
    rows = evaluate(args.directory, models=args.models, modes=args.modes,
                    splits=tuple(range(args.splits)), materials=args.material,
                    progress=lambda jobs: tqdm(jobs, desc="brdf evaluate", unit="fit"))
    write_rows(rows, out, out.with_suffix(".json"))
    print(summary_table(rows))
    print(f"wrote {out} and {out.with_suffix('.json')}")
    return 0


def register_brdf(sub, add_device) -> None:
    b = sub.add_parser("brdf", help="fit, tabulate and plot BRDF models")
    bs = b.add_subparsers(dest="brdf_command", required=True)
    f = bs.add_parser("fit", help="fit a model to measured data (CSV or pbrt .brdf)")
    data = (f"measured samples: CSV with columns {','.join(CSV_COLUMNS)} (angles in degrees, "
            "BRDF in 1/sr; # comment lines) or pbrt-v2 .brdf")
    f.add_argument("data", help=data)
    f.add_argument("--model", required=True, choices=BRDF_MODELS,
                   help="mlp: the peak-keeping neural BRDF; mlp-seed: the seed's MLP recipe "
                        "(both need torch); five-param, torrance-sparrow, phong, minnaert, "
                        "lambert: analytic models fitted by least squares in log space")
    f.add_argument("-o", "--output", required=True, help="fitted model (.h5)")
    f.add_argument("--test", help="held-out data (same formats) for the test metrics "
                   "(default: none, training metrics only)")
    f.add_argument("--metrics-json", help="also write the metrics to this JSON file "
                   "(default: printed only)")
    f.add_argument("--seed", type=int, default=0,
                   help="random seed: the networks' initialisation and validation split, or "
                        "the analytic fits' random starts (default %(default)s)")
    f.set_defaults(func=cmd_brdf_fit)
    t = bs.add_parser("texture", help="tabulate a model to a BRDF texture (HDF5)")
    t.add_argument("model", help="fitted model (.h5) written by clnlos brdf fit")
    t.add_argument("-o", "--output", required=True,
                   help="output texture (.h5): the [theta_i, theta_s, delta-phi] table and "
                        "the retro slice")
    t.add_argument("--resolution", type=int, default=64,
                   help="theta_i and theta_s nodes over 0-90 deg (default %(default)s)")
    t.add_argument("--dphi", type=int, default=None,
                   help="delta-phi nodes over 0-180 deg (default: --resolution)")
    t.add_argument("--retro", type=int, default=256,
                   help="nodes of the retro slice f(w, w) over 0-90 deg, what the light-cone "
                        "kernel reads (default %(default)s)")
    t.set_defaults(func=cmd_brdf_texture)
    p = bs.add_parser("plot", help="in-plane curves at theta_i 30/45/60 with the data")
    p.add_argument("model", help="fitted model (.h5) written by clnlos brdf fit")
    p.add_argument("--data", help="measured CSV or .brdf to overlay (default: none)")
    p.add_argument("-o", "--output", help="PNG (default: beside the model)")
    _add_force(p)
    p.set_defaults(func=cmd_brdf_plot)
    e = bs.add_parser("evaluate", help="interpolation and extrapolation scores of models on "
                      "every NAME_gonio.csv/NAME_test.csv pair in a directory")
    e.add_argument("directory", help="folder of NAME_gonio.csv / NAME_test.csv pairs")
    e.add_argument("-o", "--output", required=True, help="rows as CSV (JSON beside it)")
    e.add_argument("--models", nargs="+", default=list(EVAL_MODELS), choices=BRDF_MODELS,
                   metavar="MODEL", help="models to score, of " + ", ".join(BRDF_MODELS)
                   + " (default " + " ".join(EVAL_MODELS) + ")")
    split = f"{TRAIN_FRACTION * 100:g}/{(1 - TRAIN_FRACTION) * 100:g}"
    e.add_argument("--modes", nargs="+", default=list(EVAL_MODES), choices=list(EVAL_MODES),
                   help=f"interp: fit and score a random {split} split of all directions; "
                        "extrap: fit NAME_gonio.csv, score NAME_test.csv (default "
                        + " ".join(EVAL_MODES) + ")")
    e.add_argument("--splits", type=int, default=1,
                   help="random interpolation splits, seeds 0 to N-1 (default %(default)s)")
    e.add_argument("--material", nargs="+", help="only sets whose name contains one of these "
                   "(default: every set)")
    _add_force(e)
    e.set_defaults(func=cmd_brdf_evaluate)


# ------------------------------------------------------------------ study
def cmd_study(args) -> int:
    if args.workers is not None:
        integer("--workers", args.workers, 1, MAX_WORKERS)
    if args.scheduler is not None:
        check_scheduler_address("--scheduler", args.scheduler)
    require("torch", "clnlos study (its CNN)")
    if args.scheduler is not None or (args.workers or 2) > 1:
        require("distributed", "clnlos study with worker processes")

    out = Path(args.output)
    outs = {"-o report.html": out / "report.html", "-o results.json": out / "results.json"}
    check_outputs(outs, implied=dict.fromkeys(outs), force=args.force)
    if args.real_data is not None and not args.real_data.is_dir():  # not after the minutes
        raise InputFileError(f"--real-data {args.real_data}: "
                             + ("not a folder" if args.real_data.exists()
                                else "no such folder"))
    res = study.run(out, full=args.full, method=args.method, labels=args.labels,
                    real_data=args.real_data, transport=args.transport,
                    n_dataset=args.n_dataset, workers=args.workers, scheduler=args.scheduler,
                    device=args.device)
    for geo in res["geometries"]:
        print(f"geometry {geo['name']}: {geo['description']}; stroke / resolution "
              f"{geo['stroke_over_resolution']:.2f}")
        for m in geo["materials"]:
            i = m["identification"]
            print(f"  {m['name']:36s} {m['brdf_class']:26s} identification "
                  f"{i['accuracy']:.2f} [{i['ci'][0]:.2f}, {i['ci'][1]:.2f}] (chance "
                  f"{i['chance']:.3f}, n {i['n']}) IoU {m['iou']:.3f} (box "
                  f"{m['iou_box_baseline']:.3f}) label {m['label']} CNN {m['cnn_label']} "
                  f"seed {m['seed_label']}")
    print(f"labels {res['labels']['source']}; legibility CNN on held-out splits: " + "; ".join(
        f"{k} balanced accuracy {v['balanced_accuracy']:.3f} (one-feature baseline "
        f"{v['baseline']:.3f}), AUC {v['auc']:.3f}, ECE {v['ece']:.3f}"
        for k, v in res["classifier"]["splits"].items()))
    print(res["findings"]["statement"])
    print(f"wrote {out / 'report.html'} and results.json")
    return 0


def register_study(sub, add_device) -> None:
    quick, full = StudyOptions.quick(), StudyOptions()
    s = sub.add_parser("study", help="the material study (main job)")
    g = s.add_mutually_exclusive_group()
    g.add_argument("--quick", action="store_true", help=f"built-in default: "
                   f"{len(quick.glyphs)} glyphs x {quick.seeds} noise realisation(s) per "
                   f"material and geometry, {len(quick.sweep_glyphs)} glyphs per geometry-"
                   f"sweep point, {quick.n_dataset} extra random samples (about 5 minutes on "
                   "2 cores)")
    g.add_argument("--full", action="store_true", help=f"{len(full.glyphs)} glyphs x "
                   f"{full.seeds} noise realisations per material and geometry, "
                   f"{len(full.sweep_glyphs)} glyphs per geometry-sweep point, "
                   f"{full.n_dataset} extra random samples (within 20 minutes on 2 cores)")
    s.add_argument("-o", "--output", default="out/study",
                   help="output folder: report.html, results.json and the sample cache "
                        "(default %(default)s)")
    s.add_argument("--method", choices=list(method_names()), default=None,
                   help=f"reconstruction method (default {StudyGrid.method})")
    s.add_argument("--labels", choices=list(LABEL_METRICS), default=full.labels,
                   help="what the CNN learns: legibility (glyph identified and IoU above "
                        "its box baseline: ground truth), nr (the no-reference metric "
                        f"{LABEL_METRICS['nr']}) or fft (the seed's FFT clarity "
                        f"{LABEL_METRICS['fft']}, the seed's recipe) (default %(default)s)")
    w = s.add_mutually_exclusive_group()
    w.add_argument("--workers", type=int, default=None,
                   help="local Dask worker processes (default: CPU count; 1 = serial)")
    w.add_argument("--scheduler", default=None, help="address of an existing Dask scheduler, "
                   "e.g. tcp://HOST:8786 (default: none, local workers)")
    s.add_argument("--real-data", type=Path, default=None, metavar="DIR",
                   help="folder whose cdt/ holds the real CDT captures (letters_ut.mat, "
                        "letter_s.mat, resolution_70.mat): the report adds the real capture "
                        "beside its simulation, the real chart's resolved features and the "
                        "CNN's verdict on them; a folder without them is noted and skipped "
                        "(default: none)")
    s.add_argument("--transport", choices=list(TRANSPORT_CHOICES), default=None,
                   help="confocal: every sample with the seed's confocal transport (Eq. 9); "
                        "both: also the materials at the legible geometry under the bistatic "
                        f"transport (Eq. 8 in full, {full.face_rings} x {full.face_angles} "
                        "face samples, about 8 s a sample on 2 cores: some 10-15 minutes more "
                        "for the quick study), their table, ranks and rank correlation "
                        f"(default: {quick.transport} with --quick, {full.transport} with "
                        "--full)")
    s.add_argument("--n-dataset", type=int, default=None, help=argparse.SUPPRESS)
    _add_force(s)
    add_device(s)
    s.set_defaults(func=cmd_study)


# ------------------------------------------------------------------ bench
def cmd_bench(args) -> int:
    """Thin front of :func:`clnlos.bench.main` (runs from an installed package)."""
    if args.only is not None:
        sections_of(args.only)  # an unknown section: one line before any work
    out = Path(args.output)
    outs = {"-o bench.json": out / "bench.json", "-o bench.html": out / "bench.html"}
    check_outputs(outs, implied=dict.fromkeys(outs), force=args.force)
    argv = ["-o", args.output] + (["--quick"] if args.quick else []) + (
        ["--tiny"] if args.tiny else []) + (["--only", args.only] if args.only else []) + (
        ["--device", args.device] if args.device else []) + (
        ["--brdf-data", args.brdf_data] if args.brdf_data else [])
    bench_main(argv)
    return 0


def register_bench(sub, add_device) -> None:
    b = sub.add_parser("bench", help="accuracy versus time of every kernel knob (bench.json, "
                                     "bench.html)")
    g = b.add_mutually_exclusive_group()
    g.add_argument("--quick", action="store_true", help="about 6 minutes on 2 CPU cores")
    g.add_argument("--tiny", action="store_true", help=argparse.SUPPRESS)
    b.add_argument("-o", "--output", default="out/bench",
                   help="output folder: bench.json and bench.html (default %(default)s)")
    b.add_argument("--only", default=None, help=ONLY_HELP + " (default: all)")
    b.add_argument("--brdf-data", default=None, metavar="DIR",
                   help="folder of measured BRDFs (*_gonio.csv) for the brdf_measured section "
                        "(default: none, those rows skipped with a note)")
    _add_force(b)
    add_device(b)
    b.set_defaults(func=cmd_bench)


def register(sub, add_device) -> None:
    """Add the pipeline sub-commands to the parser ``sub``."""
    register_reconstruct(sub, add_device)
    register_plot(sub)
    register_forward(sub, add_device)
    register_brdf(sub, add_device)
    register_study(sub, add_device)
    register_bench(sub, add_device)
