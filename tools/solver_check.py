"""The iterative method's solver against the one it replaced, on the oracle captures: per
capture the IoU, iterations and time of the default solver (working-set steps, stopped by
the objective's relative decrease, :mod:`clnlos.inverse.solvers`) beside plain FISTA run
for 200 iterations (the solver and iteration count of before), both at GCV's slab pick on
one pipeline (the same plans): writes
tools/results/experiments/solver/solver_iterations.{csv,json} and prints the means.

    .venv/bin/python tools/solver_check.py [--device P:D] [--seeds 0 ...] [--holdout]
        [--tol T ...]   (more stopping tolerances beside the default)
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from clnlos.bench.oracle import HOLDOUT_CASES, ORACLE_CASES, simulate_case, write_rows
from clnlos.config import ReconstructionConfig
from clnlos.inverse.parameter_choice import model_snr_for
from clnlos.inverse.pipeline import ReconstructionPipeline
from clnlos.inverse.preprocessing import resolve_geometry
from clnlos.inverse.solvers import DEFAULT_TOL
from clnlos.study.score.metrics import mip_iou

RESULTS = Path(__file__).resolve().parent / "results" / "experiments" / "solver"
PLAIN_ITERATIONS = 200  # the iterations of before (the config's default, all of them run)


def variants(tols) -> list[tuple[str, dict]]:
    """(name, solver settings): plain FISTA for PLAIN_ITERATIONS, the default, other tols."""
    out = [("plain_200", {"working_set": False, "tol": 0.0}),
           ("default", {"working_set": True, "tol": DEFAULT_TOL})]
    return out + [(f"tol_{t:g}", {"working_set": True, "tol": t}) for t in tols
                  if t != DEFAULT_TOL]


def rows_for(case, seed: int, tols, queue=None) -> list[dict]:
    c = replace(case, seed=seed)
    cap, mask = simulate_case(c, queue)
    cfg = ReconstructionConfig(slab=cap.recorded_slab()[0], method="iterative",
                               snr_rule="gcv").validate()
    bw, start, sw = resolve_geometry(cap, cfg)
    pipe = ReconstructionPipeline(cap.transient.shape, bin_width_s=bw, start_s=start,
                                  scan_width_m=sw, config=cfg, queue=queue)
    solver = pipe.invert.solver
    pipe.run(cap.transient, model_snr=model_snr_for(cap, cfg))  # plans built
    out = []
    for name, settings in variants(tols):
        solver.working_set, solver.tol = settings["working_set"], settings["tol"]
        solver.iterations = PLAIN_ITERATIONS if name == "plain_200" else cfg.iterations
        t0, c0 = time.perf_counter(), time.process_time()
        rec = pipe.run(cap.transient, model_snr=model_snr_for(cap, cfg))
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        out.append({"capture": case.name, "seed": seed, "solver": name,
                    "iou": mip_iou(rec.volume, mask)[0],
                    "iterations": rec.solver["iterations"],
                    "solve_s": rec.timings_s["invert:iterative"], "wall_s": wall,
                    "cpu_s": cpu, "rounds": len(rec.solver.get("rounds", []))})
        print(f"{case.name} seed {seed} [{name}]: IoU {out[-1]['iou']:.3f}, "
              f"{out[-1]['iterations']} iterations, {wall:.1f} s", flush=True)
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--holdout", action="store_true", help="HOLDOUT_CASES (seed 1 default)")
    ap.add_argument("--tol", type=float, nargs="*", default=[])
    args = ap.parse_args(argv)
    cases = HOLDOUT_CASES if args.holdout else ORACLE_CASES
    rows = [r for case in cases for s in args.seeds
            for r in rows_for(case, s, args.tol, args.device)]
    stem = RESULTS / ("solver_iterations_holdout" if args.holdout else "solver_iterations")
    print("wrote", *write_rows(rows, stem))
    base = {(r["capture"], r["seed"]): r for r in rows if r["solver"] == "plain_200"}
    for name in dict.fromkeys(r["solver"] for r in rows):
        mine = [r for r in rows if r["solver"] == name]
        d = [r["iou"] - base[(r["capture"], r["seed"])]["iou"] for r in mine]
        t = [r["solve_s"] / base[(r["capture"], r["seed"])]["solve_s"] for r in mine]
        print(f"{name}: mean IoU {np.mean([r['iou'] for r in mine]):.4f} "
              f"({np.mean(d):+.4f} vs plain, worst {min(d):+.3f}), mean iterations "
              f"{np.mean([r['iterations'] for r in mine]):.0f}, solve time "
              f"{np.mean(t):.2f}x plain")


if __name__ == "__main__":
    main()
