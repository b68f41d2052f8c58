"""The cold 128 x 128 x 512 photon-count reconstruction's peak memory, stage by stage (issue 49).

The bench's end-to-end capture (:func:`clnlos.bench.sections.end_to_end_scene`) made photon
counts (:data:`clnlos.bench.sections.END_TO_END_PHOTONS`, no slab recorded: GCV's slab SNR
and the light cone's UPRE with its noise probe), reconstructed cold by each method with the
default rules in a fresh process of its own (:mod:`clnlos.bench.cold_process`, the worker of
the bench's ``reconstruct@cold,photons`` rows): one r2c + c2r FFT pair of the padded grid
timed first (its buffers freed), then VmHWM reset and one cold run. Per method: FFT pairs,
CPU seconds of the process, peak resident memory (on PoCL it includes the device buffers),
and the peak VmRSS sampled during each stage the volume's timings name (``plan and set-up``
before the first, ``after X`` between X and the next).

    python tools/cold_memory.py [--grid 128 512] [--methods lct,fk] [--noise-free]
                                [--code DIR [--code-label TEXT]] [-o FILE]

``--code DIR`` runs the reconstructions with the package in DIR (an export of another
commit: a before/after comparison on the same capture); the capture is simulated once.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grid", type=int, nargs=2, default=(128, 512), metavar=("N", "NT"))
    ap.add_argument("--methods", default="lct,fk")
    ap.add_argument("--code", help="the package's folder for the reconstructions")
    ap.add_argument("--code-label", help="what --code holds (recorded: e.g. 'git archive "
                    "236ca5d')")
    ap.add_argument("--noise-free", action="store_true",
                    help="the expected transient itself, not photon counts")
    ap.add_argument("-o", "--output", help="JSON file of the rows (default: print them)")
    a = ap.parse_args(argv)
    if a.code and not (Path(a.code) / "clnlos" / "__init__.py").is_file():
        print(f"clnlos: error: --code {a.code}: not a folder holding the clnlos package "
              "(clnlos/__init__.py)", file=sys.stderr)
        return 2
    from clnlos.bench.cold_process import cold_rows
    from clnlos.bench.sections import (
        END_TO_END_PHOTONS,
        end_to_end_config,
        end_to_end_scene,
        photon_capture,
    )
    from clnlos.forward.model import ForwardModel
    from clnlos.io.capture import Capture
    from clnlos.io.outputs import provenance

    n, nt = a.grid
    scene = end_to_end_scene(n, nt)
    tau = ForwardModel(scene).run()
    cap = (Capture(tau, scene.bin_width_s, 0.0, scene.width_m) if a.noise_free
           else photon_capture(tau, scene, END_TO_END_PHOTONS))
    cfg = end_to_end_config(nt)
    env = dict(os.environ)
    if a.code:  # the other version first on the workers' path
        env["PYTHONPATH"] = os.pathsep.join([a.code] + [p for p in [env.get("PYTHONPATH")]
                                                        if p])
    rows = cold_rows(cap, a.methods.split(","), cfg.max_path_m, cfg.bins, code=a.code,
                     env=env)
    for row in rows:
        print(json.dumps(row), flush=True)
    if a.output:
        doc = {"provenance": {**provenance(), "command": "python tools/cold_memory.py "
                              + " ".join(argv if argv is not None else sys.argv[1:])},
               "grid": [n, n, nt], "photons": None if a.noise_free else END_TO_END_PHOTONS,
               "code": a.code_label or a.code or "this checkout", "rows": rows}
        tmp = Path(a.output).with_suffix(".tmp")
        tmp.write_text(json.dumps(doc, indent=1))
        tmp.replace(a.output)
    return 0


if __name__ == "__main__":
    sys.exit(main())
