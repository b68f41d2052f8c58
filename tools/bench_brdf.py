#!/usr/bin/env python3
"""BRDF accuracy versus cost.

1. Measured materials (../shared/data/brdf when present): test-set agreement and relative
   error of the MLP (seed recipe), the MLP (improved recipe) and the five-parameter model,
   with training time -- the table of the BRDF issue.
2. Texture resolution vs interpolation error (against the model itself) vs lookup time on
   the device (image and buffer paths), and MLP evaluation cost vs texture lookup cost.

    python tools/bench_brdf.py [--device SPEC] [-o DIR] [--quick] [--data DIR]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import device_meta, print_table, timeit, write_rows  # noqa: E402

from clnlos.brdf.data import agreement, read_gonio_csv, relative_error  # noqa: E402
from clnlos.brdf.fit import fit_analytic  # noqa: E402
from clnlos.brdf.mlp import MLPConfig, train_mlp  # noqa: E402
from clnlos.brdf.models import BRDFModel  # noqa: E402
from clnlos.brdf.texture import TextureLookup, lookup_numpy, tabulate  # noqa: E402
from clnlos.runtime.device import get_queue  # noqa: E402

MEASURED = ["nist_ptfe_white_532nm", "pbrt_cayman_550nm", "pbrt_krylon_blue_550nm",
            "starlink_chassis_532nm"]


def measured_table(data: Path, quick: bool) -> list[dict]:
    rows = []
    for mat in MEASURED[:2] if quick else MEASURED:
        tr = read_gonio_csv(data / f"{mat}_gonio.csv")
        te = read_gonio_csv(data / f"{mat}_test.csv")
        t0 = time.perf_counter()
        r = fit_analytic("five-param", tr, te)
        rows.append({"table": "measured", "material": mat, "model": "five-param",
                     "test_agreement_pct": r.metrics["test_agreement_pct"],
                     "test_relative_error": r.metrics["test_relative_error"],
                     "train_agreement_pct": r.metrics["train_agreement_pct"],
                     "fit_s": time.perf_counter() - t0})
        for recipe in ("seed", "improved"):
            t0 = time.perf_counter()
            m, log = train_mlp(tr, MLPConfig(recipe=recipe, epochs=1000 if quick else 3000))
            secs = time.perf_counter() - t0
            p, ptr = (m(te.theta_i, te.phi_i, te.theta_s, te.phi_s),
                      m(tr.theta_i, tr.phi_i, tr.theta_s, tr.phi_s))
            rows.append({"table": "measured", "material": mat, "model": f"mlp-{recipe}",
                         "test_agreement_pct": agreement(p, te.brdf),
                         "test_relative_error": relative_error(p, te.brdf),
                         "train_agreement_pct": agreement(ptr, tr.brdf), "fit_s": secs,
                         "epochs": log["epochs_run"]})
    return rows


def texture_table(q, quick: bool) -> list[dict]:
    meta = device_meta(q)
    model = BRDFModel("microfacet", {"kd": 0.1, "ks": 1.0, "alpha": 0.2, "f0": 0.9})
    rng = np.random.default_rng(0)
    n = 200_000 if quick else 1_000_000
    a = np.column_stack([rng.uniform(0, 1.45, n), rng.uniform(-np.pi, np.pi, n),
                         rng.uniform(0, 1.45, n), rng.uniform(-np.pi, np.pi, n)])
    truth = model(*a.T)
    rows = []
    for res in (8, 16, 32, 64, 128):
        tex = tabulate(model, res, res, 64)
        err = relative_error(lookup_numpy(tex.texture, a[:50_000]), truth[:50_000])
        for path in ("buffer", "image"):
            if path == "image" and not q.device.image_support:
                continue
            lk = TextureLookup(tex, path=path, queue=q)
            t = timeit(lambda lk=lk: lk(a), q, repeat=3)
            rows.append({**meta, "table": "texture", "kernel": "brdf", "knob": "resolution",
                         "value": res, "path": path, "dtype": "float32", "queries": n,
                         "error": err, **t, "lookups_per_s": n / t["median_s"]})
    # MLP evaluation cost on the same queries
    fake = np.column_stack([rng.uniform(0, 1.4, 500), np.zeros(500), rng.uniform(0, 1.4, 500),
                            rng.uniform(0, np.pi, 500)])
    from clnlos.brdf.data import BRDFSamples

    s = BRDFSamples(*fake.T, model(*fake.T))
    mlp, _ = train_mlp(s, MLPConfig(epochs=300))
    t = timeit(lambda: mlp(*a.T), repeat=3)
    rows.append({**meta, "table": "texture", "kernel": "brdf", "knob": "mlp-eval",
                 "value": "torch-cpu", "path": "mlp", "dtype": "float32", "queries": n, **t,
                 "lookups_per_s": n / t["median_s"]})
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None)
    ap.add_argument("-o", "--out", default="out/bench", type=Path)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--data", type=Path,
                    default=Path(__file__).resolve().parents[2] / "shared" / "data" / "brdf")
    args = ap.parse_args(argv)
    q = get_queue(args.device)
    rows = texture_table(q, args.quick)
    print_table(rows, ["knob", "value", "path", "queries", "error", "median_s",
                       "lookups_per_s"])
    if args.data.is_dir():
        m = measured_table(args.data, args.quick)
        print_table(m, ["material", "model", "test_agreement_pct", "test_relative_error",
                        "train_agreement_pct", "fit_s"])
        rows += m
    else:
        print(f"no measured data at {args.data}: measured-material table skipped")
    p, _ = write_rows(rows, args.out, "bench_brdf")
    print(f"wrote {p}")


if __name__ == "__main__":
    main()
