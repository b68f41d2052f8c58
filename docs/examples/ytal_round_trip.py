"""A y-tal round trip: a simulated capture written in y-tal's HDF5 layout (what
`tal.io.read_capture` reads: `H`, `sensor_grid_xyz`, `delta_t` and `t_start` in metres of
path, `scene_info`), read back by clnlos.read_capture and reconstructed; the volume is
compared with the one of the capture in clnlos's own format.

    python docs/examples/ytal_round_trip.py [--small] [--out DIR]
"""

import argparse
import tempfile
import time
from pathlib import Path

import h5py
import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import clnlos  # noqa: E402
from clnlos.io.files import write_capture  # noqa: E402
from clnlos.io.formats.tal import write_tal  # noqa: E402

parser = argparse.ArgumentParser()
parser.add_argument("--small", action="store_true", help="12 x 12 scan points (the tests)")
parser.add_argument("--out", type=Path, default=Path(__file__).parent / "figures")
args = parser.parse_args()

points = 12 if args.small else 32
scene = {"seed": 1,
         "scan": {"width_m": 0.4, "points": points},
         "time": {"bin_width_s": 16e-12, "bins": 320},
         "objects": [{"shape": "letters", "text": "T", "height_m": 0.2, "stroke_m": 0.05,
                      "translate_m": [0.0, 0.0, 0.45]}],
         "slab": {"thickness_m": 0.0254, "mu_a": 0.53, "mu_s_prime": 262.0, "n": 1.12},
         "detector": {"power_w": 0.4, "exposure_s": 0.1}}  # photon counts
t0 = time.perf_counter()
capture = clnlos.simulate(scene)
print(f"simulated {capture.transient.shape} photon counts in {time.perf_counter() - t0:.1f} s")

with tempfile.TemporaryDirectory() as tmp:
    tal_path, own_path = Path(tmp) / "capture_tal.h5", Path(tmp) / "capture.h5"
    write_tal(tal_path, capture.transient, bin_width_s=capture.bin_width_s,
              start_s=capture.start_s, scan_width_m=capture.scan_width_m,
              scene_info={"original_format": "clnlos",
                          "clnlos": {k: v for k, v in capture.attrs.items()
                                     if isinstance(v, str | int | float)}})
    write_capture(own_path, capture.transient, bin_width_s=capture.bin_width_s,
                  start_s=capture.start_s, scan_width_m=capture.scan_width_m,
                  attrs=capture.attrs)
    with h5py.File(tal_path) as f:
        print("y-tal file:", ", ".join(f"{k} {f[k].shape}" for k in sorted(f)))
    from_tal = clnlos.read_capture(tal_path)
    from_own = clnlos.read_capture(own_path)

print(f"y-tal capture: bins of {from_tal.bin_width_s * 1e12:.1f} ps, scan "
      f"{from_tal.scan_width_m:.3f} m, slab recorded: {from_tal.recorded_slab() is not None}")
recs = {}
for name, cap in (("clnlos format", from_own), ("y-tal format", from_tal)):
    t0 = time.perf_counter()
    recs[name] = clnlos.reconstruct(cap, method="lct", snr_rule="gcv")
    print(f"{name}: LCT in {time.perf_counter() - t0:.1f} s, slab SNR "
          f"{recs[name].params['snr_used']:.3g}")
a, b = recs["clnlos format"].volume, recs["y-tal format"].volume
diff = float(np.max(np.abs(a - b)) / np.max(a))
print(f"largest difference of the two volumes: {diff:.2e} of the maximum")

fig, axes = plt.subplots(1, 3, figsize=(12, 3.8), layout="constrained")
clnlos.plot_volume(recs["clnlos format"], axes[0])
axes[0].set_title("from the clnlos capture")
clnlos.plot_volume(recs["y-tal format"], axes[1])
axes[1].set_title("from the y-tal capture")
clnlos.plot_volume(recs["y-tal format"], axes[2], view="depth")
axes[2].set_title(f"depth; max |difference| {diff:.1e}")
args.out.mkdir(parents=True, exist_ok=True)
fig.savefig(args.out / "ytal_round_trip.png", dpi=80)
print(f"wrote {args.out / 'ytal_round_trip.png'}")
