"""``clnlos legibility FILE... --model STUDY_DIR``: P(legible) of captures or reconstructions by
a study's trained judge (:mod:`clnlos.study.judge.apply`)."""

from __future__ import annotations

import json
from pathlib import Path

from clnlos.errors import InputFileError
from clnlos.study.judge.apply import judge_from, legibility


def cmd_legibility(args) -> int:
    judge = judge_from(args.model)  # a missing or foreign judge: one error line, no work
    missing = [f for f in args.files if not Path(f).is_file()]
    if missing:
        raise InputFileError(f"{missing[0]}: no such file")
    for f in args.files:
        v = legibility(f, judge, device=args.device)
        print(json.dumps({"file": f, "p_legible": v.p_legible, "model": v.kind,
                          "features": v.features}) if args.json else v.line(), flush=True)
    return 0


def legibility_arguments(g, add_device) -> None:
    """The arguments of ``clnlos legibility`` on the parser ``g``."""
    g.add_argument("files", nargs="+", metavar="FILE",
                   help="a volume .h5 (any method, grid or size) or a capture in any format "
                        "clnlos reads (reconstructed as the judge was trained, with two "
                        "binomial halves of its photons)")
    g.add_argument("--model", required=True, metavar="STUDY_DIR",
                   help="a study output folder holding judge.json (or the judge.json itself)")
    g.add_argument("--json", action="store_true",
                   help="one JSON object per line: file, p_legible, model, features")
    add_device(g)
    g.set_defaults(func=cmd_legibility)
