"""``clnlos bench``: accuracy versus time of every kernel knob (a thin front over
:func:`clnlos.bench.main`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from clnlos.app.flags import add_force
from clnlos.bench import ONLY_HELP, sections_of
from clnlos.bench import main as bench_main
from clnlos.io.outputs import check_outputs

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
        ["--brdf-data", args.brdf_data] if args.brdf_data else []) + (
        ["--real-data", args.real_data] if args.real_data else [])
    bench_main(argv)
    return 0


def bench_arguments(b, add_device) -> None:
    """The arguments of ``clnlos bench`` on the parser ``b``."""
    g = b.add_mutually_exclusive_group()
    g.add_argument("--quick", action="store_true", help="about 6 minutes on 2 CPU cores")
    g.add_argument("--tiny", action="store_true", help=argparse.SUPPRESS)
    b.add_argument("-o", "--output", default="out/bench",
                   help="output folder: bench.json and bench.html (default %(default)s)")
    b.add_argument("--only", default=None, help=ONLY_HELP + " (default: all)")
    b.add_argument("--brdf-data", default=None, metavar="DIR",
                   help="folder of measured BRDFs (*_gonio.csv) for the brdf_measured section "
                        "(default: none, those rows skipped with a note)")
    b.add_argument("--real-data", default=None, metavar="DIR",
                   help="folder holding the released LCT capture lct/data_s_u.mat (the "
                        "data folder the study's --real-data takes) for auto_params_cost's "
                        "rows on real counts "
                        "(default: none, those rows skipped with a note)")
    add_force(b)
    add_device(b)
    b.set_defaults(func=cmd_bench)
