#!/usr/bin/env python3
"""Look at a study report as a reader would: headless Chromium at 1280 px.

Renders REPORT.html to a PNG screenshot (``--height`` px of the page) and reads the page's
markers, set by the report's own scripts after load: ``data-overflow`` (whether anything is
wider than the window) and ``data-headline-top``/``-bottom`` (the headline figure's box, px
from the page top). Exit status 1 when the page overflows horizontally, a figure fails to
load or, with ``--first-screen``, the headline figure does not lie in the first screen
(1400 x 900 px: the window is set to it); 2 when Chromium is missing (Debian package
``chromium``).

    python tools/check_report.py out/study/report.html [-o report.png] [--width 1280]
    python tools/check_report.py out/study/report.html --first-screen -o first.png
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

FIRST_SCREEN = (1400, 900)  # the window a reader first sees the report in (px)
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--hide-scrollbars"]


def chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


def check(report: Path, png: Path | None = None, width: int = 1280, height: int = 6000
          ) -> dict:
    """{"overflow": bool, "images": n, "broken_images": n, "headline": [top, bottom] px from
    the page top (None without the marker), "screenshot": path}."""
    exe = chromium()
    if exe is None:
        raise FileNotFoundError("chromium not found (Debian package chromium)")
    url = report.resolve().as_uri()
    with tempfile.TemporaryDirectory() as profile:
        common = [exe, *FLAGS, f"--user-data-dir={profile}", f"--window-size={width},{height}"]
        dom = subprocess.run(common + ["--virtual-time-budget=5000", "--dump-dom", url],
                             capture_output=True, text=True, timeout=180).stdout
        if png is not None:
            subprocess.run(common + [f"--screenshot={png}", url], capture_output=True,
                           timeout=180)
    m = re.search(r'<body[^>]*data-overflow="(true|false)"', dom)
    top = re.search(r'<body[^>]*data-headline-top="(-?\d+)"', dom)
    bottom = re.search(r'<body[^>]*data-headline-bottom="(-?\d+)"', dom)
    imgs = re.findall(r"<img [^>]*src=\"data:image/png;base64,([^\"]*)\"", dom)
    return {"overflow": None if m is None else m.group(1) == "true", "images": len(imgs),
            "broken_images": sum(len(i) < 100 for i in imgs),
            "headline": None if top is None or bottom is None
            else [int(top.group(1)), int(bottom.group(1))],
            "screenshot": str(png) if png else None}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("report", type=Path)
    ap.add_argument("-o", "--output", type=Path, default=None, help="screenshot PNG")
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=6000, help="window height (px)")
    ap.add_argument("--first-screen", action="store_true",
                    help=f"window {FIRST_SCREEN[0]} x {FIRST_SCREEN[1]}: the headline figure "
                         "must lie in it")
    args = ap.parse_args(argv)
    width, height = FIRST_SCREEN if args.first_screen else (args.width, args.height)
    try:
        res = check(args.report, args.output, width, height)
    except FileNotFoundError as exc:
        print(f"check_report: {exc}", file=sys.stderr)
        return 2
    print(res)
    ok = res["overflow"] is False and res["images"] > 0 and res["broken_images"] == 0
    if args.first_screen:
        ok = ok and res["headline"] is not None and res["headline"][1] <= FIRST_SCREEN[1]
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
