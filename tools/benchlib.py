"""Shared helpers of the tools/bench_*.py scripts: timing, device metadata, output tables.

Timing follows pyopencl's characterize._get_time: warm-up, queue.finish() around each run,
median/min/max over repeats. Never imported by the package.
"""

from __future__ import annotations

import csv
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def device_meta(queue) -> dict:
    from clnlos.runtime import pocl_version

    dev = queue.device
    pv = pocl_version(dev)
    return {"device": dev.name.strip(), "platform": dev.platform.name.strip(),
            "driver": dev.driver_version.strip(),
            "pocl": f"{pv[0]}.{pv[1]}" if pv else None,
            "host": platform.processor() or platform.machine(), "cpus": os.cpu_count()}


def timeit(fn, queue=None, *, warmup: int = 1, repeat: int = 5, min_time: float = 0.0):
    """Run fn() warmup times, then repeat times (more while the total is under min_time)."""
    for _ in range(warmup):
        fn()
        if queue is not None:
            queue.finish()
    times = []
    t_total = 0.0
    while len(times) < repeat or t_total < min_time:
        if queue is not None:
            queue.finish()
        t0 = time.perf_counter()
        fn()
        if queue is not None:
            queue.finish()
        dt = time.perf_counter() - t0
        times.append(dt)
        t_total += dt
        if len(times) > 1000:
            break
    return {"median_s": statistics.median(times), "min_s": min(times), "max_s": max(times),
            "repeats": len(times)}


def write_rows(rows: list[dict], out_dir: Path, stem: str) -> tuple[Path, Path]:
    """Write rows as CSV and JSON atomically; returns both paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    keys: list[str] = []
    for r in rows:
        keys.extend(k for k in r if k not in keys)
    paths = []
    for ext in ("csv", "json"):
        path = out_dir / f"{stem}.{ext}"
        fd, tmp = tempfile.mkstemp(dir=out_dir, suffix=f".{ext}.tmp")
        with os.fdopen(fd, "w", newline="") as f:
            if ext == "csv":
                w = csv.DictWriter(f, fieldnames=keys)
                w.writeheader()
                w.writerows(rows)
            else:
                json.dump(rows, f, indent=1)
        os.replace(tmp, path)
        paths.append(path)
    return paths[0], paths[1]


def print_table(rows: list[dict], cols: list[str]) -> None:
    def fmt(v):
        if isinstance(v, float):
            return f"{v:.3g}"
        return str(v)

    width = {c: max(len(c), *(len(fmt(r.get(c, ""))) for r in rows)) for c in cols}
    print("  ".join(c.rjust(width[c]) for c in cols))
    for r in rows:
        print("  ".join(fmt(r.get(c, "")).rjust(width[c]) for c in cols))
