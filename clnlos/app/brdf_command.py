"""``clnlos brdf``: fit, tabulate, plot and score BRDF models (thin fronts over
:mod:`clnlos.brdf`)."""

from __future__ import annotations

from pathlib import Path

from tqdm import tqdm

from clnlos.app.flags import add_force, require
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
from clnlos.errors import ParameterError
from clnlos.io.files import save_figure
from clnlos.io.outputs import HDF5_SUFFIXES, check_outputs
from clnlos.io.progress import counter, progress_bar

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


def brdf_arguments(b, add_device) -> None:
    """The arguments of ``clnlos brdf`` (its sub-commands) on the parser ``b``."""
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
