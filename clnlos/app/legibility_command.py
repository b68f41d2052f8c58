"""``clnlos legibility FILE... [--model STUDY_DIR]``: P(legible) of captures or reconstructions
by the judge shipped with clnlos or a study's own (:mod:`clnlos.study.judge.apply`)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from clnlos.app.commands import SLAB_FLAGS, config_from_args
from clnlos.app.flags import add_slab_flags
from clnlos.errors import InputFileError
from clnlos.study.judge.apply import judge_from, legibility


def cmd_legibility(args) -> int:
    judge = judge_from(args.model)  # a missing or foreign judge: one error line, no work
    options = config_from_args(args) if given_options(args) else None
    missing = [f for f in args.files if not Path(f).is_file()]
    if missing:
        raise InputFileError(f"{missing[0]}: no such file")
    for f in args.files:
        v = legibility(f, judge, config=options, no_slab=args.no_slab, device=args.device)
        if args.json:
            print(json.dumps(v.as_json()), flush=True)
            continue
        print(v.line(), flush=True)
        for note in v.notes:
            print(f"clnlos: note: {f}: outside the judge's domain: {note}", file=sys.stderr)
    return 0


OPTION_DESTS = ("config", "scan_width", "bin_width", "direct_cut", "max_path", "bins",
                *SLAB_FLAGS)


def given_options(args) -> bool:
    """Whether the user gave any reconstruction option (a config or a flag)."""
    return any(getattr(args, d, None) is not None for d in OPTION_DESTS)


def legibility_arguments(g, add_device) -> None:
    """The arguments of ``clnlos legibility`` on the parser ``g``."""
    g.add_argument("files", nargs="+", metavar="FILE",
                   help="a volume .h5 (any method, grid or size) or a capture in any format "
                        "clnlos reads (reconstructed as the judge was trained, with two "
                        "binomial halves of its photons)")
    g.add_argument("--model", default=None, metavar="STUDY_DIR",
                   help="a study output folder holding judge.json (or the judge.json itself) "
                        "(default: the judge shipped with clnlos)")
    g.add_argument("--json", action="store_true",
                   help="one JSON object per line: file, p_legible, interval, notes (what "
                        "lies outside the judge's training domain), model, judge, "
                        "descriptors, features")
    from_file = "(default: from the capture file, else the config's [capture])"
    g.add_argument("--config", help="a reconstruction TOML: the capture's geometry, window "
                   "and slab are taken from it, the judge's own method and SNR rule run "
                   "(default: none, what the capture file records)")
    g.add_argument("--scan-width", type=float, help=f"side of the scanned area along x (m) "
                   f"{from_file}")
    g.add_argument("--bin-width", type=float, help=f"histogram bin width (s) {from_file}")
    g.add_argument("--direct-cut", type=float,
                   help="zero the window before this round-trip time (s) (default: what the "
                        "capture records)")
    g.add_argument("--max-path", type=float,
                   help="keep round-trip path lengths c t below this (m) (default: the whole "
                        "window)")
    g.add_argument("--bins", type=int, help="rebin the kept window to this many bins "
                   "(default: at most the judge's 256)")
    add_slab_flags(g, "(default: the config's [slab], else the slab a clnlos capture "
                      "recorded)", "no slab deconvolution (also of a slab the capture recorded)")
    add_device(g)
    g.set_defaults(func=cmd_legibility, method=None)
