"""Sub-commands of the clnlos CLI beyond ``devices`` (each one thin over a pipeline)."""

from __future__ import annotations

import json
import sys
import tomllib
from pathlib import Path

import numpy as np

from .errors import ParameterError

DTYPES = {"float32": np.float32, "float64": np.float64}


def _add_precision(p) -> None:
    p.add_argument("--dtype", choices=sorted(DTYPES), default="float32",
                   help="kernel precision (default float32)")


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
        import argparse

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
    from .io import read_capture, save_figure, write_h5
    from .reconstruct import reconstruct, volume_figure
    from .runtime import get_queue

    from .reconstruct import resolve_geometry

    cfg = config_from_args(args)  # parameter errors before reading the capture
    capture = read_capture(args.capture)
    resolve_geometry(capture, cfg)  # missing geometry before the slab note
    cfg = config_from_args(args, capture)
    queue = get_queue(args.device)
    rec = reconstruct(capture, cfg, dtype=DTYPES[args.dtype], device=queue)
    out = Path(args.output)
    attrs = {**rec.extents, "bin_width_s": rec.bin_width_s, "scan_width_m": rec.scan_width_m,
             "stages": json.dumps(rec.stages), "timings_s": json.dumps(rec.timings_s),
             "params": json.dumps(rec.params), "capture": str(args.capture),
             "noise": json.dumps(rec.noise), "solver": json.dumps(rec.solver),
             "dtype": args.dtype, "device": queue.device.name.strip(),
             "axes": "volume[z, y, x]; +x with column index, +y with row index",
             "format": "clnlos-volume-1"}
    write_h5(out, {"volume": rec.volume.astype(np.float32)}, attrs)
    png = out.with_suffix(".png")
    save_figure(volume_figure(rec, title=f"{Path(args.capture).name} ({cfg.method})"), png)
    total = sum(rec.timings_s.values())
    print(f"wrote {out} volume {rec.volume.shape} [z, y, x], depth 0-"
          f"{rec.extents['depth_max_m']:.3f} m; stages {', '.join(rec.stages)}; "
          f"{total:.3f} s on {queue.device.name.strip()}")
    print(f"wrote {png}")
    return 0


def register(sub, add_device) -> None:
    """Add the pipeline sub-commands to the parser ``sub``."""
    r = sub.add_parser("reconstruct", help="reconstruct a hidden volume from a capture")
    r.add_argument("capture", help="clnlos HDF5 capture or CDT .mat file")
    r.add_argument("-o", "--output", required=True, help="output HDF5 (a PNG is written beside)")
    r.add_argument("--config", help="reconstruction parameters (TOML)")
    r.add_argument("--method", choices=["lct", "fk", "iterative"], default=None)
    r.add_argument("--scan-width", type=float, help="side of the scanned square (m)")
    r.add_argument("--bin-width", type=float, help="histogram bin width (s)")
    r.add_argument("--snr", type=number_or_auto,
                   help="Wiener SNR of the slab deconvolution, or auto (default: from the "
                        "capture's photon count)")
    r.add_argument("--inversion-snr", type=number_or_auto,
                   help="Wiener SNR of the LCT filter (and of the iterative warm start), or "
                        "auto (default)")
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
    r.add_argument("--no-slab", action="store_true", help="plain NLOS: skip the deconvolution")
    _add_precision(r)
    add_device(r)
    r.set_defaults(func=cmd_reconstruct)
    register_forward(sub, add_device)
    register_brdf(sub, add_device)
    register_study(sub, add_device)
    register_bench(sub, add_device)


def transient_figure(tau: np.ndarray, scene, title: str = ""):
    """x-t and y-t slices through the centre and the time-integrated image."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    nt, ny, nx = tau.shape
    w = scene.width_m
    t0, t1 = scene.start_s * 1e9, (scene.start_s + nt * scene.bin_width_s) * 1e9
    fig, ax = plt.subplots(1, 3, figsize=(12, 4))
    ax[0].imshow(tau[:, ny // 2, :], origin="lower", aspect="auto", cmap="magma",
                 extent=(-w / 2, w / 2, t0, t1))
    ax[0].set(xlabel="x (m)", ylabel="t (ns)", title="x-t slice (y = centre)")
    ax[1].imshow(tau[:, :, nx // 2], origin="lower", aspect="auto", cmap="magma",
                 extent=(-w / 2, w / 2, t0, t1))
    ax[1].set(xlabel="y (m)", ylabel="t (ns)", title="y-t slice (x = centre)")
    ax[2].imshow(tau.sum(axis=0), origin="lower", cmap="gray",
                 extent=(-w / 2, w / 2, -w / 2, w / 2))
    ax[2].set(xlabel="x (m)", ylabel="y (m)", title="time-integrated")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig


def simulate_to_file(scene, out: Path, *, dtype, queue) -> tuple[np.ndarray, list[str], float]:
    import time

    from .forward import ForwardModel
    from .io import save_figure, write_capture

    t0 = time.perf_counter()
    fm = ForwardModel(scene, dtype=dtype, queue=queue)
    tau = fm.run()
    seconds = time.perf_counter() - t0
    write_capture(out, tau, bin_width_s=scene.bin_width_s, start_s=scene.start_s,
                  scan_width_m=scene.width_m,
                  attrs={**fm.setup_attrs(), "seconds": seconds,
                         "units": "photon counts" if scene.detector else
                         "1/(m^2 sr) per bin (light-cone normalisation)"})
    save_figure(transient_figure(tau, scene, f"{out.name}: {', '.join(fm.stages)}"),
                out.with_suffix(".png"))
    return tau, fm.stages, seconds


def cmd_simulate(args) -> int:
    from .runtime import get_queue
    from .scene import Scene

    scene = Scene.from_toml(args.scene)
    queue = get_queue(args.device)
    out = Path(args.output)
    tau, stages, secs = simulate_to_file(scene, out, dtype=DTYPES[args.dtype], queue=queue)
    print(f"wrote {out} transient {tau.shape} [t, y, x]; stages {', '.join(stages)}; "
          f"{secs:.2f} s on {queue.device.name.strip()}")
    print(f"wrote {out.with_suffix('.png')}")
    return 0


def cmd_demo(args) -> int:
    """Simulate a scene (default: the seed's Table 1 round trip), reconstruct it with LCT and
    f-k, and score it against the true letters."""
    import importlib.resources

    from .config import ReconstructionConfig, load_toml
    from .io import atomic_path, read_capture, save_figure, write_h5
    from .metrics import letters_truth_mask, mip_iou, peak_depth_m
    from .reconstruct import reconstruct, volume_figure
    from .runtime import get_queue
    from .scene import Scene

    queue = get_queue(args.device)
    out = Path(args.output)
    data = importlib.resources.files("clnlos").joinpath("data")
    if args.scene:
        scene = Scene.from_toml(args.scene)
    else:
        text = data.joinpath("demo_scene.toml").read_text()
        scene = Scene.from_dict(tomllib.loads(text), text=text)
    cfg_dict = (load_toml(args.config) if args.config
                else tomllib.loads(data.joinpath("demo_reconstruct.toml").read_text()))
    base_cfg = ReconstructionConfig.from_dict(cfg_dict)
    if base_cfg.slab is None:
        base_cfg = base_cfg.replace(slab=scene.slab)
    obj = scene.objects[0]
    if obj.shape != "letters":
        raise ParameterError("objects[0].shape", obj.shape, "'letters' (the demo scores letters)")
    out.mkdir(parents=True, exist_ok=True)
    cap_path = out / "capture.h5"
    _, stages, t_sim = simulate_to_file(scene, cap_path, dtype=np.float32, queue=queue)
    print(f"simulated {cap_path} ({', '.join(stages)}) in {t_sim:.2f} s")
    summary = {"device": queue.device.name.strip(), "simulate_s": t_sim, "stages": stages,
               "methods": {}}
    truth = letters_truth_mask(obj.text, obj.height_m, obj.stroke_m, obj.translate_m[:2],
                               scene.scan_centres())
    for method in ("lct", "fk", "iterative"):
        cfg = base_cfg.replace(method=method).validate()
        rec = reconstruct(read_capture(cap_path), cfg, device=queue)
        score, _ = mip_iou(rec.volume, truth)
        depth = peak_depth_m(rec.volume, rec.extents["voxel_depth_m"])
        vol_path = out / f"volume_{method}.h5"
        write_h5(vol_path, {"volume": rec.volume}, {**rec.extents,
                                                    "params": json.dumps(rec.params)})
        save_figure(volume_figure(rec, f"demo: {obj.text} at {obj.translate_m[2]} m ({method}), "
                                       f"IoU {score:.2f}"), vol_path.with_suffix(".png"))
        summary["methods"][method] = {"iou": score, "depth_m": depth,
                                      "reconstruct_s": sum(rec.timings_s.values())}
        print(f"{method}: IoU of the thresholded MIP with the true letters {score:.3f}, "
              f"depth {depth:.3f} m (true {obj.translate_m[2]} m), "
              f"{sum(rec.timings_s.values()):.2f} s; wrote {vol_path} and .png")
    with atomic_path(out / "summary.json") as tmp:
        tmp.write_text(json.dumps(summary, indent=1))
    print(f"wrote {out / 'summary.json'}")
    return 0


def register_forward(sub, add_device) -> None:
    s = sub.add_parser("simulate", help="simulate a confocal capture from a scene TOML")
    s.add_argument("scene", help="scene description (TOML)")
    s.add_argument("-o", "--output", required=True, help="output capture HDF5 (+ PNG beside)")
    _add_precision(s)
    add_device(s)
    s.set_defaults(func=cmd_simulate)
    d = sub.add_parser("demo", help="simulate 'UT' behind the slab, reconstruct, score (main job)")
    d.add_argument("-o", "--output", default="out/demo", help="output folder")
    d.add_argument("--scene", help="scene TOML with letters as objects[0] (default: built-in)")
    d.add_argument("--config", help="reconstruction TOML (default: built-in; its slab "
                   "defaults to the scene's)")
    add_device(d)
    d.set_defaults(func=cmd_demo)


def _read_samples(path):
    from .brdf.data import read_gonio_csv, read_pbrt_brdf

    p = str(path)
    return read_pbrt_brdf(p) if p.endswith(".brdf") else read_gonio_csv(p)


def cmd_brdf_fit(args) -> int:
    from .brdf.fit import fit_analytic, metrics_for
    from .brdf.store import save_model
    from .io import atomic_path

    train = _read_samples(args.data)
    test = _read_samples(args.test) if args.test else None
    if args.model in ("mlp", "mlp-seed"):
        from .brdf.mlp import MLPConfig, train_mlp

        model, log = train_mlp(train, MLPConfig(recipe="seed" if args.model == "mlp-seed"
                                                else "improved", seed=args.seed))
        metrics = {"model": args.model, "epochs_run": log["epochs_run"],
                   **metrics_for(model, train, test)}
    else:
        r = fit_analytic(args.model, train, test, seed=args.seed)
        model, metrics = r.model, r.metrics
    prov = {"train": train.meta, "test": test.meta if test else None}
    save_model(args.output, model, metrics, prov)
    for k, v in metrics.items():
        if k != "loss_log":
            print(f"{k}: {v:.4g}" if isinstance(v, float) else f"{k}: {v}")
    if args.metrics_json:
        with atomic_path(args.metrics_json) as tmp:
            tmp.write_text(json.dumps(metrics, indent=1))
    print(f"wrote {args.output}")
    return 0


def cmd_brdf_texture(args) -> int:
    from .brdf.store import load_model
    from .brdf.texture import tabulate, write_texture

    model, meta = load_model(args.model)
    tex = tabulate(model, args.resolution, args.dphi or args.resolution, args.retro,
                   provenance={"model_file": str(args.model), **meta})
    write_texture(args.output, tex)
    print(f"wrote {args.output} texture {tex.shape} [theta_i, theta_s, dphi], "
          f"retro slice {len(tex.retro)}")
    return 0


def cmd_brdf_plot(args) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .brdf.store import load_model
    from .io import save_figure

    model, meta = load_model(args.model)
    data = _read_samples(args.data) if args.data else None
    fig, axes = plt.subplots(1, 3, figsize=(13, 4), sharey=True)
    ts = np.radians(np.linspace(-89, 89, 357))
    for ax, ti_deg in zip(axes, (30, 45, 60), strict=True):
        ti = np.radians(ti_deg)
        # in-plane: detector at phi = 180 (forward, positive angles) or 0 (backward)
        f = model(np.full_like(ts, ti), np.zeros_like(ts), np.abs(ts),
                  np.where(ts >= 0, np.pi, 0.0))
        ax.semilogy(np.degrees(ts), np.maximum(f, 1e-6), label="model")
        if data is not None:
            sel = (np.abs(np.degrees(data.theta_i) - ti_deg) < 0.6) & (
                np.abs(np.sin(data.phi_s - data.phi_i)) < 0.05)
            sign = np.where(np.cos(data.phi_s[sel] - data.phi_i[sel]) < 0, 1, -1)
            ax.semilogy(sign * np.degrees(data.theta_s[sel]), np.maximum(data.brdf[sel], 1e-6),
                        ".", ms=3, label="data")
        ax.set(title=f"theta_i = {ti_deg} deg (in plane)", xlabel="theta_s (deg, + = forward)")
    axes[0].set_ylabel("BRDF (1/sr)")
    axes[0].legend()
    fig.suptitle(f"{args.model}: {meta['metrics'].get('model', '')}")
    out = args.output or str(Path(args.model).with_suffix(".png"))
    save_figure(fig, out)
    print(f"wrote {out}")
    return 0


def register_brdf(sub, add_device) -> None:
    b = sub.add_parser("brdf", help="fit, tabulate and plot BRDF models")
    bs = b.add_subparsers(dest="brdf_command", required=True)
    f = bs.add_parser("fit", help="fit a model to measured data (CSV or pbrt .brdf)")
    f.add_argument("data")
    f.add_argument("--model", required=True, choices=["mlp", "mlp-seed", "five-param",
                                                      "torrance-sparrow", "phong", "minnaert",
                                                      "lambert"])
    f.add_argument("-o", "--output", required=True)
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


def cmd_study(args) -> int:
    from dataclasses import replace

    from .study.run import StudyOptions, run_study

    opts = StudyOptions() if args.full else StudyOptions.quick()
    if args.n_dataset is not None:
        opts.n_dataset = args.n_dataset
    if args.method is not None:
        opts.grid = replace(opts.grid, method=args.method)
    opts.labels = args.labels
    res = run_study(Path(args.output), opts.validate(), workers=args.workers,
                    scheduler=args.scheduler, device=args.device)
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
    print(f"wrote {Path(args.output) / 'report.html'} and results.json")
    return 0


def register_study(sub, add_device) -> None:
    s = sub.add_parser("study", help="the material study (main job)")
    g = s.add_mutually_exclusive_group()
    g.add_argument("--quick", action="store_true", help="built-in default: 200 dataset "
                   "samples, 48 ps bins, 50 iterations (under 3 minutes on 2 cores)")
    g.add_argument("--full", action="store_true", help="1000 dataset samples, 32 ps bins, "
                   "100 iterations, 2 noise seeds per sweep point")
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
    s.add_argument("--n-dataset", type=int, default=None, help=argparse_suppress())
    add_device(s)
    s.set_defaults(func=cmd_study)


def argparse_suppress():
    import argparse

    return argparse.SUPPRESS


def cmd_bench(args) -> int:
    """Thin front of :func:`clnlos.bench.main` (runs from an installed package)."""
    from .bench import main as bench_main

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
    g.add_argument("--tiny", action="store_true", help=argparse_suppress())
    b.add_argument("-o", "--output", default="out/bench")
    b.add_argument("--only", default=None, help="comma-separated sections (diffusion, "
                   "lightcone, brdf, forward, reconstruction, iterative, end_to_end)")
    add_device(b)
    b.set_defaults(func=cmd_bench)
