"""``clnlos bench``: what accuracy costs in time -- every accuracy knob of every kernel.

Each knob's error is measured against a float64 high-accuracy reference computed in the same
run on the same device; times are medians over repeats after a warm-up (queue.finish() around
each run). Baselines (vectorised numpy float64, torch CPU for the reconstruction) run beside
them and are reported as ratios. A trivial copy kernel gives the device's memory bandwidth,
and the bandwidth-bound stages are reported as a fraction of it.

Writes DIR/bench.json (one row per measurement) and DIR/bench.html (Pareto plots of error
against time per kernel, and a table of recommended settings). Runs from an installed
package (``clnlos bench``, or ``python -m clnlos.bench``): the one benchmark system (the former
``tools/bench_*.py`` scripts are its sections ``lightcone_grid``, ``blur_reach``,
``brdf_measured`` and ``reconstruction_process``; the committed run is
``tools/results/bench.json``).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from clnlos.bench.harness import Bench, print_table
from clnlos.bench.report import recommendations, write_html
from clnlos.bench.sections import (
    bench_auto_params,
    bench_auto_params_cost,
    bench_bistatic,
    bench_blur_reach,
    bench_brdf,
    bench_brdf_measured,
    bench_diffusion,
    bench_end_to_end,
    bench_iterative,
    bench_lightcone,
    bench_lightcone_grid,
    bench_model_level,
    bench_reconstruction,
    bench_reconstruction_process,
    bench_roofline,
)
from clnlos.bench.brdf_inversion import inversion_rows, iteration_rows, operator_rows
from clnlos.checks import choice
from clnlos.io.outputs import stamp, write_group
from clnlos.runtime.device import get_queue

SECTIONS = {"diffusion": bench_diffusion, "lightcone": bench_lightcone,
            "lightcone_grid": bench_lightcone_grid, "brdf": bench_brdf,
            "brdf_measured": bench_brdf_measured, "forward": bench_model_level,
            "blur_reach": bench_blur_reach, "bistatic": bench_bistatic,
            "reconstruction": bench_reconstruction,
            "reconstruction_process": bench_reconstruction_process,
            "iterative": bench_iterative, "end_to_end": bench_end_to_end,
            "auto_params": bench_auto_params, "auto_params_cost": bench_auto_params_cost,
            "brdf_operator": operator_rows, "brdf_inversion": inversion_rows,
            "brdf_iteration": iteration_rows}
ONLY_HELP = "comma-separated sections: " + ", ".join(SECTIONS)


def sections_of(only: str) -> list[str]:
    """The section names of a comma-separated ``--only``, each checked (ParameterError)."""
    return [choice("--only", name.strip(), tuple(SECTIONS)) for name in only.split(",")]


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None)
    ap.add_argument("-o", "--out", default="out/bench", type=Path)
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--quick", action="store_true", help="about 6 minutes on 2 CPU cores")
    g.add_argument("--tiny", action="store_true", help="seconds; for tests")
    ap.add_argument("--only", default=",".join(SECTIONS), help=ONLY_HELP + " (default: all)")
    ap.add_argument("--brdf-data", default=None, type=Path,
                    help="measured BRDFs of brdf_measured (default: none, those rows skipped)")
    ap.add_argument("--real-data", default=None, type=Path,
                    help="folder holding the released captures (lct/data_s_u.mat) of "
                         "auto_params_cost (default: none, those rows skipped)")
    args = ap.parse_args(argv)
    sections = sections_of(args.only)  # all checked before the first one runs
    b = Bench(get_queue(args.device), "tiny" if args.tiny else "quick" if args.quick else "full")
    b.options["brdf_data"] = args.brdf_data
    b.options["real_data"] = args.real_data
    t0 = time.perf_counter()
    section_s = {}
    for name in sections:
        print(f"== {name}", flush=True)
        t1 = time.perf_counter()
        SECTIONS[name](b)
        section_s[name] = time.perf_counter() - t1
        print(f"   {name}: {section_s[name]:.1f} s", flush=True)
    bw = bench_roofline(b)
    for r in b.rows:  # ratios against the baselines of the same kernel/knob/value
        base = [x for x in b.rows if x["impl"] in ("numpy", "torch") and
                (x["kernel"], x["knob"], x["value"]) == (r["kernel"], r["knob"], r["value"])]
        for x in base:
            r[f"speedup_vs_{x['impl']}"] = x["median_s"] / r["median_s"]
    recs = recommendations(b.rows)
    doc = {"meta": b.meta, "size": b.size, "seconds": time.perf_counter() - t0,
           "copy_bandwidth_gbs": bw / 1e9, "rows": b.rows, "recommendations": recs,
           "section_seconds": section_s, "notes": b.notes}
    with write_group([args.out / "bench.json", args.out / "bench.html"]) as (tmp_j, tmp_h):
        tmp_j.write_text(json.dumps(stamp(doc), indent=1, default=str), encoding="utf-8")
        write_html(tmp_h, b.rows, recs, b.meta, bw, b.notes)
    print_table(b.rows, ["kernel", "knob", "value", "dtype", "impl", "median_s", "error"])
    for note in b.notes:
        print(f"note: {note}")
    print(f"wrote {args.out / 'bench.json'} and bench.html in {doc['seconds']:.1f} s")
    return doc
