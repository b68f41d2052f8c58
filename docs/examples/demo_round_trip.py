"""Demo round trip: simulate "UT" 0.5 m behind the CDT slab, reconstruct it with the three
methods, score each against the true letters and draw them (the Python form of `clnlos demo`).

    python docs/examples/demo_round_trip.py [--small] [--out DIR]
"""

import argparse
import time
import tomllib
from importlib.resources import files
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import clnlos  # noqa: E402
from clnlos.study.score.metrics import letters_truth_mask, mip_iou  # noqa: E402

parser = argparse.ArgumentParser()
parser.add_argument("--small", action="store_true", help="16 x 16 scan points (the tests)")
parser.add_argument("--out", type=Path, default=Path(__file__).parent / "figures")
args = parser.parse_args()

data = files("clnlos").joinpath("data")
scene = tomllib.loads(data.joinpath("demo_scene.toml").read_text())  # the built-in scene
if args.small:
    scene["scan"]["points"] = 16
config = tomllib.loads(data.joinpath("demo_reconstruct.toml").read_text())

scene = clnlos.api.load_scene(scene)  # the typed, validated Scene
t0 = time.perf_counter()
capture = clnlos.simulate(scene)  # noise-free, the slab recorded in the capture
print(f"simulated {capture.transient.shape} [t, y, x] in {time.perf_counter() - t0:.1f} s")

letters = scene.objects[0]
truth = letters_truth_mask(letters.text, letters.height_m, letters.stroke_m,
                           letters.translate_m[:2], scene.scan_centres())

fig, axes = plt.subplots(2, 3, figsize=(11, 6.5), layout="constrained")
for col, method in enumerate(("lct", "fk", "iterative")):
    options = {"iterations": 60} if method == "iterative" else {}
    t0 = time.perf_counter()
    rec = clnlos.reconstruct(capture, method=method, config=config, **options)
    seconds = time.perf_counter() - t0
    iou, _ = mip_iou(rec.volume, truth)
    print(f"{method}: IoU {iou:.2f}, {seconds:.1f} s; {rec.notes[0]}")
    clnlos.plot_volume(rec, axes[0, col])
    axes[0, col].set_title(f"{method}: max over depth (IoU {iou:.2f})")
    clnlos.plot_volume(rec, axes[1, col], view="xz")
fig.suptitle(f'"{letters.text}" {letters.translate_m[2]} m behind the 2.54 cm slab, '
             f"{scene.points} x {scene.points} scan")
args.out.mkdir(parents=True, exist_ok=True)
fig.savefig(args.out / "demo_round_trip.png", dpi=80)
print(f"wrote {args.out / 'demo_round_trip.png'}")
