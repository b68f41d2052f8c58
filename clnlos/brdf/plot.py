"""``clnlos brdf plot``: in-plane curves of a fitted model at theta_i = 30, 45, 60 degrees with
the measured samples near that plane."""

from __future__ import annotations

import numpy as np

from clnlos.brdf.data import merl_samples, read_gonio_csv, read_pbrt_brdf

PLANE_TOL_DEG = 0.6   # samples within this of the plotted incidence angle
PLANE_SIN_TOL = 0.05  # and |sin(phi_s - phi_i)| below this (in the plane of incidence)


def read_samples(path, *, held_out: bool = False):
    """Measured samples by the file's suffix: pbrt-v2 ``.brdf``, MERL ``.binary``
    (:func:`clnlos.brdf.data.merl_samples`: its gonioreflectometer grid, or random directions
    for a ``held_out`` set), else gonioreflectometer CSV."""
    p = str(path)
    if p.endswith(".binary"):
        return merl_samples(p, held_out=held_out)
    return read_pbrt_brdf(p) if p.endswith(".brdf") else read_gonio_csv(p)


def in_plane(data, theta_i_deg: float):
    """(signed theta_s in deg, + = forward; BRDF) of the samples in the plane of incidence."""
    sel = (np.abs(np.degrees(data.theta_i) - theta_i_deg) < PLANE_TOL_DEG) & (
        np.abs(np.sin(data.phi_s - data.phi_i)) < PLANE_SIN_TOL)
    sign = np.where(np.cos(data.phi_s[sel] - data.phi_i[sel]) < 0, 1, -1)
    return sign * np.degrees(data.theta_s[sel]), data.brdf[sel]


def brdf_figure(model, title: str, data=None):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 4), sharey=True, constrained_layout=True)
    ts = np.radians(np.linspace(-89, 89, 357))
    for ax, ti_deg in zip(axes, (30, 45, 60), strict=True):
        ti = np.radians(ti_deg)
        # in-plane: detector at phi = 180 (forward, positive angles) or 0 (backward)
        f = model(np.full_like(ts, ti), np.zeros_like(ts), np.abs(ts),
                  np.where(ts >= 0, np.pi, 0.0))
        ax.semilogy(np.degrees(ts), np.maximum(f, 1e-6), label="model")
        if data is not None:
            x, y = in_plane(data, ti_deg)
            ax.semilogy(x, np.maximum(y, 1e-6), ".", ms=3, label="data")
        ax.set(title=f"theta_i = {ti_deg} deg (in plane)",
               xlabel="theta_s (deg, + = forward)")
    axes[0].set_ylabel("BRDF (1/sr)")
    axes[0].legend()
    fig.suptitle(title)
    return fig
