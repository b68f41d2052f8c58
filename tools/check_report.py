#!/usr/bin/env python3
"""Look at a study report as a reader would: headless Chromium at 1280 px.

Renders REPORT.html to a PNG screenshot (the whole page) and reads the page's
``data-overflow`` marker (set by the report's own script after load: whether anything is
wider than the window). Exit status 1 when the page overflows horizontally or a figure fails
to load, 2 when Chromium is missing (Debian package ``chromium``).

    python tools/check_report.py out/study/report.html [-o report.png] [--width 1280]
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

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
    """{"overflow": bool, "images": n, "broken_images": n, "screenshot": path}."""
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
    imgs = re.findall(r"<img [^>]*src=\"data:image/png;base64,([^\"]*)\"", dom)
    return {"overflow": None if m is None else m.group(1) == "true", "images": len(imgs),
            "broken_images": sum(len(i) < 100 for i in imgs),
            "screenshot": str(png) if png else None}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("report", type=Path)
    ap.add_argument("-o", "--output", type=Path, default=None, help="screenshot PNG")
    ap.add_argument("--width", type=int, default=1280)
    args = ap.parse_args(argv)
    try:
        res = check(args.report, args.output, args.width)
    except FileNotFoundError as exc:
        print(f"check_report: {exc}", file=sys.stderr)
        return 2
    print(res)
    ok = res["overflow"] is False and res["images"] > 0 and res["broken_images"] == 0
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
