"""BRDF fit -> texture -> simulation -> reconstruction: fit an analytic model to a measured
BRDF (the MERL aluminium set of ../shared/data/brdf), tabulate it as the texture the kernels
read, simulate a target of that material behind the slab and reconstruct it assuming a
Lambertian target and assuming the fitted texture (the BRDF-aware iterative inversion).

    python docs/examples/brdf_texture.py [--small] [--out DIR] [--data ../shared/data]

The CLI form: `clnlos brdf fit DATA.csv --model five-param -o m.h5`, `clnlos brdf texture m.h5
-o tex.h5`, a scene with `material = "tex.h5"`, `clnlos reconstruct ... --method iterative
--brdf tex.h5`. Without the measured data the script says so and exits with status 0.
"""

import argparse
import sys
import tempfile
import time
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import clnlos  # noqa: E402
from clnlos.brdf.fit import fit_to_file  # noqa: E402
from clnlos.brdf.plot import in_plane, read_samples  # noqa: E402
from clnlos.brdf.store import load_model  # noqa: E402
from clnlos.brdf.texture import tabulate, write_texture  # noqa: E402
from clnlos.study.score.legibility import glyph_templates, identify  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
parser = argparse.ArgumentParser()
parser.add_argument("--small", action="store_true", help="a 12 x 12 scan (the tests)")
parser.add_argument("--out", type=Path, default=Path(__file__).parent / "figures")
parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
args = parser.parse_args()

measured = args.data / "brdf" / "merl_nbrdf_aluminium_G_gonio.csv"
if not measured.is_file():
    print(f"{measured}: not present (see the README of ../shared/data/brdf)")
    sys.exit(0)

with tempfile.TemporaryDirectory() as tmp:
    tmp = Path(tmp)
    samples = read_samples(measured)
    t0 = time.perf_counter()
    metrics = fit_to_file("five-param", samples, None, tmp / "model.h5", seed=0)
    print(f"fitted five-param to {len(samples.brdf)} samples in "
          f"{time.perf_counter() - t0:.1f} s (log-space RMS {metrics['log_rms']:.2f}, "
          f"agreement {metrics['train_agreement_pct']:.0f}%)")
    model, _ = load_model(tmp / "model.h5")
    n = 32 if args.small else 64
    texture = tabulate(model, n, n, 256, provenance={"model_file": "model.h5"})
    write_texture(tmp / "aluminium.h5", texture)
    print(f"texture {texture.shape} [theta_i, theta_s, dphi], retro slice {len(texture.retro)}")

    points = 12 if args.small else 24
    scene = {"seed": 2,
             "scan": {"width_m": 0.4, "points": points},
             "time": {"bin_width_s": 16e-12, "bins": 300},
             "objects": [{"shape": "letters", "text": "H", "height_m": 0.2, "stroke_m": 0.05,
                          "translate_m": [0.0, 0.0, 0.4],
                          "material": str(tmp / "aluminium.h5")}],
             "slab": {"thickness_m": 0.0254, "mu_a": 0.53, "mu_s_prime": 262.0, "n": 1.12},
             "detector": {"power_w": 0.4, "exposure_s": 0.1}}
    t0 = time.perf_counter()
    capture = clnlos.simulate(scene)
    print(f"simulated {capture.transient.shape} in {time.perf_counter() - t0:.1f} s")
    sc = clnlos.api.load_scene(scene)
    obj = sc.objects[0]
    # the study's identification: the MIP matched to the 8 candidate glyphs' true coverages
    # (Pearson r, best over 1-cell shifts); it never sees which glyph is true
    templates = glyph_templates(obj.height_m, obj.stroke_m, obj.translate_m[:2],
                                sc.scan_centres(), lateral_fwhm_m=0.0)
    recs = {}
    for brdf in ("lambertian", str(tmp / "aluminium.h5")):
        t0 = time.perf_counter()
        rec = clnlos.reconstruct(capture, method="iterative", brdf=brdf,
                                 iterations=40 if args.small else 150)
        name = "Lambertian" if brdf == "lambertian" else "fitted texture"
        glyph, margin, scores = identify(rec.volume.max(axis=0), templates)
        verdict = (f"read as '{glyph}' (r {scores[glyph]:.2f}, 'H' r {scores['H']:.2f}, "
                   f"margin {margin:.2f})")
        recs[name] = (rec, verdict)
        print(f"iterative assuming {name}: {verdict}, {time.perf_counter() - t0:.1f} s")

fig, axes = plt.subplots(1, 3, figsize=(12.5, 3.8), layout="constrained")
ts = np.radians(np.linspace(-85, 85, 341))
for ti_deg, colour in ((30, "C0"), (60, "C1")):
    ti = np.radians(ti_deg)
    theta = np.abs(ts)
    phi = np.where(ts >= 0, np.pi, 0.0)  # + = forward (the mirror side)
    f = model(np.full_like(ts, ti), np.zeros_like(ts), theta, phi)
    axes[0].semilogy(np.degrees(ts), f, colour, label=f"fit, theta_i {ti_deg} deg")
    s, v = in_plane(samples, ti_deg)
    axes[0].semilogy(s, v, ".", color=colour, ms=3, label="measured")
axes[0].set(xlabel="theta_s (deg, + forward)", ylabel="BRDF (1/sr)",
            title="MERL aluminium: five-param fit")
axes[0].legend(fontsize=7)
for ax, (name, (rec, verdict)) in zip(axes[1:], recs.items(), strict=True):
    clnlos.plot_volume(rec, ax)
    ax.set_title(f"assuming {name}:\n{verdict}", fontsize=9)
args.out.mkdir(parents=True, exist_ok=True)
fig.savefig(args.out / "brdf_texture.png", dpi=80)
print(f"wrote {args.out / 'brdf_texture.png'}")
