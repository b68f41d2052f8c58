"""Figures people look at: every image with axes in metres or nanoseconds and a colour bar.

matplotlib is imported only here, only when a figure is drawn (never on the compute path).
"""

from __future__ import annotations

import sys

import numpy as np

from clnlos.io.raster import Panel, RasterFigure

DEPTH_MAP_FLOOR = 0.1  # the depth map shows columns whose MIP is at least this of its max


def new_figure(rows: int, cols: int, figsize):
    """(figure, axes) without pyplot: a plain ``matplotlib.figure.Figure`` rendered by Agg
    when saved (importing pyplot costs about 0.4 s of a cold reconstruct)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, layout="constrained")
    return fig, fig.subplots(rows, cols)


def close_figure(fig) -> None:
    """Release a figure: pyplot keeps figures it made until closed; plain Figures and
    :class:`clnlos.io.raster.RasterFigure` need nothing."""
    plt = sys.modules.get("matplotlib.pyplot")
    if plt is not None and not isinstance(fig, RasterFigure):
        plt.close(fig)


def display_scale(img: np.ndarray, gamma: float | None = None, log: bool = False
                  ) -> tuple[np.ndarray, str]:
    """(image normalised to its maximum and transformed for display, colour-bar label)."""
    a = np.asarray(img, np.float64)
    m = a.max()
    a = a / m if m > 0 else a
    if log:
        return np.log10(np.maximum(a, 1e-4)), "log10(value / max)"
    if gamma is not None:
        return np.power(np.clip(a, 0, None), gamma), f"(value / max)^{gamma:g}"
    return a, "value / max (albedo, a.u.)"


def volume_figure(volume: np.ndarray, extents: dict, title: str = "", *,
                  gamma: float | None = None, log: bool = False):
    """Max-intensity projection (x-y), depth map (depth of the brightest voxel, where the MIP
    is at least DEPTH_MAP_FLOOR of its maximum; its colour bar spans the volume's depth
    range), x-z and y-z projections: a :class:`clnlos.io.raster.RasterFigure` (drawn with
    Pillow in a few tens of milliseconds; saved like a matplotlib figure)."""
    e = extents
    xy = (e["x_min_m"], e["x_max_m"], e["y_min_m"], e["y_max_m"])
    raw_mip = volume.max(axis=0)
    mip, label = display_scale(raw_mip, gamma, log)
    depth = volume_view(volume, e, "depth")[0]
    empty = not raw_mip.max() > 0  # nothing to show a depth of: said, not drawn as a map
    panels = [Panel(mip, xy, "max over depth (x-y)" + (": all zero" if empty else ""),
                    "x (m)", "y (m)", "gray", label),
              Panel(depth, xy, "depth of the brightest voxel" + (": none (the volume is all "
                                                                  "zero)" if empty else ""),
                    "x (m)", "y (m)", "viridis", "depth z (m)",
                    limits=depth_range(e))]
    for axis, lo, hi, lab in ((1, "x_min_m", "x_max_m", "x (m)"),
                              (2, "y_min_m", "y_max_m", "y (m)")):
        proj, plab = display_scale(volume.max(axis=axis), gamma, log)
        panels.append(Panel(proj, (e[lo], e[hi], e["depth_min_m"], e["depth_max_m"]),
                            f"max over {'y' if axis == 1 else 'x'} ({lab[0]}-z)", lab,
                            "depth z (m)", "gray", plab, aspect="auto"))
    return RasterFigure(panels, suptitle=title)


def transient_figure(tau: np.ndarray, *, width_m: float, start_s: float, bin_width_s: float,
                     title: str = "", units: str = "counts"):
    """x-t and y-t slices through the centre and the time-integrated image."""
    nt, ny, nx = tau.shape
    w = width_m
    h = w * ny / nx
    t0, t1 = start_s * 1e9, (start_s + nt * bin_width_s) * 1e9
    fig, ax = new_figure(1, 3, (13, 4))
    for a, img, lab, ext in ((ax[0], tau[:, ny // 2, :], "x (m)", (-w / 2, w / 2, t0, t1)),
                             (ax[1], tau[:, :, nx // 2], "y (m)", (-h / 2, h / 2, t0, t1))):
        im = a.imshow(img, origin="lower", aspect="auto", cmap="magma", extent=ext)
        a.set(xlabel=lab, ylabel="t (ns)",
              title=f"{lab[0]}-t slice ({'y' if lab[0] == 'x' else 'x'} = centre)")
        fig.colorbar(im, ax=a, label=units + " per bin", shrink=0.85)
    im = ax[2].imshow(tau.sum(axis=0), origin="lower", cmap="gray",
                      extent=(-w / 2, w / 2, -h / 2, h / 2))
    ax[2].set(xlabel="x (m)", ylabel="y (m)", title="time-integrated")
    fig.colorbar(im, ax=ax[2], label=units, shrink=0.85)
    if title:
        fig.suptitle(title)
    return fig




VIEWS = ("xy", "xz", "yz", "depth")  # the projections volume_axes draws


def volume_view(volume: np.ndarray, extents: dict | None, view: str, *,
                gamma: float | None = None, log: bool = False
                ) -> tuple[np.ndarray, tuple[float, float, float, float], str, str, str]:
    """(image, extent (left, right, bottom, top), x label, y label, colour-bar label) of one
    view of a volume [z, y, x]: "xy" the maximum over depth, "xz" / "yz" the maximum over y /
    x (depth increasing downwards), "depth" the depth (m) of the brightest voxel where the
    maximum is at least DEPTH_MAP_FLOOR of its largest value (:func:`depth_range`: the
    range its colour bar spans). Without ``extents`` the axes count voxels."""
    if view not in VIEWS:
        raise ValueError(f"view {view!r}: one of {', '.join(VIEWS)}")
    e = extents or voxel_extents(volume.shape)
    unit = "m" if extents else "voxels"
    xy = (e["x_min_m"], e["x_max_m"], e["y_min_m"], e["y_max_m"])
    if view == "depth":
        raw = volume.max(axis=0)
        depth = e["depth_min_m"] + (np.argmax(volume, axis=0) + 0.5) * e["voxel_depth_m"]
        depth = np.where(raw < DEPTH_MAP_FLOOR * max(raw.max(), 1e-300), np.nan, depth)
        return depth, xy, f"x ({unit})", f"y ({unit})", f"depth z ({unit})"
    if view == "xy":
        img, label = display_scale(volume.max(axis=0), gamma, log)
        return img, xy, f"x ({unit})", f"y ({unit})", label
    axis = 1 if view == "xz" else 2
    img, label = display_scale(volume.max(axis=axis), gamma, log)
    lo, hi = ("x_min_m", "x_max_m") if view == "xz" else ("y_min_m", "y_max_m")
    return (img, (e[lo], e[hi], e["depth_max_m"], e["depth_min_m"]), f"{view[0]} ({unit})",
            f"depth z ({unit})", label)


def voxel_extents(shape) -> dict:
    """Extents in voxels, for a volume [z, y, x] given without its extents in metres."""
    nz, ny, nx = shape
    return {"x_min_m": 0.0, "x_max_m": float(nx), "y_min_m": 0.0, "y_max_m": float(ny),
            "depth_min_m": 0.0, "depth_max_m": float(nz), "voxel_depth_m": 1.0}


def depth_range(extents: dict) -> tuple[float, float]:
    """The range a depth map's colour bar spans: the volume's depths (m, or voxels), so the
    colours mean the same depth in every figure of the volume."""
    return float(extents["depth_min_m"]), float(extents["depth_max_m"])


def volume_axes(volume: np.ndarray, extents: dict | None = None, *, ax=None,
                view: str = "xy", gamma: float | None = None, log: bool = False,
                colorbar: bool = True):
    """Draw one view of a volume [z, y, x] (:func:`volume_view`) on matplotlib axes ``ax``
    (a new pyplot figure's when None, so a notebook shows it), with axis labels in metres
    and a colour bar; returns the axes."""
    img, extent, xlabel, ylabel, label = volume_view(np.asarray(volume), extents, view,
                                                     gamma=gamma, log=log)
    if ax is None:
        import matplotlib.pyplot as plt  # lazy: only a notebook figure needs pyplot

        _, ax = plt.subplots(figsize=(5, 4), layout="constrained")
    depth_view = view in ("xz", "yz")
    im = ax.imshow(img, origin="upper" if depth_view else "lower", extent=extent,
                   cmap="viridis" if view == "depth" else "gray",
                   aspect="auto" if depth_view else "equal", interpolation="nearest")
    ax.set(xlabel=xlabel, ylabel=ylabel,
           title={"xy": "max over depth", "xz": "max over y", "yz": "max over x",
                  "depth": "depth of the brightest voxel"}[view])
    if view == "depth":
        im.set_clim(*depth_range(extents or voxel_extents(np.shape(volume))))
    if colorbar:
        ax.figure.colorbar(im, ax=ax, label=label, shrink=0.85)
    return ax
