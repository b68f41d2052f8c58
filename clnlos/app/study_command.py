"""``clnlos study``: the material study (a thin front over :func:`clnlos.study.run`); the
only command that imports the study, scipy.stats and torch."""

from __future__ import annotations

import argparse
from pathlib import Path

import clnlos.study as study  # the package (study.run: the function)
from clnlos.app.flags import add_force, require
from clnlos.checks import integer
from clnlos.errors import InputFileError
from clnlos.inverse.methods import method_names
from clnlos.io.outputs import check_outputs
from clnlos.study.plan.scenes import StudyGrid
from clnlos.study.samples.render import MAX_WORKERS, check_scheduler_address
from clnlos.study.run import (
    LABEL_METRICS,
    TRANSPORT_CHOICES,
    StudyOptions,
)

def cmd_study(args) -> int:
    if args.workers is not None:
        integer("--workers", args.workers, 1, MAX_WORKERS)
    if args.scheduler is not None:
        check_scheduler_address("--scheduler", args.scheduler)
    if args.labels != "legibility":
        require("torch", f"clnlos study --labels {args.labels} (the seed recipe's CNN)")
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
    print(f"labels {res['labels']['source']}; legibility judge on held-out splits: " + "; ".join(
        f"{k} balanced accuracy {v['balanced_accuracy']:.3f} (one-feature baseline "
        f"{v['baseline']:.3f}), AUC {v['auc']:.3f}, ECE {v['ece']:.3f}"
        for k, v in res["classifier"]["splits"].items()))
    print(res["findings"]["statement"])
    print(f"wrote {out / 'report.html'} and results.json")
    return 0


def study_arguments(s, add_device) -> None:
    """The arguments of ``clnlos study`` on the parser ``s``."""
    quick, full = StudyOptions.quick(), StudyOptions()
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
    add_force(s)
    add_device(s)
    s.set_defaults(func=cmd_study)
