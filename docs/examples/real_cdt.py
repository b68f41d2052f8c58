"""A real CDT capture (Lindell & Wetzstein 2020, letters "UT" behind a 2.54 cm slab) read and
reconstructed from Python: the published parameters against the automatic ones.

    python docs/examples/real_cdt.py [--small] [--out DIR] [--data ../shared/data]

The capture is not part of clnlos: it comes from the authors' repository (see the README of
../shared/data/cdt). Without it the script says so and exits with status 0.
"""

import argparse
import sys
import time
import tomllib
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import clnlos  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
parser = argparse.ArgumentParser()
parser.add_argument("--small", action="store_true", help="LCT only (the tests)")
parser.add_argument("--out", type=Path, default=Path(__file__).parent / "figures")
parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
args = parser.parse_args()

path = args.data / "cdt" / "letters_ut.mat"
if not path.is_file():
    print(f"{path}: not present (get it from computational-imaging/confocal-diffuse-tomography)")
    sys.exit(0)
capture = clnlos.read_capture(path)
print(f"read {path.name}: {capture.transient.shape} [t, y, x], bins of "
      f"{capture.bin_width_s * 1e12:.0f} ps (no scan width stored: the config gives it)")

published = tomllib.loads((ROOT / "examples" / "cdt_letters_ut.toml").read_text())
automatic = {k: v for k, v in published.items() if k != "deconvolution"}  # slab SNR "auto"
automatic["inversion"] = {"method": "lct"}                                # light cone "auto"
methods = ("lct",) if args.small else ("lct", "fk", "iterative")
fig, axes = plt.subplots(2, len(methods), figsize=(3.8 * len(methods), 6.5),
                         layout="constrained", squeeze=False)
for col, method in enumerate(methods):
    for row, (name, config) in enumerate((("published SNRs", published),
                                          ("automatic SNRs", automatic))):
        options = {"iterations": 100} if method == "iterative" else {}
        if method != "lct":  # keys only LCT reads
            config = {**config, "inversion": {"method": method}}
        t0 = time.perf_counter()
        rec = clnlos.reconstruct(capture, method=method, config=config, **options)
        print(f"{method}, {name}: slab SNR {rec.params['snr_used']:.3g} "
              f"({rec.params.get('snr_rule_used', 'as given')}), "
              f"{time.perf_counter() - t0:.1f} s")
        clnlos.plot_volume(rec, axes[row, col], gamma=0.7)
        axes[row, col].set_title(f"{method}, {name}\nslab SNR {rec.params['snr_used']:.3g}")
fig.suptitle("letters_ut.mat (Lindell & Wetzstein 2020): max over depth")
args.out.mkdir(parents=True, exist_ok=True)
fig.savefig(args.out / "real_cdt.png", dpi=80)
print(f"wrote {args.out / 'real_cdt.png'}")
