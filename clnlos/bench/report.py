"""The benchmark report: recommended settings and an HTML page with Pareto plots."""

from __future__ import annotations

import base64
import html
import io
import json
from pathlib import Path

from clnlos.io.outputs import HTML_GENERATOR


# ------------------------------------------------------------------ report
def recommendations(rows) -> list[dict]:
    """For each kernel knob and target error, the cheapest OpenCL setting reaching it."""
    out = []
    groups = {}
    for r in rows:
        if r["impl"] == "opencl" and r["error"] is not None and r["kernel"] != "roofline":
            # a grid size is a different problem, not a knob: there, only the dtype is chosen
            per_value = r["kernel"] in ("reconstruction", "end_to_end") or r["knob"] == "grid"
            key = (r["kernel"], f"{r['knob']}={r['value']}" if per_value else r["knob"])
            groups.setdefault(key, []).append(r)
    for (kern, knob), rs in groups.items():
        for target in (0.1, 0.01, 1e-4):
            ok = [r for r in rs if r["error"] <= target]
            if ok:
                best = min(ok, key=lambda r: r["median_s"])
                out.append({"kernel": kern, "knob": knob, "target_error": target,
                            "value": best["value"], "dtype": best["dtype"],
                            "seconds": best["median_s"], "error": best["error"]})
    return out


def _png(fig) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=85, bbox_inches="tight")
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def write_html(path: Path, rows, recs, meta, bw, notes=()):
    """Write the report page to ``path`` (not atomic: :func:`clnlos.bench.main` writes it
    to a temporary of its group)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    parts = [f"<h1>clnlos: what accuracy costs in time</h1><p>Device {html.escape(meta['device'])}"
             f" ({html.escape(meta['platform'])}, driver {html.escape(meta['driver'])}, PoCL "
             f"{meta['pocl']}); copy bandwidth {bw / 1e9:.1f} GB/s.</p>"]
    if notes:
        parts.append("<h2>Skipped</h2><ul>" + "".join(
            f"<li>{html.escape(n)}</li>" for n in notes) + "</ul>")
    kernels = sorted({r["kernel"] for r in rows if r["error"] is not None})
    roof = [r for r in rows if r.get("bandwidth_fraction") is not None]
    if roof:
        parts.append("<h2>Memory-bandwidth roofline</h2><table border=1 cellpadding=3><tr><th>"
                     "stage</th><th>grid</th><th>s</th><th>GB/s</th><th>fraction of copy</th>"
                     "</tr>" + "".join(
                         f"<tr><td>{r['knob']}</td><td>{r['value']}</td><td>{r['median_s']:.3g}"
                         f"</td><td>{r['bytes_moved'] / r['median_s'] / 1e9:.2f}</td><td>"
                         f"{r['bandwidth_fraction']:.2f}</td></tr>" for r in roof) + "</table>")
    for kern in kernels:
        fig, ax = plt.subplots(figsize=(6, 4))
        knobs = sorted({(r["knob"], r["dtype"], r["impl"]) for r in rows
                        if r["kernel"] == kern and r["error"] is not None})
        for knob, dt, impl in knobs:
            rs = [r for r in rows if (r["kernel"], r["knob"], r["dtype"], r["impl"]) ==
                  (kern, knob, dt, impl) and r["error"] is not None]
            ax.loglog([r["median_s"] for r in rs], [max(r["error"], 1e-17) for r in rs], "o-",
                      label=f"{knob} {dt} {impl}")
        ax.set(xlabel="time (s)", ylabel="relative error vs float64 reference", title=kern)
        ax.legend(fontsize=6)
        parts.append(f"<h2>{kern}</h2><img src='data:image/png;base64,{_png(fig)}'/>")
    parts.append("<h2>Recommended settings</h2><table border=1 cellpadding=3><tr><th>kernel"
                 "</th><th>knob</th><th>for error</th><th>use</th><th>dtype</th><th>costs (s)"
                 "</th><th>error reached</th></tr>" + "".join(
                     f"<tr><td>{r['kernel']}</td><td>{r['knob']}</td><td>{r['target_error']:g}"
                     f"</td><td>{r['value']}</td><td>{r['dtype']}</td><td>{r['seconds']:.3g}"
                     f"</td><td>{r['error']:.2g}</td></tr>" for r in recs) + "</table>")
    parts.append("<h2>All rows</h2><pre>" + html.escape(json.dumps(rows, indent=0)) + "</pre>")
    path.write_text(f"<!doctype html><html><head><meta charset='utf-8'>{HTML_GENERATOR}"
                    "<title>clnlos bench"
                    "</title></head><body style='font-family:sans-serif'>" + "\n".join(parts)
                    + "</body></html>", encoding="utf-8")
