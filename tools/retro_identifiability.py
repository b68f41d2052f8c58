"""Can the data tell a retroreflective target from a diffuse one? Held-out photon scores of
the iterative inversion's reflectance models on the released light-cone captures.

For each capture in ``SHARED/lct`` (binned to 32 x 32 scan points and 32 ps to keep each
reconstruction to seconds), the counts are split binomially (clnlos.inverse.thinning), the
first half reconstructed by the iterative method with each lobe (50 iterations, the
``brdf = "auto"`` search's budget) and the second half predicted through the same lobe's
transport, less its background floor:

    CV = min_a ||y2 - a L_f rho_f||^2 / ||y2||^2

twice: from the whole volume (what ``brdf = "auto"`` scores) and from its brightest voxels
only, as many as the scan has points ("one surface's worth": a model that puts the light
where the target is explains the held-out half with few voxels; one that smears it needs
many). Lobes: the Lambertian voxel (signal ~ z^-4 cos^8 theta at scan angle theta on a
plane at depth z), the retroreflective preset (clnlos.physics.retroreflector: ~ z^-2
cos^4 theta g(theta), g its entrance-angle profile reaching zero at 39.5 deg), the same
sheeting with an acceptance of 85 deg (~ z^-2 cos^4 theta), and GGX lobes of the auto
ladder. Writes tools/results/retro_identifiability.{csv,json}; docs/brdf.md reads them.

    .venv/bin/python tools/retro_identifiability.py [--shared ../shared/data]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from pathlib import Path


ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "tools" / "results"
SCAN_POINTS = 32        # scan points per side at most after binning
BIN_WIDTH_S = 32e-12    # bins after binning (s)
SEARCH_ITERATIONS = 50  # iterations per half reconstruction (clnlos.inverse.brdf_choice)


def lobes():
    from clnlos.brdf.lobes import auto_ladder, named_lobe
    from clnlos.brdf.presets import RETROREFLECTIVE, retroreflector
    from clnlos.physics.lobe import RetroLobe

    wide = dataclasses.replace(retroreflector(RETROREFLECTIVE), acceptance_deg=85.0)
    ladder = auto_ladder()
    return [ladder[0], named_lobe(RETROREFLECTIVE),
            RetroLobe.retroreflector(wide, "retroreflective, acceptance 85 deg"),
            *ladder[1:3]]


def scores(path: Path) -> list[dict]:
    """One row per lobe: its held-out score from the whole volume and from its brightest
    voxels (module docstring)."""
    from clnlos.config import ReconstructionConfig
    from clnlos.inverse.brdf_choice import surface_of
    from clnlos.inverse.pipeline import ReconstructionPipeline
    from clnlos.inverse.preprocessing import resolve_geometry
    from clnlos.inverse.thinning import fitted_residual
    from clnlos.io.capture import without_direct
    from clnlos.io.files import read_capture
    from clnlos.runtime.device import get_queue
    from clnlos.study.judge.recipe import binned_laterally

    cap, _ = without_direct(binned_laterally(read_capture(path), SCAN_POINTS))
    bins = round(cap.transient.shape[0] * cap.bin_width_s / BIN_WIDTH_S)
    cfg = ReconstructionConfig(method="iterative", bins=bins, brdf="auto").validate()
    bw, start, sw = resolve_geometry(cap, cfg)
    queue = get_queue()
    pipe = ReconstructionPipeline(cap.transient.shape, bin_width_s=bw, start_s=start,
                                  scan_width_m=sw, config=cfg, queue=queue)
    train, test = pipe._split(cap.transient)
    held, _, _ = pipe._held_out_prediction_target(test)  # what brdf = "auto" scores
    rows = []
    for lobe in lobes():
        t0 = time.perf_counter()
        with pipe.invert.iteration_budget(SEARCH_ITERATIONS):
            rec = pipe.run(train, model_snr=math.inf, slab_snr_factor=1.0, lobe=lobe)
        v = rec.volume
        k = v.shape[1] * v.shape[2]
        top = surface_of(v)  # what brdf = "auto"'s surface score keeps
        rows.append({"capture": path.stem, "lobe": lobe.name,
                     "cv_volume": fitted_residual(pipe.invert.predict(v).get(), held),
                     "cv_brightest": fitted_residual(pipe.invert.predict(top).get(), held),
                     "voxels_kept": k, "seconds": time.perf_counter() - t0})
        print(" ".join(f"{a}={b:.4f}" if isinstance(b, float) else f"{a}={b}"
                       for a, b in rows[-1].items()), flush=True)
    return rows


def main(argv=None) -> int:
    from clnlos.bench.oracle import write_rows

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", default=str(ROOT.parent / "shared" / "data"))
    args = ap.parse_args(argv)
    files = sorted(Path(args.shared, "lct").glob("*.mat"))
    if not files:
        print(f"clnlos: error: no captures in {args.shared}/lct", file=sys.stderr)
        return 2
    rows = [r for f in files for r in scores(f)]
    for r in rows:  # the command that wrote them (write_rows adds the version and commit)
        r["command"] = "python tools/retro_identifiability.py"
    write_rows(rows, RESULTS / "retro_identifiability")
    for name in dict.fromkeys(r["capture"] for r in rows):
        mine = [r for r in rows if r["capture"] == name]
        best = {m: min(mine, key=lambda r: r[m])["lobe"] for m in ("cv_volume", "cv_brightest")}
        print(f"{name}: best by volume {best['cv_volume']}, by brightest {best['cv_brightest']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
