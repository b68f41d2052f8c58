"""Benchmark harness: synchronised timing, device metadata, rows, tables (CSV/JSON).

Timing follows pyopencl's characterize._get_time: warm-up, queue.finish() around each run,
median/min/max over repeats. Each row pairs a time with an error against a float64 reference
of the same run.
"""

from __future__ import annotations

import csv
import json
import os
import platform
import resource
import statistics
import time
from pathlib import Path

import numpy as np

from clnlos.io.outputs import provenance, stamp, write_group
from clnlos.runtime.device import has_fp64, pocl_version


def device_meta(queue) -> dict:
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


def timed_once(fn, queue=None):
    """(fn()'s result, its timing as :func:`timeit` reports it) from one cold run: for runs
    too long to repeat (a training, a numpy baseline of seconds)."""
    if queue is not None:
        queue.finish()
    t0 = time.perf_counter()
    out = fn()
    if queue is not None:
        queue.finish()
    dt = time.perf_counter() - t0
    return out, {"median_s": dt, "min_s": dt, "max_s": dt, "repeats": 1}


def rows_document(rows: list[dict]) -> dict:
    """The JSON of a result table: the clnlos version first, then its provenance (version,
    git commit, UTC time: :func:`clnlos.io.outputs.provenance`) and the rows."""
    return stamp({"provenance": provenance(), "rows": rows})


def read_rows(path) -> list[dict]:
    """The rows of a result JSON: :func:`rows_document`'s, or a bare list of rows (the files
    written before the results recorded their provenance)."""
    doc = json.loads(Path(path).read_text(encoding="utf-8"))
    return doc["rows"] if isinstance(doc, dict) else doc


def write_rows(rows: list[dict], out_dir: Path, stem: str) -> tuple[Path, Path]:
    """Write rows as CSV and JSON (:func:`rows_document`), atomically together
    (:func:`clnlos.io.outputs.write_group`); returns both paths."""
    keys: list[str] = []
    for r in rows:
        keys.extend(k for k in r if k not in keys)
    paths = (out_dir / f"{stem}.csv", out_dir / f"{stem}.json")
    with write_group(list(paths)) as (tmp_csv, tmp_json):
        with open(tmp_csv, "w", newline="", encoding="utf-8") as f:
            w = csv.DictWriter(f, fieldnames=keys)
            w.writeheader()
            w.writerows(rows)
        with open(tmp_json, "w", encoding="utf-8") as f:
            json.dump(rows_document(rows), f, indent=1)
    return paths


def print_table(rows: list[dict], cols: list[str]) -> None:
    def fmt(v):
        if isinstance(v, float):
            return f"{v:.3g}"
        return str(v)

    width = {c: max(len(c), *(len(fmt(r.get(c, ""))) for r in rows)) for c in cols}
    print("  ".join(c.rjust(width[c]) for c in cols))
    for r in rows:
        print("  ".join(fmt(r.get(c, "")).rjust(width[c]) for c in cols))


ROW_KEYS = ("device", "driver", "pocl", "kernel", "knob", "value", "dtype", "impl", "median_s",
            "min_s", "max_s", "error", "peak_mem_bytes")


def rel_error(a, b) -> float:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-300))


class Bench:
    """One run's rows: :meth:`add` times a callable, :meth:`record` keeps a timing measured
    elsewhere (a single long run, another process); :meth:`note` says what was skipped."""

    def __init__(self, queue, size: str):
        self.q, self.size = queue, size
        self.meta = device_meta(queue)
        self.rows: list[dict] = []
        self.notes: list[str] = []
        self.options: dict = {}  # section inputs from the command line (``brdf_data``)
        self.repeat = {"tiny": 1, "quick": 3, "full": 5}[size]
        self.f64 = has_fp64(queue.device)

    def add(self, kernel, knob, value, dtype, fn, error, impl="opencl", sync=True, **extra):
        t = timeit(fn, self.q if sync else None, repeat=self.repeat)
        return self.record(kernel, knob, value, dtype, t, error, impl=impl, **extra)

    def record(self, kernel, knob, value, dtype, timing: dict, error, impl="opencl", **extra):
        """A row from ``timing`` (the keys :func:`timeit` returns)."""
        row = {"device": self.meta["device"], "driver": self.meta["driver"],
               "pocl": self.meta["pocl"], "kernel": kernel, "knob": knob, "value": value,
               "dtype": np.dtype(dtype).name, "impl": impl, **timing,
               "error": None if error is None else float(error),
               "peak_mem_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
               **extra}
        self.rows.append(row)
        return row

    def note(self, text: str) -> None:
        """Something a section skipped (an optional dependency or data set absent), and why."""
        self.notes.append(text)
        print(f"  note: {text}", flush=True)

    @property
    def dtypes(self):
        return [np.float32] + ([np.float64] if self.f64 else [])
