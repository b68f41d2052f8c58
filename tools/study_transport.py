"""The study's material table under both transports (confocal Eq. 9, bistatic Eq. 8): the
comparison stage of ``clnlos study --transport both`` on its own (clnlos.study.
transport_compare), writing tools/results/study_transport.{csv,json}.

It uses the quick study file (every glyph, one noise realisation, its table's legible
target), measures the lateral resolution as the study does (the glyph templates) and
shares the study's sample cache (default out/study/cache: a later ``clnlos study
--transport both -o out/study`` reads these samples from it, and this tool reads the
study's).

    PYTHONPATH=. .venv/bin/python tools/study_transport.py [--cache DIR] [--workers N]
        [--glyphs E H T U] [--rings 3 --angles 6] [--materials "quartz glass" --stem NAME]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from dataclasses import replace

from clnlos.bench.harness import print_table, write_rows
from clnlos.io.outputs import provenance, stamp
from clnlos.study.file.spec import TransportComparison, load_study
from clnlos.study.findings.transport import csv_rows
from clnlos.study.samples.identify import study_resolution
from clnlos.study.samples.materials import prepare_materials
from clnlos.study.sections import transport_comparison

OUT = Path(__file__).resolve().parent / "results"


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, default=Path("out/study/cache"))
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--glyphs", nargs="+", default=None, help="default: the study's")
    ap.add_argument("--rings", type=int, default=None)
    ap.add_argument("--angles", type=int, default=None)
    ap.add_argument("--materials", nargs="+", default=None, help="default: the ten presets")
    ap.add_argument("--stem", default="study_transport", help="results file name (default "
                    "%(default)s)")
    ap.add_argument("--device", default=None)
    args = ap.parse_args(argv)
    study = load_study("quick")
    tc = TransportComparison()
    tc = replace(tc, glyphs=tuple(args.glyphs) if args.glyphs else None,
                 face_rings=args.rings or tc.face_rings,
                 face_angles=args.angles or tc.face_angles)
    keep = [m for m in study.materials if not args.materials or m.name in args.materials]
    study = replace(study, transport=tc, materials=tuple(keep))
    mats, _ = prepare_materials(study, args.cache.parent)
    t0 = time.perf_counter()
    resolution, lateral = study_resolution(study, args.device)
    t_res = time.perf_counter() - t0
    t0 = time.perf_counter()
    out = transport_comparison(study, mats, args.cache, resolution, lateral,
                               workers=args.workers, device=args.device)
    seconds = time.perf_counter() - t0
    rows = csv_rows(out)
    summary = {k: v for k, v in out.items() if k not in ("plan", "results", "rows")}
    legible = study.table.legible_target
    meta = {"face_rings": tc.face_rings, "face_angles": tc.face_angles,
            "glyphs": list(tc.glyphs or study.target(legible).glyphs),
            "seeds": study.table.realisations, "geometry": legible,
            "lateral_fwhm_m": lateral[legible], "seconds_resolution": t_res,
            "seconds_samples": seconds, "samples": len(out["plan"])}
    csv_path, json_path = write_rows(rows, OUT, args.stem)
    # the JSON holds the rows and the summary (correlations, moves, statement)
    json_path.write_text(json.dumps(stamp({"provenance": provenance(), "rows": out["rows"],
                                         **summary, **meta}), indent=1))
    print_table(rows, ["material", "confocal_identification", "bistatic_identification",
                       "confocal_margin", "bistatic_margin", "confocal_rank", "bistatic_rank",
                       "counts_ratio"])
    print(out["statement"])
    print(f"wrote {csv_path} and {json_path} ({seconds:.0f} s for {len(out['plan'])} samples)")
    return out


if __name__ == "__main__":
    main()
