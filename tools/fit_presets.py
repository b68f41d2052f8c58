#!/usr/bin/env python3
"""Build the ten material presets of the seed from the closest measured data (../shared).

Each preset is a Torrance-Sparrow (GGX microfacet + Lambertian) model fitted in log space to
the closest available measured set, or documented analytic parameters where no data is
close. Writes clnlos/brdf/presets.json (parameters, provenance, fit metrics): derived numbers
only, the data stay in ../shared.

    python tools/fit_presets.py [--data ../shared/data/brdf]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from clnlos.brdf.data import read_gonio_csv
from clnlos.brdf.fit import fit_analytic

ROOT = Path(__file__).resolve().parents[1]

# name -> (BRDF class, closest measured set or None, analytic parameters if None, note)
PLAN = {
    "gold-plated polyester film": ("strong specular", "merl_nbrdf_two-layer-gold_G", None,
                                   "MERL two-layer-gold (neural fit of MERL)"),
    "quartz glass": ("strong specular", None,
                     {"model": "microfacet", "kd": 0.0, "ks": 1.0, "alpha": 0.01, "f0": 0.04},
                     "analytic: smooth dielectric, n = 1.46 gives f0 = 0.035"),
    "aluminium alloy sample": ("strong specular", "merl_nbrdf_aluminium_G", None,
                               "MERL aluminium (neural fit of MERL)"),
    "painted steel plate": ("strong specular + diffuse", "pbrt_cayman_550nm", None,
                            "Cornell/pbrt Cayman metallic car paint, 550 nm (measured)"),
    "black anode plate": ("strong specular + diffuse", "merl_nbrdf_black-oxidized-steel_G",
                          None, "MERL black-oxidized-steel (neural fit of MERL)"),
    "fuchsia lacquer board": ("strong specular + diffuse", "pbrt_krylon_blue_550nm", None,
                              "Cornell/pbrt Krylon glossy spray paint, 550 nm (measured)"),
    "aluminium diffuse reflection plate": ("strong diffuse", None,
                                           {"model": "microfacet", "kd": 0.25, "ks": 0.6,
                                            "alpha": 0.45, "f0": 0.9},
                                           "analytic: rough (alpha 0.45) metal with diffuse"),
    "glass fibre": ("strong diffuse", "merl_nbrdf_white-fabric_G", None,
                    "MERL white-fabric (neural fit of MERL)"),
    "standard white plate": ("Lambertian", "nist_ptfe_white_532nm", None,
                             "NIST sintered PTFE, 532 nm (measured, Germer 2017)"),
    "cement board": ("Lambertian", None, {"model": "minnaert", "kd": 0.35, "k": 1.0},
                     "analytic: Lambertian, reflectance 0.35 (typical fibre cement)"),
}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data" / "brdf")
    args = ap.parse_args(argv)
    out = {}
    for name, (cls, data_id, analytic, note) in PLAN.items():
        if data_id is None:
            out[name] = {"class": cls, "model": analytic, "provenance": note}
            continue
        tr = read_gonio_csv(args.data / f"{data_id}_gonio.csv")
        te = read_gonio_csv(args.data / f"{data_id}_test.csv")
        r = fit_analytic("torrance-sparrow", tr, te)
        out[name] = {"class": cls,
                     "model": {"model": "microfacet", **r.metrics["params"],
                               **{k: v for k, v in r.metrics["fixed"].items()}},
                     "provenance": f"{note}; fitted to {data_id}_gonio.csv",
                     "test_agreement_pct": r.metrics["test_agreement_pct"],
                     "test_relative_error": r.metrics["test_relative_error"]}
        print(f"{name:36s} {cls:28s} agreement {r.metrics['test_agreement_pct']:.1f}%")
    path = ROOT / "clnlos" / "brdf" / "presets.json"
    path.write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
