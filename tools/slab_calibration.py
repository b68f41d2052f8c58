#!/usr/bin/env python3
"""Fit the slab diffusion model to the real CDT calibration captures (1.0 ... 8.0 inches).

    .venv/bin/python tools/slab_calibration.py [--shared ../shared/data]

Reads ``<shared>/cdt/calibration`` (exits with a message when absent) and writes
``tools/results/slab_calibration.csv`` (one row per thickness and fit), ``.json`` (the same
plus the joint fits and the n profiles) and ``.png``. Fits (clnlos.forward.calibration):

* ``published``: mu_s', mu_a, n held at the authors' values, only t0 and amplitude free;
* ``per_thickness``: mu_s', mu_a fitted per capture at the published n;
* ``per_thickness_best_n``: the same at the n of N_GRID with the lowest residual;
* ``joint``: mu_s', mu_a shared by all captures (one t0 each) at the published n, and the
  joint n profile over N_GRID (as the authors did: a joint fit per n).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
OUT = ROOT / "tools" / "results"
STEM = "slab_calibration"
FIG_THICKNESSES = (1.0, 2.0, 4.0, 6.0, 8.0)  # inches plotted in the curve panel
COLUMNS = ("fit", "thickness_inch", "mu_s_prime", "mu_a", "n", "t0_ps", "residual",
           "rise_residual", "tail_residual", "half_rise_ps", "peak_ps", "ratio_at_rise_10",
           "tail_rate_ratio")


def _row(cal, kind, th, fit, i, m, irf):
    curve = cal.model_curve(fit.slab(i), m.s_s, irf.kernel, fit.t0_s[i])
    return {"fit": kind, "thickness_inch": th, "mu_s_prime": fit.mu_s_prime,
            "mu_a": fit.mu_a, "n": fit.n, "t0_ps": fit.t0_s[i] * 1e12,
            "residual": fit.residual[i], **cal.departures(m, curve)}


def _summary(fit):
    return {"mu_s_prime": fit.mu_s_prime, "mu_a": fit.mu_a, "n": fit.n,
            "residual_all": fit.residual_all, "residual": list(fit.residual),
            "t0_ps": [v * 1e12 for v in fit.t0_s], "nfev": fit.nfev, "success": fit.success}


def run(cal, data: Path) -> dict:
    """All fits; returns {"rows": [...], "joint": ..., "joint_n_profile": [...], ...}."""
    irf, meas = cal.load_captures(data)
    pub = cal.PUBLISHED
    rows, per_n = [], {}
    for th, m in zip(cal.THICKNESSES_INCH, meas, strict=True):
        t = time.perf_counter()
        p = cal.fit_slab([m], irf, fit_mu=False, mu_s_prime=pub.mu_s_prime, mu_a=pub.mu_a)
        rows.append(_row(cal, "published", th, p, 0, m, irf))
        prof = cal.n_profile([m], irf)
        per_n[th] = [_summary(f) for f in prof]
        best = min(prof, key=lambda f: f.residual_all)
        f = next((g for g in prof if g.n == pub.n), None) or cal.fit_slab([m], irf, n=pub.n)
        rows.append(_row(cal, "per_thickness", th, f, 0, m, irf))
        rows.append(_row(cal, "per_thickness_best_n", th, best, 0, m, irf))
        print(f"{th:.1f} in: mu_s' {f.mu_s_prime:7.1f} mu_a {f.mu_a:6.3f} res {f.residual[0]:.4f}"
              f" | best n {best.n:.2f}: mu_s' {best.mu_s_prime:7.1f} res {best.residual[0]:.4f}"
              f" | published res {p.residual[0]:.4f} ({time.perf_counter() - t:.1f} s)",
              flush=True)
    joint = cal.fit_slab(meas, irf, n=pub.n)
    for i, (th, m) in enumerate(zip(cal.THICKNESSES_INCH, meas, strict=True)):
        rows.append(_row(cal, "joint", th, joint, i, m, irf))
    print(f"joint (n {pub.n}): mu_s' {joint.mu_s_prime:.1f} mu_a {joint.mu_a:.3f} "
          f"res {joint.residual_all:.4f}", flush=True)
    jprof = cal.n_profile(meas, irf)
    for f in jprof:
        print(f"joint n {f.n:.2f}: mu_s' {f.mu_s_prime:.1f} mu_a {f.mu_a:.3f} "
              f"res {f.residual_all:.4f}", flush=True)
    return {"rows": rows, "joint": _summary(joint),
            "joint_n_profile": [_summary(f) for f in jprof],
            "per_thickness_n_profile": {str(k): v for k, v in per_n.items()},
            "published": {"mu_s_prime": pub.mu_s_prime, "mu_a": pub.mu_a, "n": pub.n},
            "irf": {"onset_bin": irf.onset, "bins": len(irf.kernel)},
            "_meas": meas, "_irf": irf, "_joint": joint}


def figure(cal, res, path: Path) -> None:
    """Curves (data and joint fit, log scale), fitted mu_s' and mu_a per thickness, residuals."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(15, 4.5), layout="constrained")
    ax = fig.subplots(1, 4)
    meas, irf, joint = res["_meas"], res["_irf"], res["_joint"]
    for i, (th, m) in enumerate(zip(cal.THICKNESSES_INCH, meas, strict=True)):
        if th not in FIG_THICKNESSES:
            continue
        c = cal.model_curve(joint.slab(i), m.s_s, irf.kernel, joint.t0_s[i])
        line, = ax[0].semilogy(m.s_s * 1e9, m.y, ".", ms=1.5, label=f"data {th:g} in")
        ax[0].semilogy(m.s_s * 1e9, joint.amplitude[i] * c, "-", color=line.get_color(), lw=1,
                       label=f"joint fit {th:g} in")
    ax[0].set(xlabel="time since entry s (ns)", ylabel="counts / max", ylim=(1e-4, 1.5),
              xlim=(0, 30), title="transmittance: data and joint fit")
    ax[0].legend(fontsize=6, ncol=2)
    rows = res["rows"]
    pub = res["published"]
    for kind, mk in (("per_thickness", "o"), ("per_thickness_best_n", "s"), ("joint", "-")):
        sel = [r for r in rows if r["fit"] == kind]
        x = [r["thickness_inch"] for r in sel]
        ax[1].plot(x, [r["mu_s_prime"] for r in sel], mk, label=kind)
        ax[2].plot(x, [r["mu_a"] for r in sel], mk, label=kind)
    for kind, mk in (("published", "x"), ("per_thickness", "o"), ("joint", "-")):
        sel = [r for r in rows if r["fit"] == kind]
        ax[3].semilogy([r["thickness_inch"] for r in sel], [r["residual"] for r in sel], mk,
                       label=kind)
    ax[1].axhline(pub["mu_s_prime"], color="k", ls=":", label="published")
    ax[2].axhline(pub["mu_a"], color="k", ls=":", label="published")
    ax[1].set(xlabel="slab thickness (inch)", ylabel="mu_s' (1/m)", title="reduced scattering")
    ax[2].set(xlabel="slab thickness (inch)", ylabel="mu_a (1/m)", title="absorption")
    ax[3].set(xlabel="slab thickness (inch)", ylabel="||A m - y|| / ||y||",
              title="relative residual")
    for a in ax[1:]:
        a.legend(fontsize=7)
    fig.savefig(path, dpi=100, format="png")


def main(argv=None) -> int:
    from clnlos.forward import calibration as cal
    from clnlos.io.outputs import provenance, stamp, write_group

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", default=str(SHARED), help="the shared data folder")
    data = Path(ap.parse_args(argv).shared) / "cdt" / "calibration"
    if not data.is_dir():
        print(f"slab_calibration: {data} not present, nothing to do", file=sys.stderr)
        return 0
    res = run(cal, data)
    paths = [OUT / f"{STEM}.csv", OUT / f"{STEM}.json", OUT / f"{STEM}.png"]
    with write_group(paths) as (csv_p, json_p, png_p):
        lines = [",".join(COLUMNS)]
        lines += [",".join(f"{r[c]:.6g}" if isinstance(r[c], float) else str(r[c])
                           for c in COLUMNS) for r in res["rows"]]
        csv_p.write_text("\n".join(lines) + "\n")
        json_p.write_text(json.dumps(stamp({"provenance": provenance(), **{
            k: v for k, v in res.items() if not k.startswith("_")}}),
                                     indent=1, default=float) + "\n")
        figure(cal, res, png_p)
    for p in paths:
        print(f"wrote {p}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
