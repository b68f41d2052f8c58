"""Run a study file and keep its answer as a committed result: the plan's rows and the real
check's (tools/results/<name>.json, with the command, the commit and the study file's text;
the report, with the real captures beside their twins, stays in the study's folder).

    .venv/bin/python tools/study_rig.py examples/studies/lct_rig.toml [-o out/lct_rig]
    .venv/bin/python tools/study_rig.py examples/studies/cdt_rig.toml
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import clnlos.study as study_pkg
from clnlos.io.outputs import provenance, stamp
from clnlos.study.file.spec import load_study

OUT = Path(__file__).resolve().parent / "results"
KEEP = ("study", "source", "study_file", "options", "materials_prepared", "left_out", "plan",
        "smallest_legible_letter", "real_check", "real_check_summary", "timings_s")


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("study", type=Path)
    ap.add_argument("-o", "--output", type=Path, default=None,
                    help="the study's folder (default out/<file name>)")
    ap.add_argument("--workers", type=int, default=None)
    args = ap.parse_args(argv)
    study = load_study(args.study)
    name = args.study.stem
    out = args.output or Path("out") / name
    res = study_pkg.run(out, study=study, workers=args.workers)
    kept = {k: res.get(k) for k in KEEP}
    kept["provenance"] = {**provenance(),
                          "command": "python tools/study_rig.py " + " ".join(sys.argv[1:])}
    (OUT / f"{name}.json").write_text(json.dumps(stamp(kept), indent=1))
    for r in res.get("real_check") or ():
        bound = "" if r["ratio_bound"] is None else f" ({r['ratio_bound']})"
        print(f"{r['name']:28s} measured {r['photons_needed_measured']:.3g} predicted "
              f"{r['photons_needed_predicted']:.3g} ratio {r['ratio']:.2f}{bound}")
    print(f"wrote {OUT / (name + '.json')} (the report: {out / 'report.html'})")
    return kept


if __name__ == "__main__":
    main()
