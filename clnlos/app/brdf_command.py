"""``clnlos brdf``: fit, tabulate, plot and score BRDF models (thin fronts over
:mod:`clnlos.brdf`)."""

from __future__ import annotations

import warnings
from pathlib import Path

from tqdm import tqdm

from clnlos.app.flags import add_force, require
from clnlos.brdf.data import CSV_COLUMNS, MERL_GONIO_DEG
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
from clnlos.brdf.fit import (
    AUTO,
    AUTO_CANDIDATES,
    AUTO_VALIDATION_FRACTION,
    MLP_MODELS,
    USABLE_AGREEMENT_PCT,
    USABLE_PEAK_RATIO,
    auto_line,
    fit_to_file,
    quality_line,
)
from clnlos.brdf.models import model_spec
from clnlos.brdf.plot import brdf_figure, read_samples
from clnlos.brdf.store import FitQualityWarning, fit_warning, load_model
from clnlos.brdf.texture import MAX_NODES, MIN_NODES, tabulate, write_texture
from clnlos.checks import integer
from clnlos.errors import ParameterError
from clnlos.io.files import save_figure
from clnlos.io.outputs import HDF5_SUFFIXES, check_outputs
from clnlos.io.progress import counter, progress_bar

BRDF_MODELS = ["mlp", "mlp-seed", "five-param", "torrance-sparrow", "phong", "minnaert",
               "lambert"]
FIT_MODELS = [*BRDF_MODELS, AUTO]


def cmd_brdf_fit(args) -> int:
    candidates = tuple(args.candidates or AUTO_CANDIDATES)
    if args.candidates and args.model != AUTO:
        raise ParameterError("--candidates", " ".join(args.candidates), "only with --model "
                             "auto")
    neural = [m for m in ((args.model,) if args.model != AUTO else candidates)
              if m in MLP_MODELS]
    if neural:
        require("torch", f"brdf fit --model {args.model}"
                + (f" --candidates ... {neural[0]}" if args.model == AUTO else ""))
    outs = {"-o": Path(args.output)}
    if args.metrics_json:
        outs["--metrics-json"] = Path(args.metrics_json)
    check_outputs(outs, inputs=[args.data, args.test], suffixes={"-o": HDF5_SUFFIXES})

    train = read_samples(args.data)
    test = read_samples(args.test, held_out=True) if args.test else None
    unit = ("fit" if args.model == AUTO else "epoch" if args.model in MLP_MODELS
            else "start")
    with progress_bar(None, f"brdf fit {args.model}", unit) as bar:
        metrics = fit_to_file(args.model, train, test, args.output, seed=args.seed,
                              metrics_json=args.metrics_json, progress=counter(bar),
                              candidates=candidates)
    for k, v in metrics.items():
        if k not in ("loss_log", "fit_quality", "auto"):
            print(f"{k}: {v:.4g}" if isinstance(v, float) else f"{k}: {v}")
    if "auto" in metrics:
        print(auto_line(metrics["auto"]))
    quality = metrics["fit_quality"]
    print(quality_line(metrics["model"], quality))
    if "warning" in quality:
        warnings.warn(quality["warning"], FitQualityWarning, stacklevel=1)
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
    warning = fit_warning(meta.get("metrics", {}), args.model)
    if warning:  # said now, and carried in the texture for what uses it
        warnings.warn(warning, FitQualityWarning, stacklevel=1)
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


def brdf_arguments(b, add_device) -> None:
    """The arguments of ``clnlos brdf`` (its sub-commands) on the parser ``b``."""
    bs = b.add_subparsers(dest="brdf_command", required=True)
    f = bs.add_parser("fit", help="fit a model to measured data (CSV, pbrt .brdf or MERL "
                      ".binary); prints its held-out agreement and peak error and warns when "
                      "the fit is not usable")
    data = (f"measured samples: CSV with columns {','.join(CSV_COLUMNS)} (angles in degrees, "
            "BRDF in 1/sr; # comment lines), pbrt-v2 .brdf or MERL .binary (its green "
            f"channel sampled at incidence {', '.join(f'{a:g}' for a in MERL_GONIO_DEG)} deg)")
    f.add_argument("data", help=data)
    f.add_argument("--model", required=True, choices=FIT_MODELS,
                   help="mlp: the peak-keeping neural BRDF; mlp-seed: the seed's MLP recipe "
                        "(both need torch); five-param, torrance-sparrow, phong, minnaert, "
                        "lambert: analytic models fitted by least squares in log space; auto: "
                        "fit every --candidates model on the training data less "
                        f"{AUTO_VALIDATION_FRACTION * 100:g}%% held out, keep the one that "
                        "agrees best with that part, fit it again on all of it")
    f.add_argument("--candidates", nargs="+", choices=BRDF_MODELS, metavar="MODEL",
                   help="--model auto: the models it tries, of " + ", ".join(BRDF_MODELS)
                        + " (default " + " ".join(AUTO_CANDIDATES) + "; add mlp for the "
                        "neural BRDF, about 100 s per fit on 2 CPU cores)")
    f.add_argument("-o", "--output", required=True, help="fitted model (.h5)")
    f.add_argument("--test", help="held-out data (same formats; a MERL .binary is sampled at "
                   "random directions) for the test metrics, which judge the fit (usable: "
                   f"agreement >= {USABLE_AGREEMENT_PCT:g}%% and the peak within a factor "
                   f"{USABLE_PEAK_RATIO:g}) (default: none, judged on the training data)")
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
    add_force(p)
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
    add_force(e)
    e.set_defaults(func=cmd_brdf_evaluate)
