"""The material question on the real captures (clnlos.study.real.materials) with the full or
the quick plan, outside the study: photons needed per capture x inversion x reflectance,
the diffuse/retroreflective S ratio, the charts' resolution. Writes
tools/results/real_materials.json (the section, with the command and commit) and
real_materials.png (reference front views and scores against photons).

    .venv/bin/python tools/real_materials.py [--shared ../shared/data] [--quick]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "tools" / "results"


def main(argv=None) -> int:
    from tqdm import tqdm

    from clnlos.io.files import atomic_path, save_figure_file
    from clnlos.io.outputs import provenance, stamp
    from clnlos.study.real.materials import (
        RealPlan,
        real_capture_paths,
        real_materials,
        section_figure,
    )
    from clnlos.study.samples.resolution import json_ready

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", default=str(ROOT.parent / "shared" / "data"))
    ap.add_argument("--quick", action="store_true", help="the quick study's plan")
    args = ap.parse_args(argv)
    plan = RealPlan.quick() if args.quick else RealPlan()
    if not real_capture_paths(Path(args.shared)):
        raise SystemExit(f"no shared capture under {args.shared}")
    with tqdm(total=None, desc="real materials", unit="reconstruction") as bar:
        section = real_materials(Path(args.shared), plan, progress=bar.update)
    RESULTS.mkdir(parents=True, exist_ok=True)
    save_figure_file(section_figure(section), RESULTS / "real_materials.png")
    with atomic_path(RESULTS / "real_materials.json") as tmp:
        doc = {"provenance": {**provenance(), "command": "python tools/real_materials.py"
                              + (" --quick" if args.quick else "")}, **json_ready(section)}
        Path(tmp).write_text(json.dumps(stamp(doc), indent=1))
    for h in section["headline"]:
        print(json.dumps(h))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
