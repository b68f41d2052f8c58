"""``clnlos study [STUDY.toml]``: a study file end to end (a thin front over
:func:`clnlos.study.run`); ``--quick`` / ``--full`` the built-in studies, ``--init FILE``
writes one out to start from. The only command that imports the study, scipy.stats and
torch."""

from __future__ import annotations

import argparse
from pathlib import Path

import clnlos.study as study_pkg  # the package (callable; study_pkg.run: the function)
from clnlos.app.flags import add_force, require
from clnlos.checks import integer
from clnlos.errors import InputFileError, OutputFileError
from clnlos.inverse.methods import method_names
from clnlos.io.files import atomic_path
from clnlos.io.outputs import check_outputs
from clnlos.study.file.spec import LABELS, builtin_text, load_study
from clnlos.study.findings.summary import need_text
from clnlos.study.samples.render import MAX_WORKERS, check_scheduler_address

TRANSPORT_CHOICES = ("confocal", "both")


def cmd_study(args) -> int:
    if args.init is not None:
        return write_study(args)
    if args.workers is not None:
        integer("--workers", args.workers, 1, MAX_WORKERS)
    if args.scheduler is not None:
        check_scheduler_address("--scheduler", args.scheduler)
    name = args.study or ("full" if args.full else "quick")
    if args.study and (args.quick or args.full):
        raise InputFileError(f"{args.study}: a study file and --quick / --full: give one")
    study = load_study(name)  # every key checked before any work
    if args.labels not in (None, "legibility") or (
            study.classifier is not None and study.classifier.labels != "legibility"):
        require("torch", "clnlos study with the seed recipe's CNN (--labels fft / nr)")
    if args.scheduler is not None or (args.workers or 2) > 1:
        require("distributed", "clnlos study with worker processes")
    out = Path(args.output)
    outs = {"-o report.html": out / "report.html", "-o results.json": out / "results.json"}
    check_outputs(outs, implied=dict.fromkeys(outs), force=args.force,
                  inputs=[p for p in (study.source,) if p and Path(p).is_file()])
    if args.real_data is not None and not args.real_data.is_dir():  # not after the minutes
        raise InputFileError(f"--real-data {args.real_data}: "
                             + ("not a folder" if args.real_data.exists()
                                else "no such folder"))
    res = study_pkg.run(out, study=study, method=args.method, labels=args.labels,
                        real_data=args.real_data, transport=args.transport,
                        n_dataset=args.n_dataset, workers=args.workers,
                        scheduler=args.scheduler, device=args.device)
    print_answer(res)
    print(f"wrote {out / 'report.html'} and results.json")
    return 0


def print_answer(res: dict) -> None:
    """The answer on the terminal: the plan's rows, the real check, the table's summary."""
    for r in res["plan"]:
        at = "".join(f", {k} {v:g}" for k, v in r["at"].items())
        print(f"{r['material']:28s} {r['target']:14s}{at} {r['method']:9s} "
              f"{r['reflectance']:10s} {need_text(r)}{'  (best)' if r.get('best') else ''}")
    for r in res.get("real_check") or ():
        bound = "" if r["ratio_bound"] is None else f" ({r['ratio_bound']})"
        print(f"real {r['name']}: photons needed measured {r['photons_needed_measured']:.3g}, "
              f"predicted {r['photons_needed_predicted']:.3g}, ratio {r['ratio']:.2f}{bound}")
    for geo in res.get("geometries", ()):
        print(f"geometry {geo['name']}: {geo['description']}; stroke / resolution "
              f"{geo['stroke_over_resolution']:.2f}")
        for m in geo["materials"]:
            i = m["identification"]
            print(f"  {m['name']:36s} {m['brdf_class']:26s} identification "
                  f"{i['accuracy']:.2f} [{i['ci'][0]:.2f}, {i['ci'][1]:.2f}] (chance "
                  f"{i['chance']:.3f}, n {i['n']}) IoU {m['iou']:.3f} (box "
                  f"{m['iou_box_baseline']:.3f}) label {m['label']} CNN {m['cnn_label']} "
                  f"seed {m['seed_label']}")
    splits = res.get("classifier", {}).get("splits", {})
    if splits:
        print(f"labels {res['labels']['source']}; legibility judge on held-out splits: "
              + "; ".join(f"{k} balanced accuracy {v['balanced_accuracy']:.3f} (one-feature "
                          f"baseline {v['baseline']:.3f}), AUC {v['auc']:.3f}, ECE "
                          f"{v['ece']:.3f}" for k, v in splits.items()))
    print(res["findings"]["statement"])


def write_study(args) -> int:
    """``--init FILE``: a study file to start from (the planner's template, or with
    ``--quick`` / ``--full`` the built-in study); never over an existing file without
    --force."""
    out = Path(args.init)
    if out.exists() and not args.force:
        raise OutputFileError(f"--init {out}: exists (add --force to replace it)")
    text = builtin_text("full" if args.full else "quick" if args.quick else "template")
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out) as tmp:
        tmp.write_text(text, encoding="utf-8")
    print(f"wrote {out} (edit it, then run: clnlos study {out})")
    return 0


def study_arguments(s, add_device) -> None:
    """The arguments of ``clnlos study`` on the parser ``s``."""
    s.add_argument("study", nargs="?", default=None, metavar="STUDY.toml",
                   help="a study file: the rig, materials, targets, sweeps and inversions "
                        "(docs/study-file.md; --init writes one to start from); default the "
                        "quick study")
    g = s.add_mutually_exclusive_group()
    g.add_argument("--quick", action="store_true", help="the built-in quick study "
                   "(clnlos/data/study_quick.toml, the default: the seed's ten materials, "
                   "about 5 minutes on 2 cores)")
    g.add_argument("--full", action="store_true", help="the built-in full study "
                   "(clnlos/data/study_full.toml: every glyph, two realisations, the "
                   "bistatic comparison; about 70 minutes on 2 cores)")
    s.add_argument("--init", default=None, metavar="FILE",
                   help="write a study file to start from and stop: the exposure planner's "
                        "template (one material at two albedos, a letter at 1 m, no slab), "
                        "or with --quick / --full the built-in study (default: none, run a "
                        "study)")
    s.add_argument("-o", "--output", default="out/study",
                   help="output folder: report.html, results.json and the sample cache "
                        "(default %(default)s)")
    s.add_argument("--method", choices=list(method_names()), default=None,
                   help="every inversion by this method (default: the study file's)")
    s.add_argument("--labels", choices=list(LABELS), default=None,
                   help="what the table's CNN learns: legibility (ground truth), nr (the "
                        "no-reference metric) or fft (the seed's FFT clarity, the seed's "
                        "recipe) (default: the file's [classifier] labels, else legibility)")
    w = s.add_mutually_exclusive_group()
    w.add_argument("--workers", type=int, default=None,
                   help="local Dask worker processes (default: CPU count; 1 = serial)")
    w.add_argument("--scheduler", default=None, help="address of an existing Dask scheduler, "
                   "e.g. tcp://HOST:8786 (default: none, local workers)")
    s.add_argument("--real-data", type=Path, default=None, metavar="DIR",
                   help="folder whose cdt/ and lct/ hold the shared real captures: the "
                        "report adds them (photons a real target needs, the twins, the "
                        "judge on their thinning ladders); a folder without them is noted "
                        "and skipped (default: none)")
    s.add_argument("--transport", choices=list(TRANSPORT_CHOICES), default=None,
                   help="confocal: every sample with the seed's confocal transport (Eq. 9); "
                        "both: also the table's legible target under the bistatic transport "
                        "(Eq. 8 in full; needs a [table] and a [slab]) (default: the file's)")
    s.add_argument("--n-dataset", type=int, default=None, help=argparse.SUPPRESS)
    add_force(s)
    add_device(s)
    s.set_defaults(func=cmd_study)
