"""Sub-commands of the clnlos CLI beyond ``devices``: each one parses, checks its inputs, its
output paths and its optional dependencies before any work, calls one library function, and
prints what it wrote."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from .outputs import HDF5_SUFFIXES, check_outputs

DTYPES = {"float32": np.float32, "float64": np.float64}

# optional dependencies: import name -> (extra, what needs it)
EXTRAS = {"torch": ("ml", "the torch CPU wheel: pip install torch==2.13.0"),
          "dask": ("study", "dask[distributed]"),
          "distributed": ("study", "dask[distributed]")}


def require(module: str, what: str) -> None:
    """One line naming the extra when an optional dependency is missing."""
    import importlib.util

    from .errors import MissingDependencyError

    if importlib.util.find_spec(module) is None:
        extra, hint = EXTRAS[module]
        raise MissingDependencyError(
            f"{what} needs {module!r}, which is not installed: pip install 'clnlos[{extra}]' "
            f"({hint})")


def _add_precision(p) -> None:
    p.add_argument("--dtype", choices=sorted(DTYPES), default="float32",
                   help="kernel precision (default float32)")


# ------------------------------------------------------------------ reconstruct
# CLI flag -> ReconstructionConfig field (error messages name the flag the user typed)
RECON_FLAGS = {"scan_width": ("scan_width_m", "--scan-width"),
               "bin_width": ("bin_width_s", "--bin-width"),
               "snr": ("snr", "--snr"), "inversion_snr": ("inversion_snr", "--inversion-snr"),
               "falloff": ("falloff", "--falloff"), "max_path": ("max_path_m", "--max-path"),
               "bins": ("bins", "--bins"), "method": ("method", "--method"),
               "iterations": ("iterations", "--iterations"),
               "tv_weight": ("tv_weight", "--tv-weight"),
               "l1_weight": ("l1_weight", "--l1-weight"),
               "depth_min": ("depth_min_m", "--depth-min")}
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


def config_from_args(args, capture=None):
    """The reconstruction config: TOML file (if any), overridden by flags; validated with
    the flags' names in error messages. Without slab flags, --no-slab or a [slab] in the
    config, the slab a clnlos capture recorded is used (:func:`clnlos.reconstruct.setup_slab`).
    """
    from .config import ReconstructionConfig, slab_from_table, slab_table
    from .reconstruct import setup_slab

    cfg = ReconstructionConfig.from_toml(args.config) if args.config else ReconstructionConfig()
    changes, names = {}, {}
    for dest, (field, flag) in RECON_FLAGS.items():
        v = getattr(args, dest, None)
        if v is not None:
            changes[field], names[field] = v, flag
    slab_given = {k: getattr(args, dest) for dest, (k, _) in SLAB_FLAGS.items()
                  if getattr(args, dest) is not None}
    if args.no_slab:
        changes["slab"] = None
    elif slab_given:
        base = {} if cfg.slab is None else slab_table(cfg.slab)
        base.update(slab_given)
        changes["slab"], _ = slab_from_table(
            base, names={k: flag for k, flag in SLAB_FLAGS.values()})
    cfg = cfg.replace(**changes).validate(names)
    if capture is not None and not args.no_slab and cfg.slab is None:
        cfg, note = setup_slab(cfg, capture)
        print(f"clnlos: note: {note}", file=sys.stderr)
    return cfg


def cmd_reconstruct(args) -> int:
    from .io import read_capture
    from .reconstruct import reconstruct_to_files, resolve_geometry
    from .runtime import get_queue

    out = Path(args.output)
    cfg = config_from_args(args)  # parameter errors before reading anything
    check_outputs({"-o": out, "figure": out.with_suffix(".png")},
                  inputs=[args.capture, args.config], suffixes={"-o": HDF5_SUFFIXES})
    queue = get_queue(args.device)
    capture = read_capture(args.capture)
    resolve_geometry(capture, cfg)  # missing geometry before the slab note
    if not np.any(capture.transient):
        from .errors import InputFileError

        raise InputFileError(f"{args.capture}: the capture holds no signal (all zero): "
                             "nothing to reconstruct")
    cfg = config_from_args(args, capture)
    rec = reconstruct_to_files(capture, out, cfg, dtype=DTYPES[args.dtype], queue=queue)
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
    r.add_argument("--config", help="reconstruction parameters (TOML)")
    r.add_argument("--method", choices=["lct", "fk", "iterative"], default=None)
    r.add_argument("--scan-width", type=float, help="side of the scanned square (m)")
    r.add_argument("--bin-width", type=float, help="histogram bin width (s)")
    r.add_argument("--snr", type=number_or_auto,
                   help="Wiener SNR of the slab deconvolution, or auto (default: chosen "
                        "from the capture by generalised cross-validation)")
    r.add_argument("--inversion-snr", type=number_or_auto,
                   help="Wiener SNR of the LCT filter (and of the iterative warm start), or "
                        "auto (default: by generalised cross-validation)")
    r.add_argument("--falloff", type=float, help="radiometric exponent of the inversion")
    r.add_argument("--max-path", type=float, help="keep round-trip paths below this (m)")
    r.add_argument("--bins", type=int, help="rebin the kept window to this many bins")
    r.add_argument("--iterations", type=int, help="iterative: iterations at most (default 200)")
    r.add_argument("--tv-weight", type=float,
                   help="iterative: total-variation weight, relative (default 0)")
    r.add_argument("--l1-weight", type=float,
                   help="iterative: L1 (sparsity) weight, relative (default 0.1)")
    r.add_argument("--depth-min", type=number_or_auto,
                   help="iterative: shallowest depth of the volume (m), or auto (default: "
                        "from the capture's first arrival)")
    r.add_argument("--slab-thickness", type=float, help="slab thickness (m)")
    r.add_argument("--mu-a", type=float, help="slab absorption coefficient (1/m)")
    r.add_argument("--mu-s-prime", type=float, help="slab reduced scattering coefficient (1/m)")
    r.add_argument("--n", type=float, help="slab refractive index (relative)")
    r.add_argument("--no-slab", action="store_true",
                   help="skip the slab deconvolution (also of a slab the capture recorded)")
    _add_precision(r)
    add_device(r)
    r.set_defaults(func=cmd_reconstruct)


# ------------------------------------------------------------------ plot
def cmd_plot(args) -> int:
    from .figures import volume_figure
    from .io import read_volume, save_figure

    out = Path(args.output) if args.output else Path(args.volume).with_suffix(".png")
    check_outputs({"-o": out}, inputs=[args.volume], suffixes={"-o": (".png",)})
    if args.gamma is not None and not (np.isfinite(args.gamma) and 0 < args.gamma <= 10):
        from .errors import ParameterError

        raise ParameterError("--gamma", args.gamma, "a number > 0 and <= 10")
    volume, extents, attrs = read_volume(args.volume)
    save_figure(volume_figure(volume, extents, f"{Path(args.volume).name}",
                              gamma=args.gamma, log=args.log), out)
    print(f"wrote {out}")
    return 0


def register_plot(sub) -> None:
    p = sub.add_parser("plot", help="re-render the figure of a reconstructed volume")
    p.add_argument("volume", help="volume HDF5 written by clnlos reconstruct")
    p.add_argument("-o", "--output", help="PNG (default: beside the volume)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--gamma", type=float, help="display value^gamma (e.g. 0.5)")
    g.add_argument("--log", action="store_true", help="display log10(value / max)")
    p.set_defaults(func=cmd_plot)


# ------------------------------------------------------------------ simulate, demo
def cmd_simulate(args) -> int:
    from .runtime import get_queue
    from .scene import Scene
    from .simulate import figure_path, simulate_to_file

    out = Path(args.output)
    scene = Scene.from_toml(args.scene)
    check_outputs({"-o": out, "figure": figure_path(out)}, inputs=[args.scene],
                  suffixes={"-o": HDF5_SUFFIXES})
    queue = get_queue(args.device)
    sim = simulate_to_file(scene, out, fmt=args.format, dtype=DTYPES[args.dtype], queue=queue)
    print(f"wrote {out} ({args.format}) transient {sim.transient.shape} [t, y, x]; stages "
          f"{', '.join(sim.stages)}; {sim.seconds:.2f} s on {queue.device.name.strip()}")
    print(f"wrote {sim.figure}")
    return 0


def cmd_demo(args) -> int:
    from .demo import DEMO_FILES, demo_inputs, run_demo
    from .runtime import get_queue

    out = Path(args.output)
    if out.exists() and not out.is_dir():
        from .errors import OutputFileError

        raise OutputFileError(f"-o {out}: is a file; the demo writes a folder")
    scene, cfg = demo_inputs(args.scene, args.config)
    check_outputs({f"-o {name}": out / name for name in DEMO_FILES},
                  inputs=[args.scene, args.config])
    run_demo(out, scene, cfg, queue=get_queue(args.device))
    return 0


def register_forward(sub, add_device) -> None:
    s = sub.add_parser("simulate", help="simulate a confocal capture from a scene TOML")
    s.add_argument("scene", help="scene description (TOML)")
    s.add_argument("-o", "--output", required=True,
                   help="output capture (.h5; a PNG is written beside)")
    s.add_argument("--format", choices=["clnlos", "tal"], default="clnlos",
                   help="capture format: clnlos HDF5 (default) or y-tal HDF5")
    _add_precision(s)
    add_device(s)
    s.set_defaults(func=cmd_simulate)
    d = sub.add_parser("demo", help="simulate 'UT' behind the slab, reconstruct with LCT, f-k "
                                    "and the iterative method, score")
    d.add_argument("-o", "--output", default="out/demo", help="output folder")
    d.add_argument("--scene", help="scene TOML with letters as objects[0] (default: built-in)")
    d.add_argument("--config", help="reconstruction TOML (default: built-in; its slab "
                   "defaults to the scene's)")
    add_device(d)
    d.set_defaults(func=cmd_demo)


# ------------------------------------------------------------------ brdf
BRDF_MODELS = ["mlp", "mlp-seed", "five-param", "torrance-sparrow", "phong", "minnaert",
               "lambert"]


def cmd_brdf_fit(args) -> int:
    from .brdf.fit import fit_to_file
    from .brdf.plot import read_samples

    if args.model in ("mlp", "mlp-seed"):
        require("torch", f"brdf fit --model {args.model}")
    outs = {"-o": Path(args.output)}
    if args.metrics_json:
        outs["--metrics-json"] = Path(args.metrics_json)
    check_outputs(outs, inputs=[args.data, args.test], suffixes={"-o": HDF5_SUFFIXES})
    train = read_samples(args.data)
    test = read_samples(args.test) if args.test else None
    metrics = fit_to_file(args.model, train, test, args.output, seed=args.seed,
                          metrics_json=args.metrics_json)
    for k, v in metrics.items():
        if k != "loss_log":
            print(f"{k}: {v:.4g}" if isinstance(v, float) else f"{k}: {v}")
    print(f"wrote {args.output}")
    return 0


def cmd_brdf_texture(args) -> int:
    from .brdf.store import load_model
    from .brdf.texture import tabulate, write_texture

    check_outputs({"-o": Path(args.output)}, inputs=[args.model],
                  suffixes={"-o": HDF5_SUFFIXES})
    model, meta = load_model(args.model)
    tex = tabulate(model, args.resolution, args.dphi or args.resolution, args.retro,
                   provenance={"model_file": str(args.model), **meta})
    write_texture(args.output, tex)
    print(f"wrote {args.output} texture {tex.shape} [theta_i, theta_s, dphi], "
          f"retro slice {len(tex.retro)}")
    return 0


def cmd_brdf_plot(args) -> int:
    from .brdf.plot import brdf_figure, read_samples
    from .brdf.store import load_model
    from .io import save_figure

    out = Path(args.output) if args.output else Path(args.model).with_suffix(".png")
    check_outputs({"-o": out}, inputs=[args.model, args.data], suffixes={"-o": (".png",)})
    model, meta = load_model(args.model)
    data = read_samples(args.data) if args.data else None
    save_figure(brdf_figure(model, f"{args.model}: {meta['metrics'].get('model', '')}", data),
                out)
    print(f"wrote {out}")
    return 0


def cmd_brdf_evaluate(args) -> int:
    from tqdm import tqdm

    from .brdf.evaluate import evaluate, measured_sets, summary_table, write_rows

    if any(m in ("mlp", "mlp-seed") for m in args.models):
        require("torch", "brdf evaluate with an MLP model")
    if args.splits < 1 or args.splits > 100:
        from .errors import ParameterError

        raise ParameterError("--splits", args.splits, "an integer from 1 to 100")
    out = Path(args.output)
    outs = {"-o": out, "(json)": out.with_suffix(".json")}
    check_outputs(outs, inputs=[args.directory], suffixes={"-o": (".csv",)})
    measured_sets(args.directory)
    rows = evaluate(args.directory, models=args.models, modes=args.modes,
                    splits=tuple(range(args.splits)), materials=args.material,
                    progress=lambda jobs: tqdm(jobs, desc="brdf evaluate", unit="fit"))
    write_rows(rows, out, out.with_suffix(".json"))
    print(summary_table(rows))
    print(f"wrote {out} and {out.with_suffix('.json')}")
    return 0


def register_brdf(sub, add_device) -> None:
    from .brdf.evaluate import MODELS as EVAL_MODELS, MODES as EVAL_MODES

    b = sub.add_parser("brdf", help="fit, tabulate and plot BRDF models")
    bs = b.add_subparsers(dest="brdf_command", required=True)
    f = bs.add_parser("fit", help="fit a model to measured data (CSV or pbrt .brdf)")
    f.add_argument("data")
    f.add_argument("--model", required=True, choices=BRDF_MODELS)
    f.add_argument("-o", "--output", required=True, help="fitted model (.h5)")
    f.add_argument("--test", help="held-out data for the test metrics")
    f.add_argument("--metrics-json")
    f.add_argument("--seed", type=int, default=0)
    f.set_defaults(func=cmd_brdf_fit)
    t = bs.add_parser("texture", help="tabulate a model to a BRDF texture (HDF5)")
    t.add_argument("model")
    t.add_argument("-o", "--output", required=True)
    t.add_argument("--resolution", type=int, default=64, help="theta_i and theta_s nodes")
    t.add_argument("--dphi", type=int, default=None, help="delta-phi nodes (default: same)")
    t.add_argument("--retro", type=int, default=256, help="nodes of the retro slice")
    t.set_defaults(func=cmd_brdf_texture)
    p = bs.add_parser("plot", help="in-plane curves at theta_i 30/45/60 with the data")
    p.add_argument("model")
    p.add_argument("--data", help="measured CSV to overlay")
    p.add_argument("-o", "--output")
    p.set_defaults(func=cmd_brdf_plot)
    e = bs.add_parser("evaluate", help="interpolation and extrapolation scores of models on "
                      "every NAME_gonio.csv/NAME_test.csv pair in a directory")
    e.add_argument("directory")
    e.add_argument("-o", "--output", required=True, help="rows as CSV (JSON beside it)")
    e.add_argument("--models", nargs="+", default=list(EVAL_MODELS), choices=BRDF_MODELS)
    e.add_argument("--modes", nargs="+", default=list(EVAL_MODES), choices=list(EVAL_MODES))
    e.add_argument("--splits", type=int, default=1, help="random interpolation splits")
    e.add_argument("--material", nargs="+", help="only sets whose name contains one of these")
    e.set_defaults(func=cmd_brdf_evaluate)


# ------------------------------------------------------------------ study
def cmd_study(args) -> int:
    from dataclasses import replace

    require("torch", "clnlos study (its CNN)")
    if args.scheduler is not None or (args.workers or 2) > 1:
        require("distributed", "clnlos study with worker processes")
    from .study.run import StudyOptions, run_study

    out = Path(args.output)
    check_outputs({"-o report.html": out / "report.html", "-o results.json":
                   out / "results.json"})
    opts = StudyOptions() if args.full else StudyOptions.quick()
    if args.n_dataset is not None:
        opts.n_dataset = args.n_dataset
    if args.method is not None:
        opts.grid = replace(opts.grid, method=args.method)
    opts.labels = args.labels
    res = run_study(out, opts.validate(), workers=args.workers, scheduler=args.scheduler,
                    device=args.device)
    for m in res["materials"]:
        print(f"{m['name']:36s} {m['brdf_class']:26s} IoU {m['iou']:.3f} "
              f"[{m['iou_ci'][0]:.2f}, {m['iou_ci'][1]:.2f}] label {m['label']} "
              f"CNN {m['cnn_label']} seed {m['seed_label']} depth error "
              f"{m['depth_error_m'] * 100:.1f} cm")
    print(f"labels {res['labels']['metric']}: r = {res['labels']['corr_with_iou']:+.2f} with "
          f"IoU; CNN validation accuracy {res['cnn']['val_accuracy']:.3f} (majority "
          f"{res['cnn']['majority_baseline']:.3f}); seed Figure 9 agreement "
          f"{res['seed_figure9_agreement']}/10")
    print(res["findings"]["statement"])
    print(f"wrote {out / 'report.html'} and results.json")
    return 0


def register_study(sub, add_device) -> None:
    s = sub.add_parser("study", help="the material study (main job)")
    g = s.add_mutually_exclusive_group()
    g.add_argument("--quick", action="store_true", help="built-in default: 200 dataset "
                   "samples, 1 noise seed per sweep point (under 3 minutes on 2 cores)")
    g.add_argument("--full", action="store_true", help="1000 dataset samples, 2 noise seeds "
                   "per sweep point (under 15 minutes on 2 cores)")
    s.add_argument("-o", "--output", default="out/study")
    s.add_argument("--method", choices=["lct", "fk", "iterative"], default=None,
                   help="reconstruction method (default iterative)")
    s.add_argument("--labels", choices=["nr", "fft"], default="nr",
                   help="label source: the no-reference metric nr_clarity (default) or the "
                        "seed's FFT clarity")
    w = s.add_mutually_exclusive_group()
    w.add_argument("--workers", type=int, default=None,
                   help="local Dask worker processes (default: CPU count; 1 = serial)")
    w.add_argument("--scheduler", default=None, help="address of an existing Dask scheduler")
    s.add_argument("--n-dataset", type=int, default=None, help=argparse.SUPPRESS)
    add_device(s)
    s.set_defaults(func=cmd_study)


# ------------------------------------------------------------------ bench
def cmd_bench(args) -> int:
    """Thin front of :func:`clnlos.bench.main` (runs from an installed package)."""
    from .bench import main as bench_main

    out = Path(args.output)
    check_outputs({"-o bench.json": out / "bench.json", "-o bench.html": out / "bench.html"})
    argv = ["-o", args.output] + (["--quick"] if args.quick else []) + (
        ["--tiny"] if args.tiny else []) + (["--only", args.only] if args.only else []) + (
        ["--device", args.device] if args.device else [])
    bench_main(argv)
    return 0


def register_bench(sub, add_device) -> None:
    b = sub.add_parser("bench", help="accuracy versus time of every kernel knob (bench.json, "
                                     "bench.html)")
    g = b.add_mutually_exclusive_group()
    g.add_argument("--quick", action="store_true", help="under 5 minutes on 2 CPU cores")
    g.add_argument("--tiny", action="store_true", help=argparse.SUPPRESS)
    b.add_argument("-o", "--output", default="out/bench")
    b.add_argument("--only", default=None, help="comma-separated sections (diffusion, "
                   "lightcone, brdf, forward, reconstruction, iterative, end_to_end)")
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
