"""Image-panel figures drawn with Pillow: axes in physical units, ticks, colour bars.

For the figure every reconstruction writes beside its volume (:func:`clnlos.io.figures.
volume_figure`): four image panels with a colour bar each. matplotlib would draw the same in
about 0.55 s, most of it importing and laying out artists; this draws it in a few tens of
milliseconds, which matters when the reconstruction itself takes two seconds. Figures with
curves, legends or scatter plots stay with matplotlib.

Conventions: an image ``img[row, col]`` is drawn with row 0 at the bottom (matplotlib's
``origin="lower"``) over ``extent = (x_min, x_max, y_min, y_max)``; masked values (NaN) are
left white; ``aspect="equal"`` keeps metres square, ``"auto"`` fills the panel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from PIL import Image, ImageDraw, ImageFont
from PIL.PngImagePlugin import PngInfo

# viridis (van der Walt & Smith, CC0), sampled at 17 equally spaced points; linear
# interpolation between them is within 6/255 of the 256-entry map
VIRIDIS_ANCHORS = np.array([
    [68, 1, 84], [72, 24, 106], [71, 45, 123], [66, 64, 134], [59, 82, 139], [51, 99, 141],
    [44, 114, 142], [38, 130, 142], [33, 145, 140], [31, 160, 136], [40, 174, 128],
    [63, 188, 115], [94, 201, 98], [132, 212, 75], [173, 220, 48], [216, 226, 25],
    [253, 231, 37]], np.float64)

FONT_PX = {"tick": 13, "label": 14, "title": 15, "suptitle": 16}
TICK_PX = 5  # tick mark length
BAR_WIDTH_PX, BAR_GAP_PX = 14, 12
INK, BACKGROUND = (0, 0, 0), (255, 255, 255)


def colormap_lut(name: str) -> np.ndarray:
    """256 x 3 uint8 lookup table of ``"gray"`` or ``"viridis"``."""
    x = np.linspace(0.0, 1.0, 256)
    if name == "gray":
        rgb = np.repeat(x[:, None], 3, axis=1) * 255
    elif name == "viridis":
        a = np.linspace(0.0, 1.0, len(VIRIDIS_ANCHORS))
        rgb = np.stack([np.interp(x, a, VIRIDIS_ANCHORS[:, c]) for c in range(3)], axis=1)
    else:
        raise ValueError(f"colour map {name!r}: 'gray' or 'viridis'")
    return np.round(rgb).astype(np.uint8)


def nice_ticks(lo: float, hi: float, target: int = 5) -> tuple[np.ndarray, int]:
    """(tick values inside [lo, hi], decimals to print them with): steps of 1, 2, 2.5 or 5
    times a power of ten, at most about ``target`` + 1 ticks."""
    lo, hi = (lo, hi) if lo <= hi else (hi, lo)
    span = hi - lo
    if not math.isfinite(span) or span <= 0:
        return np.array([lo]), 2
    mag = 10.0 ** math.floor(math.log10(span / target))
    for m in (1.0, 2.0, 2.5, 5.0, 10.0):
        step = m * mag
        if span / step <= target:
            break
    ticks = np.arange(math.ceil(lo / step - 1e-9), math.floor(hi / step + 1e-9) + 1) * step
    decimals = max(0, -math.floor(math.log10(step) + 1e-9) + (1 if m == 2.5 else 0))
    return ticks, decimals


def tick_label(v: float, decimals: int) -> str:
    s = f"{v:.{decimals}f}"
    return s.lstrip("-") if float(s) == 0 else s  # no "-0.0"


@dataclass
class Panel:
    """One image panel: data, its extent and labels, colour map and colour-bar label."""

    img: np.ndarray
    extent: tuple[float, float, float, float]
    title: str
    xlabel: str
    ylabel: str
    cmap: str = "gray"
    bar_label: str = ""
    aspect: str = "equal"
    limits: tuple[float, float] | None = None  # the colour bar's range (default: the data's)


class RasterFigure:
    """A row of :class:`Panel` s on one canvas, saved as PNG (``savefig``, like a
    matplotlib figure; ``dpi`` and layout options are ignored: sizes are in pixels)."""

    def __init__(self, panels: list[Panel], *, suptitle: str = "", width_px: int = 1800,
                 height_px: int = 440):
        self._Image, self._ImageDraw = Image, ImageDraw
        self.canvas = Image.new("RGB", (int(width_px), int(height_px)), BACKGROUND)
        self.draw = ImageDraw.Draw(self.canvas)
        self.fonts = {k: ImageFont.load_default(size=v) for k, v in FONT_PX.items()}
        self.panels = list(panels)
        top = 0
        if suptitle:
            self._text((width_px / 2, 8), suptitle, "suptitle", anchor="ma")
            top = 30
        slot = width_px / max(1, len(panels))
        for i, p in enumerate(panels):
            self._panel(p, int(i * slot), int(slot), top, int(height_px))

    # -- drawing helpers
    def _text(self, xy, text, font, anchor="la", rotate=False):
        f = self.fonts[font]
        if not rotate:
            self.draw.text(xy, text, fill=INK, font=f, anchor=anchor)
            return
        left, top, right, bottom = self.draw.textbbox((0, 0), text, font=f)
        tmp = self._Image.new("L", (right - left + 2, bottom - top + 2), 0)
        self._ImageDraw.Draw(tmp).text((1 - left, 1 - top), text, fill=255, font=f)
        tmp = tmp.rotate(90, expand=True)
        x, y = xy  # centre of the rotated text
        self.canvas.paste(INK, (int(x - tmp.width / 2), int(y - tmp.height / 2)), tmp)

    def _image(self, rgb: np.ndarray, box):
        x0, y0, x1, y1 = box
        im = self._Image.fromarray(rgb[::-1])  # row 0 at the bottom
        self.canvas.paste(im.resize((x1 - x0, y1 - y0), self._Image.Resampling.BOX),
                          (x0, y0))
        self.draw.rectangle((x0 - 1, y0 - 1, x1, y1), outline=INK)

    def _xticks(self, box, lo, hi):
        x0, _, x1, y1 = box
        ticks, dec = nice_ticks(lo, hi)
        for v in ticks:
            x = x0 + (v - lo) / (hi - lo) * (x1 - x0)
            self.draw.line((x, y1, x, y1 + TICK_PX), fill=INK)
            self._text((x, y1 + TICK_PX + 2), tick_label(v, dec), "tick", anchor="ma")

    def _yticks(self, box, lo, hi, right=False):
        x0, y0, x1, y1 = box
        ticks, dec = nice_ticks(lo, hi)
        widest = 0
        for v in ticks:
            y = y1 - (v - lo) / (hi - lo) * (y1 - y0)
            label = tick_label(v, dec)
            widest = max(widest, self.draw.textlength(label, font=self.fonts["tick"]))
            if right:
                self.draw.line((x1, y, x1 + TICK_PX, y), fill=INK)
                self._text((x1 + TICK_PX + 3, y), label, "tick", anchor="lm")
            else:
                self.draw.line((x0 - TICK_PX, y, x0, y), fill=INK)
                self._text((x0 - TICK_PX - 3, y), label, "tick", anchor="rm")
        return widest

    def _panel(self, p: Panel, left: int, width: int, top: int, height: int):
        img = np.asarray(p.img, np.float64)
        finite = np.isfinite(img)
        if p.limits is not None:
            lo, hi = (float(v) for v in p.limits)
        else:
            lo = float(img[finite].min()) if finite.any() else 0.0
            hi = float(img[finite].max()) if finite.any() else 1.0
        hi = hi if hi > lo else lo + 1.0
        # room: y ticks + label on the left, colour bar + its ticks + label on the right
        ax_l, ax_r = left + 78, left + width - (BAR_GAP_PX + BAR_WIDTH_PX + 70)
        ax_t, ax_b = top + 28, height - 52
        x_min, x_max, y_min, y_max = p.extent
        if p.aspect == "equal":
            scale = min((ax_r - ax_l) / (x_max - x_min), (ax_b - ax_t) / (y_max - y_min))
            w, h = int((x_max - x_min) * scale), int((y_max - y_min) * scale)
            ax_l += (ax_r - ax_l - w) // 2
            ax_t += (ax_b - ax_t - h) // 2
            ax_r, ax_b = ax_l + w, ax_t + h
        box = (int(ax_l), int(ax_t), int(ax_r), int(ax_b))
        lut = colormap_lut(p.cmap)
        idx = np.clip(np.round((np.where(finite, img, lo) - lo) / (hi - lo) * 255), 0, 255)
        rgb = lut[idx.astype(np.uint8)]
        rgb[~finite] = BACKGROUND
        self._image(rgb, box)
        self._xticks(box, x_min, x_max)
        widest = self._yticks(box, y_min, y_max)
        self._text(((box[0] + box[2]) / 2, box[1] - 6), p.title, "title", anchor="md")
        self._text(((box[0] + box[2]) / 2, box[3] + TICK_PX + 22), p.xlabel, "label",
                   anchor="ma")
        self._text((box[0] - TICK_PX - widest - 14, (box[1] + box[3]) / 2), p.ylabel,
                   "label", rotate=True)
        # colour bar: the map from lo (bottom) to hi (top), ticks in data units
        bar = (box[2] + BAR_GAP_PX, box[1], box[2] + BAR_GAP_PX + BAR_WIDTH_PX, box[3])
        ramp = np.repeat(lut[:, None, :], BAR_WIDTH_PX, axis=1)  # row 0 (lo) at the bottom
        self._image(ramp, bar)
        bar_widest = self._yticks(bar, lo, hi, right=True)
        if p.bar_label:
            self._text((bar[2] + TICK_PX + bar_widest + 16, (bar[1] + bar[3]) / 2),
                       p.bar_label, "label", rotate=True)

    def savefig(self, path, format: str = "png", metadata: dict | None = None,
                **_ignored) -> None:
        """Write the canvas as PNG to a path or a binary file object, with ``metadata``
        (keyword -> text) as PNG tEXt chunks."""
        info = PngInfo()
        for k, v in (metadata or {}).items():
            info.add_text(k, v)
        self.canvas.save(path, format="PNG", compress_level=3, pnginfo=info)
