"""Face-sample convergence of the bistatic transport at the study's legible geometry.

The noise-free capture (no detector) of one glyph ('E', 0.3 m tall, 8 cm strokes, 0.5 m behind
the CDT slab, 0.6 m scan of 32 x 32 points, 48 ps bins, 35 ps pulse: the study's grid) under
``[transport] model = "bistatic"`` with increasing face samples (rings x angles), each against
the finest: total-signal ratio, relative L2 of the transient and of its time integral (the
image identification keys on), and seconds. Writes tools/results/study_transport_faces.{csv,json}.

    .venv/bin/python tools/study_transport_faces.py [--materials "quartz glass" ...]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from clnlos.bench.harness import print_table, write_rows
from clnlos.forward.model import ForwardModel
from clnlos.forward.scene import Scene
from clnlos.runtime.device import get_queue
from clnlos.study.file.spec import StudyGrid, load_study
from clnlos.study.plan.entries import MaterialKeys, target_sample
from clnlos.study.plan.scenes import scene_dict

OUT = Path(__file__).resolve().parent / "results"
FACES = ((1, 4), (2, 4), (2, 8), (3, 6), (4, 8))
MATERIALS = ("quartz glass", "aluminium alloy sample", "standard white plate")


def noise_free(sample: dict, grid: StudyGrid, queue) -> tuple[np.ndarray, float]:
    d = scene_dict(sample, grid)
    d.pop("detector")
    t0 = time.perf_counter()
    tau = ForwardModel(Scene.from_dict(d), queue=queue).run()
    return tau.astype(np.float64), time.perf_counter() - t0


def _rel(a, b) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def main(argv=None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--materials", nargs="+", default=list(MATERIALS))
    ap.add_argument("--faces", nargs="+", default=None, metavar="RxA",
                    help="face samples (default 1x4 2x4 2x8 3x6 4x8; the last is the reference)")
    ap.add_argument("--device", default=None)
    args = ap.parse_args(argv)
    q = get_queue(args.device)
    grid = StudyGrid()
    quick = load_study("quick")
    target = quick.target(quick.table.legible_target)
    rows = []
    for m in args.materials:
        s = target_sample(target, "E", MaterialKeys(m, {"material": m}, m), exposure_s=0.1,
                          seed=0, method=grid.method, brdf={}, scan_width_m=grid.scan_width_m)
        conf, t_conf = noise_free(s, grid, q)
        runs = {}
        faces = [tuple(int(v) for v in f.split("x")) for f in args.faces] if args.faces \
            else FACES
        for r, a in faces:
            runs[(r, a)] = noise_free({**s, "transport": {"model": "bistatic", "face_rings": r,
                                                          "face_angles": a}}, grid, q)
        ref = runs[faces[-1]][0]
        for (r, a), (tau, sec) in [(("confocal", ""), (conf, t_conf)), *runs.items()]:
            rows.append({"material": m, "rings": r, "angles": a,
                         "face_samples": "" if r == "confocal" else r * a,
                         "total_ratio": float(tau.sum() / ref.sum()),
                         "rel_l2": _rel(tau, ref),
                         "rel_l2_image": _rel(tau.sum(axis=0), ref.sum(axis=0)),
                         "seconds": sec, "reference": f"bistatic {faces[-1][0]}x{faces[-1][1]}"})
        print_table([x for x in rows if x["material"] == m],
                    ["material", "rings", "angles", "total_ratio", "rel_l2", "rel_l2_image",
                     "seconds"])
        csv_path, json_path = write_rows(rows, OUT, "study_transport_faces")  # each material
        print(f"wrote {csv_path} and {json_path}", flush=True)
    return rows


if __name__ == "__main__":
    main()
