"""The BRDF-aware light-cone transport against ``clnlos simulate`` of the same glyph.

Per material and tilt: no slab (confocal transport), and behind the CDT slab under the
confocal (Eq. 9) and bistatic (Eq. 8) transports, the transport with the Lambertian lobe,
with the material's, and (behind the slab) with the material's widened by the slab's
footprint (clnlos.bench.brdf_inversion, docs/brdf.md). Writes
tools/results/brdf_operator_check.csv and .json (the JSON with the command and provenance).

    .venv/bin/python tools/brdf_operator_check.py [--materials A,B] [--device D]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from clnlos.io.progress import progress_bar
from clnlos.bench.brdf_inversion import CHECK_MATERIALS, operator_check_rows
from clnlos.bench.harness import print_table, write_rows
from clnlos.io.files import atomic_path
from clnlos.io.outputs import provenance
from clnlos.runtime.device import get_queue

OUT = Path(__file__).resolve().parent / "results"
COLUMNS = ["material", "tilt_deg", "slab", "transport", "model_lobe", "footprint_rms_m",
           "terms", "rel_l2_image", "rel_l2_transient"]


def main(argv=None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--materials", default=",".join(CHECK_MATERIALS))
    ap.add_argument("--device", default=None)
    args = ap.parse_args(argv)
    q = get_queue(args.device)
    with progress_bar(None, "scenes", "scene") as bar:
        def step(k, n, what):
            bar.total = n
            bar.n = k
            bar.set_postfix_str(what)

        rows = operator_check_rows(q, materials=args.materials.split(","), progress=step)
    csv_path, json_path = write_rows(rows, OUT, "brdf_operator_check")
    doc = {"command": " ".join(["tools/brdf_operator_check.py", *sys.argv[1:]]),
           "provenance": provenance(device=q.device.name.strip()), "rows": rows}
    with atomic_path(json_path) as tmp:
        tmp.write_text(json.dumps(doc, indent=1))
    print_table(rows, COLUMNS)
    print(f"wrote {csv_path} and {json_path}")
    return rows


if __name__ == "__main__":
    main()
