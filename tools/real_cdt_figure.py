"""Reconstruct the shared real CDT captures with LCT, f-k and the iterative method and save
their max-intensity projections side by side (docs/figures/real_cdt_methods.png).

    .venv/bin/python tools/real_cdt_figure.py [--shared ../shared/data] [-o PNG]

Each capture uses its published parameters (examples/cdt_letters_ut.toml,
examples/cdt_letter_s.toml); only the method changes.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CAPTURES = (("letters_ut.mat", "cdt_letters_ut.toml"), ("letter_s.mat", "cdt_letter_s.toml"))
METHODS = ("lct", "fk", "iterative")


def main() -> int:
    from matplotlib.figure import Figure

    from clnlos.config import ReconstructionConfig
    from clnlos.inverse.pipeline import reconstruct
    from clnlos.io.files import read_capture

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", default=str(ROOT.parent / "shared" / "data"))
    ap.add_argument("-o", "--output", default=str(ROOT / "docs" / "figures" /
                                                  "real_cdt_methods.png"))
    a = ap.parse_args()
    fig = Figure(figsize=(4.2 * len(METHODS), 3.8 * len(CAPTURES)), layout="constrained")
    axes = fig.subplots(len(CAPTURES), len(METHODS), squeeze=False)
    for i, (cap_name, cfg_name) in enumerate(CAPTURES):
        cap = read_capture(Path(a.shared) / "cdt" / cap_name)
        base = ReconstructionConfig.from_toml(ROOT / "examples" / cfg_name)
        for j, method in enumerate(METHODS):
            cfg = base.replace(method=method).validate()
            t0 = time.perf_counter()
            rec = reconstruct(cap, cfg)
            dt = time.perf_counter() - t0
            mip = rec.volume.max(axis=0)
            e = rec.extents
            ext = (e["x_min_m"], e["x_max_m"], e["y_min_m"], e["y_max_m"])
            im = axes[i, j].imshow(mip / max(mip.max(), 1e-30), origin="lower", cmap="gray",
                                   extent=ext)
            axes[i, j].set(title=f"{cap_name}: {method} ({dt:.1f} s)", xlabel="x (m)",
                           ylabel="y (m)")
            fig.colorbar(im, ax=axes[i, j], label="MIP / max", shrink=0.85)
            print(f"{cap_name} {method}: {dt:.2f} s", flush=True)
    fig.savefig(a.output, dpi=90)
    print(f"wrote {a.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
